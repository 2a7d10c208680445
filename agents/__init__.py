"""The three LLM roles (describer, narrator, event parser) and the paper's ablations, behind
one LLM port (``storyteller.agents.llm_port.LLMPort``).

Imports ``sim`` and ``tools`` only: no langgraph, no litellm, no clock. Each role builds typed
requests and judges typed replies; the planning graph in ``storyteller.orchestrator.planning`` decides
when to call, retry and record.
"""
