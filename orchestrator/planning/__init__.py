"""The planning graph (langgraph): state, nodes, routers, variants for the paper's ablations,
and durable checkpoints with the story log.
"""
