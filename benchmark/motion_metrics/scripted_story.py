"""``python -m storyteller.benchmark.motion_metrics.scripted_story RUN_DIR``: the scripted home story the
motion metrics are published on, built by the product itself (no LLM, no network).

The story: ``storyteller run home --names Zoe,Max,Ava --planner unified --description
object-list`` (foot IK on, lockstep pace, seed 0, 90 simulated s). Its planner's model is a
small OpenAI-compatible server on 127.0.0.1 in this process (:class:`ScriptedServer`) that
answers every request with an event program for the first free character of the request, each
character cycling through its list of :data:`TASKS` (``use_*``, ``open_fridge``,
``take_out_book``, ``turn_on_record_player``, and seated ``drink`` / ``eat`` / ``read_book`` /
``watch_tv`` / ``use_laptop``). The answers depend only on the requests and the lockstep session
waits for each one, so the run folder is the same on every build (its ``trace.jsonl`` replays it
with ``storyteller replay RUN_DIR --out DIR``).

``python -m storyteller.benchmark.motion_metrics --scripted-story RUN_DIR --out OUT`` builds it and measures
it in one command. Exit code 2 on a user error (one line), else the run's own exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import subprocess
import sys
import threading
from collections.abc import Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

SCENE = "home"
NAMES = ("Zoe", "Max", "Ava")
SECONDS = 90.0
TASKS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "Zoe": (
        ("get_area_to_interact_with", "coffee_maker_1", "use_coffee_maker"),
        ("get_area_to_sit_on", "couch_1", "drink"),
        ("get_area_to_interact_with", "microwave_1", "use_microwave"),
        ("get_area_to_sit_on", "chair_5", "use_laptop"),
        ("get_area_adjacent_to", "bookshelf_1", "take_out_book"),
    ),
    "Max": (
        ("get_area_to_interact_with", "toaster_1", "use_toaster"),
        ("get_area_to_sit_on", "armchair_1", "watch_tv"),
        ("get_area_to_interact_with", "dishwasher_1", "use_dishwasher"),
        ("get_area_to_interact_with", "fridge_1", "open_fridge"),
        ("get_area_to_sit_on", "chair_2", "eat"),
    ),
    "Ava": (
        ("get_area_to_interact_with", "record_player_1", "turn_on_record_player"),
        ("get_area_to_sit_on", "chair_1", "eat"),
        ("get_area_to_interact_with", "coffee_maker_1", "use_coffee_maker"),
        ("get_area_to_sit_on", "couch_1", "read_book"),
        ("get_area_to_interact_with", "toaster_1", "use_toaster"),
    ),
}
"""Per character, in order and then again: (where-function, object, target action)."""
KEY_ENV = "STORYTELLER_SCRIPTED_STORY_KEY"
"""The environment variable the run's config names for its API key (a dummy value)."""
_FREE = re.compile(r"Free characters: (.*)")


class StoryBuildError(Exception):
    """The scripted story cannot be built (one line)."""


class ScriptedPlanner:
    """Answers a planner request with the next task of its first free character."""

    def __init__(self) -> None:
        self.counts = dict.fromkeys(TASKS, 0)
        self.requests = 0
        self._lock = threading.Lock()

    def __call__(self, body: dict[str, Any]) -> str:
        texts = [str(m.get("content", "")) for m in body.get("messages", []) if isinstance(m, dict)]
        asked = [t for t in texts if "Free characters: " in t]
        if not asked:
            raise ValueError("not a planner request: no 'Free characters:' line")
        name = _FREE.findall(asked[-1])[-1].split(",")[0].strip()
        if name not in TASKS:
            raise ValueError(f"no tasks for character {name!r}")
        with self._lock:
            self.requests += 1
            where, obj, action = TASKS[name][self.counts[name] % len(TASKS[name])]
            self.counts[name] += 1
        return (
            f'```python\ndef parse_event():\n    a = get_character("{name}")\n    a.set_position({where}("{obj}"))\n'
            f'    a.set_target_action("{action}")\n```'
        )


