"""Motion quality the way motion papers report it, over run folders and a crowd.

``python -m storyteller.benchmark.motion_metrics RUN_DIR ... --out DIR`` prints the tables and writes
``report.md``, ``metrics.json`` and PNG figures into ``DIR`` (``__main__``). One module per
family of measure, each measure a pure function on arrays (metres, seconds, z up, the
22-joint skeleton of :mod:`storyteller.sim.body.skeleton`):

- :mod:`.feet`: foot skating ratio (GMD's definition, at 20 fps), floor penetration and float;
- :mod:`.bodies`: body-furniture penetration (spheres along limb capsules against the scene's
  object boxes) and body-body overlap between characters;
- :mod:`.gait`: walking windows, pelvis sway, arm swing, step length; jerk, bob, cadence and
  speed come from :func:`storyteller.benchmark.motion_quality.motion_stats` (not measured twice), all
  against the real walks at the same speed;
- :mod:`.interactions`: hand-to-object distance at the reach frame, seat-height error, sit
  down / stand up times (facing comes from :mod:`storyteller.benchmark.motion_facing`);
- :mod:`.partners`: pairs sent to chat, shake hands and hug: their distance, facing and a
  handshake's hands;
- :mod:`.sources`: what is measured (run folders, a crowd of walkers without an LLM, the real
  clips), :mod:`.strips`: side and top views per action label, :mod:`.report`: tables.

May import ``sim``, ``tools``, ``orchestrator`` and other ``benchmark`` modules; never
``tests`` (issue 26). Reads the real clips in place through ``storyteller.orchestrator.reference_data``.
"""
