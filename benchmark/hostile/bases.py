"""What the attacks start from: the one-run bench sweep of our case 100 against a scripted
OpenAI-compatible server on 127.0.0.1 (:func:`build_sweep`), the clean command each attacked
command is timed against (:data:`BASE_COMMANDS`) and the temporary folder (:func:`workspace`).
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from storyteller.benchmark.hostile.harness import CLI


class _ScriptedBench(BaseHTTPRequestHandler):
    """The bench sweep's model: the describer, narrator and event parser of case 100."""

    NARRATION = json.dumps({"reasoning": "asked", "event": {"characters": ["Ines"], "activity": "type notes on the laptop"}})
    PROGRAM = ('```python\ndef parse_event():\n    a = get_character("Ines")\n'
               '    a.set_position(get_area_to_sit_on("chair_5"))\n    a.set_target_action("use_laptop")\n```')

    def log_message(self, *args: Any) -> None:
        pass

    def do_POST(self) -> None:
        body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", "0"))))
        system = str(body["messages"][0].get("content", ""))
        text = ("{}" if system.startswith("You describe") else self.NARRATION if system.startswith("You are the narrator")
                else self.PROGRAM)
        data = json.dumps({"id": "s", "object": "chat.completion", "created": 0, "model": body.get("model"),
                           "choices": [{"index": 0, "finish_reason": "stop",
                                        "message": {"role": "assistant", "content": text}}],
                           "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2}}).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)


def build_sweep(root: Path, env: dict[str, str]) -> Path:
    server = ThreadingHTTPServer(("127.0.0.1", 0), _ScriptedBench)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        config = root / "bench.toml"
        config.write_text(f'[llm]\nmodel = "openai/scripted"\napi_base = "http://127.0.0.1:{server.server_address[1]}/v1"\n'
                          'api_key_env = "STORYTELLER_SCRIPTED_STORY_KEY"\n[llm.retry]\nmax_attempts = 1\n',
                          encoding="utf-8")
        sweep = root / "sweep-base"
        done = subprocess.run([*CLI, "bench", "run", "--cases", "ours", "--case-id", "100", "--method", "ours",
                               "--config", str(config), "--out", str(sweep)], env=env, capture_output=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"error: the base sweep failed: {done.stderr.decode(errors='replace')[-400:]}")
    finally:
        server.shutdown()
        server.server_close()
    return sweep


BASE_COMMANDS: dict[str, Callable[[Path, Path, Path], list[str]]] = {
    "resume": lambda root, base, sweep: ["resume", str(root / "clean-resume"), "--no-interactive", "--no-live"],
    "replay": lambda root, base, sweep: ["replay", str(base), "--out", str(root / "clean-replay"), "--no-live"],
    "view --export": lambda root, base, sweep: ["view", str(base), "--export", str(root / "clean.html")],
    "scene inspect": lambda root, base, sweep: ["scene", "inspect", "home"],
    "bench score": lambda root, base, sweep: ["bench", "score", str(root / "clean-sweep")],
    "model info": lambda root, base, sweep: ["model", "info"],
    "event-program": lambda root, base, sweep: ["event-program", "home", "--program", str(root / "clean.py")],
    "run": lambda root, base, sweep: ["scene", "inspect", "home"],  # a bad file is refused before any planning
    "plan": lambda root, base, sweep: ["scene", "inspect", "home"],  # the same
}


@contextlib.contextmanager
def workspace(keep: bool) -> Iterator[Path]:
    root = Path(tempfile.mkdtemp(prefix="hostile-"))
    try:
        yield root
    finally:
        if keep:
            print(f"kept {root}", file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)
