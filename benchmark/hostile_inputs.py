"""``python -m benchmark.hostile_inputs``: an outside attacker's corpus against every file the
CLI reads back (issue 22). The harness, the attacks by target and the runner are in
:mod:`benchmark.hostile`; see :mod:`benchmark.hostile.runner` for what it does and prints.
"""

from __future__ import annotations

from benchmark.hostile.runner import ATTACKS, main

__all__ = ["ATTACKS", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
