"""Our own benchmark cases (``benchmark/cases/ours``) and the check that re-derives their answers.

What lives here: :mod:`.derivation` evaluates the small query a case carries in its
``derivation`` block against the scene (objects, :mod:`storyteller.tools.scene_graph` relations, region
clusters) and the case's world (who sits where, which objects are in use, from the history and
the current states), and :mod:`.check` compares what it derives with the case's expected plans
at every distraction level (``python -m storyteller.benchmark.own_cases.check``).

May import ``sim``, ``tools`` and the rest of ``benchmark`` (the case loader and the position
check); nothing imports it but its tests.

Guarantee: a case set that passes the check has, for every expected character, exactly the
answer its query derives from the geometry and the history, the same answer at distraction
levels 0, 1 and 2, a single object where the query asks for one, and at least one reachable
position for every non-seat answer.
"""

OURS = "ours"
"""Folder of our case set under ``benchmark/cases``."""
OURS_REF = "ours_ref"
"""Folder of our generated cases on the authors' reference scenes under ``benchmark/cases``
(they run only where the reference data is found)."""
