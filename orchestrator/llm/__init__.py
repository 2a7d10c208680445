"""The LLM edge: run config, the litellm client with our retry policy and fallbacks, the embedded
llama.cpp model and its verified weights, trace files and replay.
"""
