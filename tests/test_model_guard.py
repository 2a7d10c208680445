"""The guard at the LLM port (tests/conftest.py): a test not marked ``embedded_model`` that
constructs the embedded model (``llama_cpp.Llama``, as ``storyteller.orchestrator.llm.local_model.get_llama``
does) fails with :class:`EmbeddedModelRefusedError`, even when it catches the error; a marked
test reaches llama.cpp. Checked in a child pytest session that uses this repository's conftest."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

pytest.importorskip("llama_cpp")

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent

CHILD = '''
import llama_cpp
import pytest

from storyteller.orchestrator.llm import local_model
from storyteller.orchestrator.llm.model_weights import QWEN_05B


def test_unmarked_constructs_llama(tmp_path):
    llama_cpp.Llama(model_path=str(tmp_path / "none.gguf"), verbose=False)


def test_unmarked_loads_through_the_provider(tmp_path, monkeypatch):
    weights = tmp_path / "weights.gguf"
    weights.write_bytes(b"not a model")
    monkeypatch.setattr(local_model, "verified_weights_path", lambda spec: weights)
    local_model.get_llama(QWEN_05B, "guard-test")


def test_unmarked_swallows_the_refusal(tmp_path):
    try:
        llama_cpp.Llama(model_path=str(tmp_path / "none.gguf"), verbose=False)
    except Exception:
        pass


@pytest.mark.embedded_model
def test_marked_reaches_llama_cpp(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        llama_cpp.Llama(model_path=str(tmp_path / "none.gguf"), verbose=False)
'''


def _ini(markers: list[str]) -> str:
    listed = ", ".join(repr(m) for m in markers)
    return (
        '[tool.pytest.ini_options]\naddopts = "--strict-markers"\nasyncio_default_fixture_loop_scope = "function"\n'
        f"markers = [{listed}]\n"
    )


@pytest.mark.slow
def test_an_unmarked_test_is_refused_the_embedded_model_and_a_marked_one_is_not(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the copied conftest imports tests.support (the one-name guard): the child finds it at the root
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    pytester.makepyprojecttoml(_ini(config["tool"]["pytest"]["ini_options"]["markers"]))
    pytester.makeconftest((TESTS / "conftest.py").read_text(encoding="utf-8"))
    pytester.makepyfile(test_guarded=CHILD)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=3)
    result.stdout.fnmatch_lines([
        "*_ test_unmarked_constructs_llama _*",
        "E *conftest.EmbeddedModelRefusedError: llama_cpp.Llama(model_path=*none.gguf*) refused: only a test marked*",
        "*_ test_unmarked_loads_through_the_provider _*",
        "E *conftest.EmbeddedModelRefusedError: llama_cpp.Llama(model_path=*weights.gguf*) refused*",
        "*_ test_unmarked_swallows_the_refusal _*",
        "E *conftest.EmbeddedModelRefusedError: the test passed only because it caught the refusal*",
    ])
