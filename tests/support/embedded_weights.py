"""The embedded model as the tests that run it see it: skipped, with the one-line reason, when
llama-cpp-python or the Qwen 0.5B weights are not installed (never an error)."""

from __future__ import annotations

import pytest

from storyteller.orchestrator.llm.model_weights import QWEN_05B, WeightsMissingError, locate_chunks


def embedded_weights_or_skip() -> None:
    """Skip the calling test unless llama-cpp-python and the 0.5B weights are installed."""
    try:
        import llama_cpp  # noqa: F401
    except ImportError:
        pytest.skip("llama-cpp-python is not installed (pip install -e '.[local]')")
    try:
        locate_chunks(QWEN_05B)
    except WeightsMissingError as exc:
        pytest.skip(f"embedded weights not installed: {exc}")
