"""``storyteller bench``: the paper's planning evaluation as resumable, traced sweeps.

What lives here: the grid of a sweep (:mod:`.grid`: case sets x distraction levels x repeats
x methods x models, and the stable id of every run), one run of the planning graph and its
score (:mod:`.execute`), the sweep driver with resume and parallel runs (:mod:`.runner`), the
result line of a run (:mod:`.results`), the reports (:mod:`.report`, :mod:`.plots`), the
progress display (:mod:`.progress`), the Ray executor (:mod:`.ray_executor`) and the
``bench`` command group (:mod:`.cli`, registered into ``storyteller`` as an entry-point plugin).

May import: ``sim``, ``tools``, ``agents``, ``orchestrator`` and the rest of ``benchmark``
(``orchestrator`` never imports this package). ``cli`` imports only typer at module level, so
registering the plugin costs nothing until a ``bench`` command runs.

Guarantees: every LLM call of a sweep is written to a trace in the sweep folder (one file per
run, one per scene description); a run's result line is derived from its outcome and its trace
only (no wall clock), so ``bench score`` (replaying the traces, no model loaded) rewrites
``results.jsonl``, ``results.csv``, ``report.md`` and the plots byte for byte; a finished run's
line is appended and fsync'd before the next is counted, so a killed sweep restarted with the
same arguments redoes only the runs without a line.
"""
