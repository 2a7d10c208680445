"""The runtime of a story session: simulation and planning in one anyio task group, the step
planner that drives the planning graph from a running simulation, and the plan / run jobs.
"""
