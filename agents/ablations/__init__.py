"""The agent-level pieces of the paper's ablations, as functions of explicit inputs.

- :mod:`storyteller.agents.ablations.unified` ("w/o Event"): the one request (node ``planner``) that
  writes a ``parse_event()`` for the free characters straight from the instruction and the
  story, and the check that turns its reply into a :class:`~storyteller.agents.messages.ParsedEvent` (or
  a wait);
- :mod:`storyteller.agents.ablations.direct` ("Direct Inference"): the event parser's request for
  coordinates instead of areas, and the check that turns them into an event program
  (:class:`~storyteller.tools.errors.BlockedPositionError` for a point nobody can stand on);
- :mod:`storyteller.agents.ablations.descriptions` (Object List, Scene Graph): scene descriptions that
  replace the describer's text.

Nothing here calls a model or loops over retries: the planning graph
(``storyteller.orchestrator.planning.ablation_graph``) makes every call, one per node, and feeds each
rejection back, exactly as it does for the full method. Imports: ``agents``, ``tools``, ``sim``.
"""
