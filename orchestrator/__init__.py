"""The edge: LLM providers and traces (``llm``), the langgraph planning graph (``planning``), the
story session that runs simulation and planning together (``session``) and the command line
(``cli``).

May import ``sim``, ``tools`` and ``agents``; reads the environment, the clock and files here
and passes what it read down as arguments.
"""
