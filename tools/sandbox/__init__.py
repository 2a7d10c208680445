"""The sandbox that runs LLM-written ``parse_event()`` programs: an allow-list AST interpreter
with step, size and time budgets. LLM code never runs through ``exec``.
"""
