"""The application logic of a story: the ``plan`` job (:mod:`~orchestrator.session.plan_job`,
K graph steps without a simulation; the planning benchmark runs it too), the ``run`` job
(:mod:`~orchestrator.session.run_job`; what it reads and opens before the first frame in
:mod:`~orchestrator.session.run_setup`, what it writes at the end in
:mod:`~orchestrator.session.run_outputs`), the roster and its world view
(:mod:`~orchestrator.session.roster`), opening the LLM port
(:mod:`~orchestrator.session.port_setup`), the session runtime (simulation and planning in one
anyio task group: :mod:`~orchestrator.session.runtime`; its data types in
:mod:`~orchestrator.session.session_types`, the planner's view of the story in
:mod:`~orchestrator.session.story_history`, the steps in flight in
:mod:`~orchestrator.session.steps_in_flight`, the recorded requests a replay or a resume makes
again in :mod:`~orchestrator.session.request_schedule`, the instructions waiting to take effect in
:mod:`~orchestrator.session.instruction_queue`) and the step planner that drives the planning graph from a running
simulation; the run folder's ``run.json`` (:mod:`~orchestrator.session.run_manifest`),
``story.md`` / ``metrics.json`` (:mod:`~orchestrator.session.run_report`) and the session's
checkpoint file (:mod:`~orchestrator.session.snapshot_file`); live instructions: the timed
script of ``--instructions FILE`` (:mod:`~orchestrator.session.instruction_script`) and the
stdin reader of ``--interactive`` (:mod:`~orchestrator.session.stdin_instructions`), or, under
the live view on the same terminal, the key-by-key prompt (:mod:`~orchestrator.session.terminal_prompt`);
what a running story looks like now, for that live view (:mod:`~orchestrator.session.run_status`).

May import ``orchestrator.llm``, ``orchestrator.planning``, ``agents``, ``tools`` and ``sim``;
never ``orchestrator.cli`` (the commands call into here, not the other way round).
"""
