"""``python -m storyteller.benchmark.hostile_inputs``: an outside attacker's corpus against every file the
CLI reads back (issue 22). The harness, the attacks by target and the runner are in
:mod:`storyteller.benchmark.hostile`; see :mod:`storyteller.benchmark.hostile.runner` for what it does and prints.
"""

from __future__ import annotations

from storyteller.benchmark.hostile.runner import ATTACKS, main

__all__ = ["ATTACKS", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
