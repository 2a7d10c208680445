"""The LLM edge: run config, the litellm client with our retry policy and fallbacks, the embedded
llama.cpp model and its verified weights, trace files and replay, and a port wrapper that reports
each call's start and end (``watched_port``, for a live view).
"""
