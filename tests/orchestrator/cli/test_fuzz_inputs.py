"""Fuzzing the user's input files, bounded and deterministic: random and mutated scene files
(project JSON and reference annotation folders), config TOML files and benchmark case files
each load or fail with their one-line typed error (SceneFileError, ConfigError,
BenchmarkCaseError), never another exception; through the CLI, bad scene and config files end
with exit code 2 and one line, no traceback.

Every ``@settings`` here is ``derandomize=True`` (the same examples on every CI run) with a
fixed ``max_examples`` and no per-example deadline (a slow CI machine is not a failure).
Random event programs are fuzzed the same way in ``tests/tools/sandbox/test_sandbox_fuzz.py``.
"""

from __future__ import annotations

import copy
import json
import tempfile
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from storyteller.benchmark.reference_cases import BenchmarkCaseError, load_case
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.config import ConfigError, StorytellerConfig, load_config
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.errors import SceneFileError
from storyteller.sim.scene.files import load_scene, save_scene_json
from storyteller.sim.scene.model import Scene

ROOT = Path(__file__).resolve().parents[3]
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
CLI_FUZZ = settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**6), 10**6), st.integers(), st.floats(allow_nan=True),
    st.text(max_size=12),
)
json_values = st.recursive(
    scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)


def paths_of(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path to a value inside a JSON document (the root is ``()``)."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths_of(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += paths_of(v, (*prefix, i))
    return out


@st.composite
def mutated(draw: st.DrawFn, doc: Any, mutations: int = 3) -> Any:
    """``doc`` with a few values replaced by random JSON or removed."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, mutations))):
        paths = paths_of(doc)
        path = draw(st.sampled_from(paths))
        if not path:
            return draw(json_values)
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if draw(st.booleans()) and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(json_values)
    return doc


def dump(doc: Any) -> str:
    return json.dumps(doc, allow_nan=True)


def one_line(message: str) -> None:
    assert message and "\n" not in message and "Traceback" not in message, message


def _valid_scene_doc() -> Any:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        save_scene_json(load_bundled_scene("home"), path)
        doc = json.loads(path.read_text(encoding="utf-8"))
    doc["objects"] = doc["objects"][:3]  # small: fewer paths, faster loads
    return doc


SCENE_DOC = _valid_scene_doc()
REFERENCE_OBJECTS = [
    {"label": "chair", "idx": 1, "center": [1.0, 1.0, 0.45], "width": 0.5, "depth": 0.5, "height": 0.9,
     "orientation": [1.0, 0.0]},
    {"label": "table", "idx": 1, "center": [2.0, 1.0, 0.4], "width": 1.2, "depth": 0.8, "height": 0.8,
     "orientation": [0.0, 1.0]},
]
CASE_DOC = json.loads(next(iter(sorted((ROOT / "benchmark" / "cases" / "ours").rglob("*.json")))).read_text())


def load_or_typed_error(path: Path) -> Scene | SceneFileError:
    try:
        return load_scene(path)
    except SceneFileError as exc:
        one_line(str(exc))
        return exc


@FUZZ
@given(doc=st.one_of(json_values, mutated(SCENE_DOC)))
def test_a_random_scene_json_loads_or_is_a_scene_file_error(doc: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        path.write_text(dump(doc), encoding="utf-8")
        load_or_typed_error(path)


@FUZZ
@given(text=st.text(max_size=80) | st.binary(max_size=80).map(lambda b: b.decode("latin-1")))
def test_random_text_as_a_scene_file_is_a_scene_file_error(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        path.write_text(text, encoding="utf-8", errors="surrogateescape")
        assert isinstance(load_or_typed_error(path), SceneFileError | Scene)


@FUZZ
@given(
    objects=st.one_of(json_values, mutated(REFERENCE_OBJECTS)),
    scene=st.none() | st.one_of(json_values, mutated({"bbox": [[0.0, 0.0, 0.0], [4.0, 3.0, 2.5]]})),
    grid=st.none() | json_values,
)
def test_a_random_reference_folder_loads_or_is_a_scene_file_error(objects: Any, scene: Any, grid: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "room"
        folder.mkdir()
        (folder / "objects.json").write_text(dump(objects), encoding="utf-8")
        for name, doc in (("scene.json", scene), ("grid_map.json", grid)):
            if doc is not None:
                (folder / name).write_text(dump(doc), encoding="utf-8")
        load_or_typed_error(folder)


TOML_LINES = st.sampled_from([
    "[llm]", "[llm.retry]", "[nodes.narrator]", "[nodes.event_parser]", "[nodes.unknown]", "[nodes.narrator.retry]",
    'model = "openai/gpt-4o-mini"', 'model = ""', "model = 3", 'api_key_env = "OPENAI_API_KEY"',
    'api_key_env = "sk-abc"', 'api_key = "sk-abc"', 'token = "x"', "timeout_s = -1", "timeout_s = 1e309",
    "timeout_s = nan", "max_tokens = 0", "max_tokens = 99999999999999999999", "temperature = 9",
    'fallbacks = ["openai/a", 3]', "max_attempts = 0", "jitter = 2.0", "seed = -1", 'api_base = "http://x"',
    "[[nodes]]", "x = ", "= 1", '"unterminated', "[llm]\n[llm]", "a.b.c = 1", "\x00", "model = [[]]",
])


@FUZZ
@given(lines=st.lists(TOML_LINES | st.text(max_size=20), max_size=10))
def test_a_random_config_loads_or_is_a_config_error(lines: list[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "storyteller.toml"
        path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogateescape")
        try:
            assert isinstance(load_config(path, env={}), StorytellerConfig)
        except ConfigError as exc:
            one_line(str(exc))


@FUZZ
@given(doc=st.one_of(json_values, mutated(CASE_DOC, mutations=2)))
def test_a_random_case_file_loads_or_is_a_case_error(doc: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "testcase_1.json"
        path.write_text(dump(doc), encoding="utf-8")
        try:
            load_case(path)
        except BenchmarkCaseError as exc:
            one_line(str(exc))


# ----- through the CLI: exit code 2 and one line ------------------------------------------------
def bad(doc: Any) -> bool:
    """A scene document that does not load (the CLI examples are the rejected ones)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        path.write_text(dump(doc), encoding="utf-8")
        return isinstance(load_or_typed_error(path), SceneFileError)


@CLI_FUZZ
@given(doc=mutated(SCENE_DOC).filter(bad))
def test_scene_inspect_of_a_bad_scene_file_exits_2_with_one_line(doc: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        path.write_text(dump(doc), encoding="utf-8")
        result = CliRunner().invoke(app, ["scene", "inspect", str(path)])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, result.stderr


@CLI_FUZZ
@given(lines=st.lists(TOML_LINES, min_size=1, max_size=6))
def test_plan_with_a_bad_config_exits_2_with_one_line(lines: list[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "storyteller.toml"
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        try:
            load_config(path, env={})
            rejected = False
        except ConfigError:
            rejected = True
        if not rejected:
            return  # a valid config would start planning; only rejected ones are asked here
        result = CliRunner().invoke(app, ["plan", "home", "--config", str(path), "--runs-db", ":memory:"])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    lines_out = [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("thread ")]
    assert len(lines_out) == 1 and "Traceback" not in result.output, result.stderr


def test_the_mutations_reach_both_outcomes() -> None:
    """The fuzzers are not vacuous: the valid documents load, and a broken one is rejected."""
    assert not bad(SCENE_DOC)
    assert bad({**SCENE_DOC, "objects": "none"})
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "objects.json").write_text(dump(REFERENCE_OBJECTS), encoding="utf-8")
        assert isinstance(load_or_typed_error(Path(tmp)), Scene)
    assert isinstance(load_case(next(iter(sorted((ROOT / "benchmark" / "cases" / "ours").rglob("*.json"))))).id, int)