def _completion(model: str, text: str) -> dict[str, Any]:
    return {
        "id": "scripted", "object": "chat.completion", "created": 0, "model": model,
        "choices": [{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": text}}],
        "usage": {"prompt_tokens": 0, "completion_tokens": 0, "total_tokens": 0},
    }  # fmt: skip


class _Server(ThreadingHTTPServer):
    daemon_threads = False
    block_on_close = True


class ScriptedServer:
    """An OpenAI-compatible chat-completion endpoint on 127.0.0.1 answered by ``planner``
    (every POST, whatever the path); a request it cannot answer gets HTTP 400. A context manager."""

    def __init__(self, planner: ScriptedPlanner) -> None:
        outer = planner

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:
                pass

            def do_POST(self) -> None:
                try:
                    body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", "0"))))
                    code, payload = 200, _completion(str(body.get("model")), outer(body))
                except (ValueError, AttributeError, IndexError) as exc:
                    code, payload = 400, {"error": {"message": str(exc), "type": "scripted", "code": 400}}
                data = json.dumps(payload).encode()
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    self.send_response(code)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
                    self.end_headers()
                    self.wfile.write(data)

        self._server = _Server(("127.0.0.1", 0), Handler)
        self.base = f"http://127.0.0.1:{self._server.server_address[1]}/v1"
        self._thread = threading.Thread(target=self._server.serve_forever, name="scripted-llm", daemon=True)

    def __enter__(self) -> ScriptedServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()


def write_config(path: Path, api_base: str) -> Path:
    """The run config of the scripted model (one attempt per call: the server never fails)."""
    path.write_text(
        f'[llm]\nmodel = "openai/scripted"\napi_base = "{api_base}"\napi_key_env = "{KEY_ENV}"\n'
        "timeout_s = 60.0\n[llm.retry]\nmax_attempts = 1\nbackoff_base_s = 0.05\nbackoff_max_s = 0.1\n",
        encoding="utf-8",
    )
    return path


def build_story(
    out: Path, *, seconds: float = SECONDS, names: Sequence[str] = NAMES, seed: int = 0, quiet: bool = False
) -> int:
    """Run the scripted story into ``out`` (a new or empty folder); the run's exit code.

    The run config is written next to ``out`` (``<out>.scripted.toml``): the run's ``run.json``
    names it, and ``storyteller replay`` reads it again. Raises :class:`StoryBuildError` on a
    folder that already holds something, an unknown name or a duration that is not positive."""
    if not (seconds > 0 and seconds < 1e6):
        raise StoryBuildError(f"story duration must be a positive number of seconds, not {seconds!r}")
    unknown = [n for n in names if n not in TASKS]
    if unknown or not names or len(set(names)) != len(names):
        raise StoryBuildError(f"story characters must be distinct names among {', '.join(TASKS)}: {', '.join(names)}")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise StoryBuildError(f"{out}: already exists and is not an empty folder (choose a new one)")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoryBuildError(f"{out.parent}: cannot create ({exc.strerror})") from None
    env = {k: v for k, v in os.environ.items() if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL")}
    env[KEY_ENV] = "scripted"  # not a secret: the local scripted server ignores it
    planner = ScriptedPlanner()
    with ScriptedServer(planner) as server:
        config = write_config(out.parent / f"{out.name}.scripted.toml", server.base)
        command = [
            sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()", "run", SCENE, "--names", ",".join(names),
            "--planner", "unified", "--description", "object-list", "--seed", str(seed),
            "--no-interactive", "--no-live", "-d", f"{seconds:g}", "--config", str(config), "--out", str(out),
        ]  # fmt: skip
        done = subprocess.run(command, env=env, check=False, capture_output=quiet)
    return done.returncode


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.motion_metrics.scripted_story", description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path, help="run folder to build (new or empty)")
    p.add_argument("-d", "--duration", type=float, default=SECONDS, help="simulated seconds (default 90)")
    p.add_argument("--names", default=",".join(NAMES), help="characters, among Zoe,Max,Ava (default all three)")
    p.add_argument("--seed", type=int, default=0)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return build_story(args.out, seconds=args.duration, names=[n.strip() for n in args.names.split(",")], seed=args.seed)
    except StoryBuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
