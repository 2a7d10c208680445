"""The story suite: end-to-end scenarios on the bundled scenes, judged on the run's story log.

What lives here: the scenario files (``scenarios/*.toml``) and their typed model
(``scenario``), the evaluator (``evaluate``: a run folder's ``story.json`` against a scenario,
as the share of expectations met, each with a verdict and a reason), the runner (``runner``:
``storyteller run --pace lockstep`` as a subprocess, recording or replaying a trace), the table
(``report``) and the command (``python -m storyteller.benchmark.story_suite run|score``).

What it may import: ``storyteller.benchmark.plan_scoring`` and ``storyteller.benchmark.position_check`` (the
benchmark's action and relationship expressions, reused as they are), ``sim`` (the scenes) and
``agents`` (the scene's action labels). Runs go through the ``storyteller`` command, never
through ``orchestrator`` internals.

Guarantee: a score depends only on the scenario file, the scene and the run's ``story.json``;
replaying a recorded trace reproduces the story log, hence the recorded score.
"""
