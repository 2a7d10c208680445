"""A scripted OpenAI-compatible chat-completions server on 127.0.0.1, shared by the tests that
drive the real litellm -> openai SDK -> httpx path (``tests/orchestrator/llm/test_llm_faults.py``,
``tests/orchestrator/cli/test_ablations_cli.py``, ``tests/benchmark/test_planning_benchmark.py``).

Tests and the speed scripts (``benchmark/bench_replay.py``, ``bench_long_run.py``,
``bench_frame_interval.py``) import it as ``from storyteller.benchmark.support.fake_openai_server import
FakeOpenAI``. The file name does not match ``test_*.py``, so pytest does not collect it.

Every ``POST`` (whatever the path; litellm posts to ``<base>/chat/completions``) is recorded
and answered with one *action*. The action comes from, in this order:

1. ``responder(body)``, if the server was built with one: a function of the decoded JSON
   request body that returns an action (used to answer by request content);
2. ``script[model]``: a list of actions for requests naming that model, one per request, in
   order; the last one repeats;
3. ``default``, for a model with no script.

An action is a plain string (shorthand for ``("ok", text)``) or one of these tuples:

``("ok", text)``
    HTTP 200, a chat completion whose content is ``text`` and whose ``finish_reason`` is
    ``"stop"``. ``text`` need not be valid JSON: broken or empty JSON content is scripted
    this way.
``("length", text)``
    As ``ok``, with ``finish_reason`` ``"length"`` (a reply truncated at max_tokens).
``("status", code)``
    HTTP ``code`` with an OpenAI-style ``{"error": {...}}`` body (429, 500, 401, ...).
``("sleep", seconds)``
    Waits ``seconds``, then answers ``ok`` with ``default_sleep_reply``; a client timeout
    shorter than ``seconds`` sees a timeout. :meth:`FakeOpenAI.stop` cuts the wait short.
``("drop", None)``
    Shuts the connection down without any response (the client sees a dropped connection).
``("echo", code)``
    HTTP ``code`` echoing every request header: for 200, a chat completion whose content is the
    headers as JSON; otherwise an OpenAI-style error whose message quotes them (as a careless
    provider or proxy does with a rejected ``Authorization`` header).

With ``echo_headers=True`` every answer also carries the request headers: in an
``X-Echo-Request-Headers`` response header and an ``"echo"`` field of the JSON body.

Each completion reports usage ``prompt_tokens``/``completion_tokens`` of
:data:`PROMPT_TOKENS`/:data:`COMPLETION_TOKENS`.

Lifetime: the server socket is bound in ``__init__`` (so :attr:`FakeOpenAI.base` is known at
once) and served from :meth:`FakeOpenAI.start`. :meth:`FakeOpenAI.stop` is idempotent: it
stops serving, closes the listening socket (a later connection is refused) and joins the serving
thread and every request thread, so nothing is left open when a test ends. Use the server as a
context manager (``with FakeOpenAI() as fake: ...``) in a fixture, so it is stopped on teardown
even when the test fails; a test may call :meth:`FakeOpenAI.stop` early to prove that a replay
does not need the provider.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from types import TracebackType
from typing import Any

Action = str | tuple[str, Any]
"""A scripted answer to one request; see the module docstring."""

Responder = Callable[[dict[str, Any]], Action]
"""Chooses the action for a request from its decoded JSON body."""

PROMPT_TOKENS = 11
COMPLETION_TOKENS = 5
REQUEST_TIMEOUT_S = 30.0  # a request thread waiting on a silent client gives up after this


def completion(model: str, text: str, finish_reason: str = "stop") -> dict[str, Any]:
    """An OpenAI chat-completion response body with one assistant message."""
    return {
        "id": "x", "object": "chat.completion", "created": 0, "model": model,
        "choices": [{"index": 0, "finish_reason": finish_reason,
                     "message": {"role": "assistant", "content": text}}],
        "usage": {"prompt_tokens": PROMPT_TOKENS, "completion_tokens": COMPLETION_TOKENS,
                  "total_tokens": PROMPT_TOKENS + COMPLETION_TOKENS},
    }


class _Server(ThreadingHTTPServer):
    # request threads are joined by server_close() (block_on_close), not abandoned as daemons
    daemon_threads = False
    block_on_close = True


SHUTDOWN_POLL_S = 0.05
"""How often the serving thread checks for :meth:`FakeOpenAI.stop`, in seconds: ``stop`` waits up
to this long (socketserver's default, 0.5 s, cost every test that starts a server half a second)."""


class FakeOpenAI:
    """Scripted OpenAI chat-completions server on an ephemeral port of 127.0.0.1.

    Attributes:
        base: the API base URL, ``http://127.0.0.1:<port>/v1``.
        script: ``script[model]`` is the list of actions for requests to ``model`` (the name in
            the request body, e.g. ``"fake-a"`` for litellm's ``"openai/fake-a"``).
        requests: every decoded request body, in arrival order.
        auth: the ``Authorization`` header of every request (``None`` if absent), same order.
        headers: every request's headers (names in lower case), same order.
    """

    def __init__(self, *, default: Action = '{"ok": true}', responder: Responder | None = None,
                 default_sleep_reply: str = '{"ok": true}', echo_headers: bool = False) -> None:
        self.script: dict[str, list[Action]] = {}
        self.requests: list[dict[str, Any]] = []
        self.auth: list[str | None] = []
        self.headers: list[dict[str, str]] = []
        self.echo_headers = echo_headers
        self.default = default
        self.responder = responder
        self.default_sleep_reply = default_sleep_reply
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._server = _Server(("127.0.0.1", 0), self._handler_class())
        self.base = f"http://127.0.0.1:{self._server.server_address[1]}/v1"
        self._thread: threading.Thread | None = None
        self._closed = False

    # ----- lifetime -----------------------------------------------------------------------
    def start(self) -> FakeOpenAI:
        """Serve requests from a background thread."""
        if self._closed:
            raise RuntimeError("FakeOpenAI was stopped; build a new one")
        if self._thread is None:
            self._thread = threading.Thread(target=self._server.serve_forever, name="fake-openai",
                                            kwargs={"poll_interval": SHUTDOWN_POLL_S}, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close every socket and thread; calling it again does nothing."""
        if self._closed:
            return
        self._closed = True
        self._stopping.set()  # wake "sleep" actions now
        if self._thread is not None:
            self._server.shutdown()
            self._thread.join()
        self._server.server_close()  # closes the listening socket, joins the request threads

    def __enter__(self) -> FakeOpenAI:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # ----- what was asked -----------------------------------------------------------------
    def to(self, model: str) -> list[dict[str, Any]]:
        """The request bodies that named ``model``, in order."""
        with self._lock:
            return [r for r in self.requests if r["model"] == model]

    def count(self, model: str) -> int:
        """How many requests named ``model``."""
        return len(self.to(model))

    # ----- serving ------------------------------------------------------------------------
    def _record_and_choose(self, body: dict[str, Any], headers: dict[str, str]) -> Action:
        """Record one request and pick its action (atomically, so concurrent requests to one
        model still walk its script in order)."""
        with self._lock:
            model = body.get("model")
            seen = sum(1 for r in self.requests if r.get("model") == model)
            self.requests.append(body)
            self.auth.append(headers.get("authorization"))
            self.headers.append(headers)
            if self.responder is not None:
                return self.responder(body)
            actions = self.script.get(model) if isinstance(model, str) else None
            if not actions:
                return self.default
            return actions[min(seen, len(actions) - 1)]

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        outer = self

        class Handler(BaseHTTPRequestHandler):
            timeout = REQUEST_TIMEOUT_S

            def log_message(self, *args: Any) -> None:
                return None

            def do_POST(self) -> None:
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                headers = {name.lower(): value for name, value in self.headers.items()}
                self._echo: str | None = json.dumps(headers) if outer.echo_headers else None
                action = outer._record_and_choose(body, headers)
                arg: Any  # the reply text, a seconds count or an HTTP status, by kind
                kind, arg = ("ok", action) if isinstance(action, str) else action
                model = str(body.get("model"))
                if kind == "drop":
                    self.close_connection = True
                    with contextlib.suppress(OSError):
                        self.connection.shutdown(socket.SHUT_RDWR)
                    return
                if kind == "sleep":
                    if outer._stopping.wait(arg):
                        return  # the server is stopping; nobody waits for this answer
                    kind, arg = "ok", outer.default_sleep_reply
                if kind == "echo":
                    self._echo = json.dumps(headers)
                    if arg == 200:
                        kind, arg = "ok", self._echo
                    else:
                        self._send(arg, {"error": {"message": f"rejected request with headers {self._echo}",
                                                   "type": "fake", "code": arg}})
                        return
                if kind == "status":
                    self._send(arg, {"error": {"message": f"scripted {arg}", "type": "fake", "code": arg}})
                elif kind in ("ok", "length"):
                    self._send(200, completion(model, arg, "length" if kind == "length" else "stop"))
                else:
                    raise ValueError(f"unknown FakeOpenAI action {kind!r}")

            def _send(self, code: int, payload: dict[str, Any]) -> None:
                if self._echo is not None:
                    payload = {**payload, "echo": self._echo}
                data = json.dumps(payload).encode()
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    self.send_response(code)
                    self.send_header("Content-Type", "application/json")
                    if self._echo is not None:
                        self.send_header("X-Echo-Request-Headers", self._echo)
                    self.send_header("Content-Length", str(len(data)))
                    self.end_headers()
                    self.wfile.write(data)

        return Handler
