"""Paths: the navigation grid, space-time A* kernels, the windowed cooperative planner with its
fallback, and frame-by-frame path following for many walkers.

Pure and deterministic: the same grid, starts, goals and seed give the same plans.

The planner (``cooperative_astar``, the import path of its public names) is built from
``plan_types``, ``clearance``, ``move_tables``, ``static_bodies``, ``heuristics``,
``usable_goals``, ``reservations``, ``compiled_backend`` (on ``astar_kernel``) and
``python_backend``; ``fallback`` reorders failed agents; ``following`` and ``tracks`` turn
plans into frame-by-frame motion.
"""
