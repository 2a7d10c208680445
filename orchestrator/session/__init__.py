"""The application logic of a story: the ``plan`` job (:mod:`~storyteller.orchestrator.session.plan_job`,
K graph steps without a simulation; the planning benchmark runs it too), the ``run`` job
(:mod:`~storyteller.orchestrator.session.run_job`; what it reads and opens before the first frame in
:mod:`~storyteller.orchestrator.session.run_setup`, what it writes at the end in
:mod:`~storyteller.orchestrator.session.run_outputs`), the roster and its world view
(:mod:`~storyteller.orchestrator.session.roster`), opening the LLM port
(:mod:`~storyteller.orchestrator.session.port_setup`), the session runtime (simulation and planning in one
anyio task group: :mod:`~storyteller.orchestrator.session.runtime`; its data types in
:mod:`~storyteller.orchestrator.session.session_types`, the planner's view of the story in
:mod:`~storyteller.orchestrator.session.story_history`, the steps in flight in
:mod:`~storyteller.orchestrator.session.steps_in_flight`, the recorded requests a replay or a resume makes
again in :mod:`~storyteller.orchestrator.session.request_schedule`, the instructions waiting to take effect in
:mod:`~storyteller.orchestrator.session.instruction_queue`) and the step planner that drives the planning graph from a running
simulation; the run folder's ``run.json`` (:mod:`~storyteller.orchestrator.session.run_manifest`),
``story.md`` / ``metrics.json`` (:mod:`~storyteller.orchestrator.session.run_report`) and the session's
checkpoint file (:mod:`~storyteller.orchestrator.session.snapshot_file`); live instructions: the timed
script of ``--instructions FILE`` (:mod:`~storyteller.orchestrator.session.instruction_script`) and the
stdin reader of ``--interactive`` (:mod:`~storyteller.orchestrator.session.stdin_instructions`), or, under
the live view on the same terminal, the key-by-key prompt (:mod:`~storyteller.orchestrator.session.terminal_prompt`);
what a running story looks like now, for that live view (:mod:`~storyteller.orchestrator.session.run_status`).

May import ``storyteller.orchestrator.llm``, ``storyteller.orchestrator.planning``, ``agents``, ``tools`` and ``sim``;
never ``storyteller.orchestrator.cli`` (the commands call into here, not the other way round).
"""
