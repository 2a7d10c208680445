"""The simulation: scenes, paths, motion, bodies, the world step and exports.

The lowest floor: imports nothing from ``tools``, ``agents``, ``orchestrator`` or
``benchmark``, and never reads a clock, the network or the environment. Every update is a
function of explicit inputs (including ``dt`` / fps and a seed), so the same commands give the
same frames. Sub-packages: ``scene``, ``paths``, ``motion`` (with ``motion.sources``), ``body``,
``world``, ``export``.
"""
