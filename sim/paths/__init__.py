"""Paths: the navigation grid, space-time A* kernels, the windowed cooperative planner with its
fallback, and frame-by-frame path following for many walkers.

Pure and deterministic: the same grid, starts, goals and seed give the same plans.
"""
