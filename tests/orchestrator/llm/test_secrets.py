"""Secrets stay secret: an API key (and any other secret-named environment variable) never
appears in a trace, a log, a story file or an error message, even when the provider echoes
every request header back, in a reply or in a 401 body.

``storyteller plan`` and ``storyteller run`` run as real processes (so their structlog output
is captured as a user sees it) against the fake OpenAI server on 127.0.0.1, with a canary key
in ``OPENAI_API_KEY`` named by the config's ``api_key_env``; then every file they wrote, their
stdout and stderr are searched for the canary.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.llm.secrets import REDACTED, redact, secret_values

ROOT = Path(__file__).resolve().parents[3]
CANARY = "sk-canary-5f3a9c1e7d2b4a60b8e1"
OTHER = "tok-canary-other-9a8b7c6d5e"  # a secret-named variable no node uses
COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)
ABLATION = ["--planner", "unified", "--description", "object-list"]


@pytest.fixture
def fake() -> Iterator[FakeOpenAI]:
    with FakeOpenAI(default='{"error": "no script"}', echo_headers=True) as server:
        yield server


def config(tmp_path: Path, base: str) -> Path:
    path = tmp_path / "fake.toml"
    path.write_text(
        "\n".join([
            "[llm]", f'api_base = "{base}"', 'api_key_env = "OPENAI_API_KEY"', "timeout_s = 10.0",
            "[llm.retry]", "max_attempts = 1",
            "[nodes.planner]", 'model = "openai/fake-planner"',
        ]) + "\n",
        encoding="utf-8",
    )
    return path


def storyteller(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("STORYTELLER_")}
    env.update(OPENAI_API_KEY=CANARY, MY_SERVICE_TOKEN=OTHER, PYTHONPATH=str(ROOT),
               STORYTELLER_CACHE_DIR=str(tmp_path / "cache"))
    return subprocess.run([sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300, check=False)


def leaks(tmp_path: Path, result: subprocess.CompletedProcess[str]) -> list[str]:
    """Where a canary appears: output streams and every file under ``tmp_path``."""
    found = [name for name, text in (("stdout", result.stdout), ("stderr", result.stderr))
             if CANARY in text or OTHER in text]
    for path in sorted(tmp_path.rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            if CANARY.encode() in data or OTHER.encode() in data:
                found.append(str(path.relative_to(tmp_path)))
    return found


@pytest.mark.slow
def test_the_fake_provider_really_saw_and_echoed_the_key(fake: FakeOpenAI, tmp_path: Path) -> None:
    """The premise: without redaction the key would reach the client (else the tests below prove nothing)."""
    fake.script["fake-planner"] = [("echo", 200), COFFEE]
    result = storyteller(tmp_path, "plan", "home", *ABLATION, "--config", str(config(tmp_path, fake.base)),
                         "--record", str(tmp_path / "trace.jsonl"), "--runs-db", str(tmp_path / "runs.sqlite"))
    assert result.returncode == 0, result.stderr
    assert fake.headers[0]["authorization"] == f"Bearer {CANARY}"
    trace = (tmp_path / "trace.jsonl").read_text(encoding="utf-8")
    assert "authorization" in trace and REDACTED in trace  # the echoed headers were traced, the key was not
    assert leaks(tmp_path, result) == []


@pytest.mark.slow
def test_storyteller_run_keeps_the_key_out_of_every_output(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-planner"] = [("echo", 200), COFFEE]
    out = tmp_path / "out"
    result = storyteller(tmp_path, "run", "home", "-n", "2", "-d", "2", "--max-events", "1", *ABLATION,
                         "--config", str(config(tmp_path, fake.base)), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert (out / "trace.jsonl").is_file() and (out / "story.md").is_file()
    assert all(h["authorization"] == f"Bearer {CANARY}" for h in fake.headers)
    assert leaks(tmp_path, result) == []


@pytest.mark.slow
def test_a_401_quoting_the_key_is_reported_without_it(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-planner"] = [("echo", 401)]
    trace = tmp_path / "trace.jsonl"
    result = storyteller(tmp_path, "plan", "home", *ABLATION, "--config", str(config(tmp_path, fake.base)),
                         "--record", str(trace), "--runs-db", str(tmp_path / "runs.sqlite"))
    shown = result.stdout + result.stderr
    assert "Traceback" not in shown
    assert "failed" in result.stdout and "AuthenticationError" in shown, shown  # the step failed, saying why
    assert REDACTED in trace.read_text(encoding="utf-8")  # the echoed header, with the key removed
    assert leaks(tmp_path, result) == []


def test_secret_values_and_redact() -> None:
    env = {"OPENAI_API_KEY": CANARY, "MY_SERVICE_TOKEN": OTHER, "HOME": "/home/someone", "SHORT_KEY": "abc",
           "CUSTOM": "custom-value-123"}
    secrets = secret_values(["CUSTOM"], env)
    assert set(secrets) == {CANARY, OTHER, "custom-value-123"}  # named, secret-looking; not HOME, not short
    assert redact(f"Bearer {CANARY} and {OTHER}", secrets) == f"Bearer {REDACTED} and {REDACTED}"
    assert redact("nothing here", secrets) == "nothing here"


def test_the_program_worker_inherits_no_secret(monkeypatch: pytest.MonkeyPatch) -> None:
    """The worker runs untrusted programs: its process environment holds no key, whatever the parent's."""
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.tools.character_states import WorldView

    monkeypatch.setenv("OPENAI_API_KEY", CANARY)
    monkeypatch.setenv("MY_SERVICE_TOKEN", OTHER)
    with WorkerRunner() as runner:
        program = "def parse_event():\n    get_character('Mia').set_position(get_area_adjacent_to('fridge_1'))\n"
        assert runner(load_bundled_scene("home"), program, WorldView(), seed=0)
        assert runner.process is not None
        environ = Path(f"/proc/{runner.process.pid}/environ").read_bytes()
    assert b"PATH=" in environ  # the file was read, and holds the variables the worker needs
    assert CANARY.encode() not in environ and OTHER.encode() not in environ
