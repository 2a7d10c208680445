"""Config files hold finite, bounded numbers and are read within limits: ``backoff_base_s =
inf`` made the first retry sleep forever; nested TOML arrays and 5,000-digit integers escaped
as RecursionError / ValueError; a config at ``/dev/zero`` would be read forever. Each is one
``ConfigError`` (``MotionConfigError`` for motion configs), and one line with exit code 2
through ``storyteller model info``."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.config import MAX_CONFIG_BYTES, ConfigError, load_config
from storyteller.sim.motion.config import MotionConfigError, load_motion_config
from tests.support.finished_run import one_error_line

NESTED = "x = " + "[" * 5_000 + "]" * 5_000 + "\n"
LONG_INT = "seed = " + "9" * 5_000 + "\n"
DOTTED = "[llm]\n" + ".".join(["a"] * 50_000) + " = 1\n"  # tomllib: 1.5 GB and minutes (second hostile corpus)
HEADER = "[" + ".".join(["t"] * 30_000) + "]\n" + "".join(f"k{i} = 1\n" for i in range(60_000))


def write(tmp_path: Path, text: str, name: str = "storyteller.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("[llm.retry]\nbackoff_base_s = inf\n", "llm.retry.backoff_base_s"),
        ("[llm.retry]\nbackoff_base_s = nan\n", "llm.retry.backoff_base_s"),
        ("[llm.retry]\nbackoff_max_s = 1e9\n", "llm.retry.backoff_max_s"),
        ("[nodes.narrator.retry]\nbackoff_base_s = 1e308\n", "nodes.narrator.retry.backoff_base_s"),
        ("[llm]\ntimeout_s = inf\n", "llm.timeout_s"),
        ("[llm]\ntimeout_s = 1e12\n", "llm.timeout_s"),
        ("[llm]\ntemperature = nan\n", "llm.temperature"),
        ("[llm.retry]\nseed = 99999999999999999999999\n", "llm.retry.seed"),
    ],
)
def test_numbers_are_finite_and_bounded(tmp_path: Path, text: str, field: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text), env={})
    assert info.value.field == field and "\n" not in str(info.value)


def test_an_infinite_timeout_from_the_environment_names_the_variable() -> None:
    with pytest.raises(ConfigError, match="STORYTELLER_NARRATOR_TIMEOUT_S"):
        load_config(None, env={"STORYTELLER_NARRATOR_TIMEOUT_S": "inf"})


@pytest.mark.parametrize(
    ("text", "words"),
    [(NESTED, "nested too deeply"), (LONG_INT, "not valid TOML"), ("a = 1\n" + "#" * MAX_CONFIG_BYTES, "allowed"),
     (DOTTED, "50000 dotted parts"), (HEADER, "30000 dotted parts")],
)
def test_files_the_toml_reader_cannot_take(tmp_path: Path, text: str, words: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=words) as info:
        load_config(path, env={})
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    one_error_line(CliRunner().invoke(app, ["model", "info", "--config", str(path)]), words)


def test_a_device_or_a_folder_is_not_a_config(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config("/dev/zero", env={})
    with pytest.raises(ConfigError, match="folder"):
        load_config(tmp_path, env={})
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b"[llm]\nmodel = '\xff'\n")
    with pytest.raises(ConfigError, match="UTF-8"):
        load_config(latin, env={})


# ----- motion configs ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('[[clips]]\nfile = "a.bvh"\nlabel = "walk"\nfps = inf\n', "finite"),
        ('[[clips]]\nfile = "a.bvh"\nlabel = "walk"\nstart = 99999999999999\n', "less than"),
        ("[weights]\nfeet = nan\n", "finite"),
        (NESTED, "nested too deeply"),
        (LONG_INT, "not valid TOML"),
        (DOTTED, "dotted parts"),
    ],
)
def test_motion_configs_are_bounded(tmp_path: Path, text: str, words: str) -> None:
    path = write(tmp_path, text, "motion.toml")
    with pytest.raises(MotionConfigError, match=words) as info:
        load_motion_config(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_a_device_is_not_a_motion_config() -> None:
    with pytest.raises(MotionConfigError, match="not a regular file"):
        load_motion_config("/dev/zero")
