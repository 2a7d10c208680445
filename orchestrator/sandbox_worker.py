"""Event programs in a worker process with OS limits: defence in depth around the sandbox.

``WorkerRunner`` is a ``ProgramRunner`` (``run_event_program``'s signature) that runs each
program in one long-lived child process (``python -m storyteller.orchestrator.sandbox_worker``) instead
of in-process. The child keeps the interpreter's own ``Budget`` and adds what only the OS can
enforce: an address-space limit (``RLIMIT_AS``), a CPU-time limit per program
(``RLIMIT_CPU``, re-armed before each program) and, from the parent, a kill when the worker
used more than ``run_seconds`` of CPU time on one program, or did not answer within
``wall_seconds`` of wall-clock time, a backstop several times larger
(``storyteller.orchestrator.worker_deadline``: CPU time, so a busy machine does not stop a
program that waited for a core).
A cost the interpreter fails to count therefore ends in ``BudgetExceededError`` for that
program, never in a stalled story or a machine out of memory.

Why here and not in ``tools/sandbox``: spawning and killing processes, setting limits and
waiting on a clock are environment effects; ``tools/`` stays pure (no clock, no processes),
and only ``orchestrator/`` may own them.

What crosses the boundary is plain data, JSON in length-prefixed frames on the child's
stdin / a private stdout (never pickle: the child runs untrusted programs, so the parent
never unpickles what it sends): the program text, the world view, the seed, the labels and
the budget one way; plans or a typed error (class name, feedback, line, steps) back. The
scene crosses once per scene per worker: requests name it by the SHA-256 of its JSON, the
child keeps the last ``SCENES_KEPT`` scenes (with their scene graphs) and answers
``need_scene`` for one it lacks, and the parent then sends it. Loading a scene also builds
what the position sampler needs for it (navigation grid, compiled kernels), outside every
program's budget and CPU limit. The child is reused across programs (no process start on the
hot path) and restarted when it dies or is killed; it starts with the first program, or ahead
of it with ``prestart()`` (its imports then overlap the caller's set-up); ``prestart(scene)``
also sends it that scene as its first message (``--scene-first``), loaded before it says it
is ready, so a run's first planning step does not wait for the scene either. It
inherits only :data:`WORKER_ENV` from the parent's environment, never an API key. Its stderr is
a pipe, never the terminal's: drained and bounded (``storyteller.orchestrator.stderr_tail``), and what it
wrote (a traceback from a crash) is logged escaped when the worker stops.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import select
import struct
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import asdict
from typing import IO, TYPE_CHECKING, Any, Self

from storyteller.orchestrator.stderr_tail import StderrTail
from storyteller.orchestrator.worker_deadline import (
    RUN_SECONDS,
    WALL_SECONDS,
    await_answer,
    process_cpu_seconds,
)
from storyteller.sim.scene.model import Scene
from storyteller.tools import errors as tool_errors
from storyteller.tools.character_states import CharacterPlan, WorldView
from storyteller.tools.errors import EventProgramError
from storyteller.tools.sandbox import Budget, BudgetExceededError
from storyteller.tools.sandbox import errors as sandbox_errors

if TYPE_CHECKING:
    from storyteller.tools.scene_graph import SceneGraph

ADDRESS_SPACE_BYTES = 2**30
"""``RLIMIT_AS`` of the worker (the runtime with numpy and a scene uses about 200 MiB of it)."""
CPU_SECONDS = 4
"""``RLIMIT_CPU`` seconds per program (re-armed from the worker's CPU time so far)."""
START_SECONDS = 60.0
"""Seconds a new worker may take to import its modules, and a scene to load (not counted
against any program's limits)."""
SCENES_KEPT = 4
"""Scenes (with their scene graphs) the worker keeps loaded."""
MAX_FRAME = 64 * 2**20
"""Largest message either side accepts (bytes)."""
_HEADER = struct.Struct(">Q")
WORKER_ENV = ("PATH", "PYTHONPATH", "PYTHONHASHSEED", "HOME", "LANG", "LC_ALL", "LC_CTYPE", "TMPDIR", "VIRTUAL_ENV")
"""The only environment variables a worker inherits: it runs untrusted programs, so API keys
and other secrets of the parent's environment never reach its process."""


def _error_types() -> dict[str, type[EventProgramError]]:
    out: dict[str, type[EventProgramError]] = {"EventProgramError": EventProgramError}
    for module in (tool_errors, sandbox_errors):
        for name, value in vars(module).items():
            if isinstance(value, type) and issubclass(value, EventProgramError):
                out[name] = value
    return out


ERROR_TYPES = _error_types()
"""Error classes a worker may name in an answer (anything else becomes ``EventProgramError``)."""


def _write_frame(stream: IO[bytes], message: dict[str, Any]) -> None:
    body = json.dumps(message, separators=(",", ":")).encode("utf-8")
    stream.write(_HEADER.pack(len(body)) + body)
    stream.flush()


def _read_exact(stream: IO[bytes], n: int) -> bytes | None:
    chunks: list[bytes] = []
    while n:
        chunk = stream.read(n)
        if not chunk:
            return None
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def _read_frame(stream: IO[bytes]) -> dict[str, Any] | None:
    """The next message, or None at end of stream or on a malformed frame."""
    header = _read_exact(stream, _HEADER.size)
    if header is None:
        return None
    (size,) = _HEADER.unpack(header)
    if size > MAX_FRAME:
        return None
    body = _read_exact(stream, size)
    if body is None:
        return None
    try:
        message = json.loads(body)
    except (ValueError, UnicodeDecodeError):
        return None
    return message if isinstance(message, dict) else None


def error_from(data: object) -> EventProgramError:
    """The typed error a worker reported (a malformed report is an ``EventProgramError``)."""
    if not isinstance(data, dict):
        return EventProgramError("the program's worker gave a malformed answer")
    cls = ERROR_TYPES.get(str(data.get("type")), EventProgramError)
    err = cls(str(data.get("feedback", ""))[: tool_errors.MAX_FEEDBACK + 40])
    line = data.get("line")
    err.line = line if isinstance(line, int) else None
    steps = data.get("steps")
    err.steps = steps if isinstance(steps, int) else None
    return err


class WorkerRunner:
    """A ``ProgramRunner`` that runs programs in a reused, OS-limited child process.

    ``budget`` is the interpreter budget inside the child (None: the default ``Budget``);
    the OS limits are keyword arguments: ``run_seconds`` is the worker's CPU time and
    ``wall_seconds`` the wall-clock backstop the parent allows one program
    (``storyteller.orchestrator.worker_deadline``). Thread-safe: calls from several threads (planning
    steps checked concurrently, each in a worker thread) run one program at a time.
    """

    def __init__(
        self,
        *,
        budget: Budget | None = None,
        address_space_bytes: int = ADDRESS_SPACE_BYTES,
        cpu_seconds: int = CPU_SECONDS,
        run_seconds: float = RUN_SECONDS,
        wall_seconds: float = WALL_SECONDS,
    ) -> None:
        self.budget = budget
        self.address_space_bytes = address_space_bytes
        self.cpu_seconds = cpu_seconds
        self.run_seconds = run_seconds
        self.wall_seconds = wall_seconds
        self.process: subprocess.Popen[bytes] | None = None
        self.starts = 0
        """Worker processes started so far (a restart after a death adds one)."""
        self._scene: tuple[Scene, str, str] | None = None
        self._lock = threading.Lock()
        self._starting = False
        """``process`` was started by :meth:`prestart` and has not said it is ready yet."""
        self._preload: threading.Thread | None = None
        self._stderr: StderrTail | None = None
        """What the current worker process writes to stderr (logged when it stops)."""
        """Writes a prestarted worker the scene to load (:meth:`prestart`); done once the
        worker said it is ready (it reads and loads the scene first) or died."""

    # -- process management
    def prestart(self, scene: Scene | None = None) -> None:
        """Start the worker process now and return at once: its imports run while the caller
        goes on with its own set-up, and the first program waits for it to be ready. With
        ``scene`` the worker also loads that scene (as a first program on it would) right after
        its imports. A worker already running (or starting) is kept."""
        with self._lock:
            if self.process is None:
                self.process = self._spawn(scene_first=scene is not None)
                self._starting = True
                if scene is not None:  # the worker reads it before it says it is ready
                    key, text = self._scene_key(scene)
                    self._preload = threading.Thread(
                        target=_send_quietly, args=(self.process, {"scene_key": key, "scene": text}),
                        name="worker-preload", daemon=True,
                    )
                    self._preload.start()  # a thread: a large scene fills the pipe until the worker reads

    def _start(self) -> subprocess.Popen[bytes]:
        process = self._spawn()
        self._await_ready(process)
        return process

    def _spawn(self, *, scene_first: bool = False) -> subprocess.Popen[bytes]:
        env = {
            **{name: os.environ[name] for name in WORKER_ENV if name in os.environ},
            "OPENBLAS_NUM_THREADS": "1",
            "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
        }
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "storyteller.orchestrator.sandbox_worker",
                str(self.address_space_bytes),
                str(self.cpu_seconds),
                *(["--scene-first"] if scene_first else []),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,  # never the terminal's: a traceback quotes the input
            env=env,
        )
        assert process.stderr is not None
        self._stderr = StderrTail(process.stderr)
        self.starts += 1
        return process

    def _await_ready(self, process: subprocess.Popen[bytes]) -> None:
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], START_SECONDS)
        if not ready or _read_frame(process.stdout) != {"ready": True}:
            self._stop(process)
            raise EventProgramError("the event-program worker process did not start")

    def _log_stderr(self, process: subprocess.Popen[bytes]) -> None:
        """Log what the stopped worker wrote to stderr (escaped, its last bytes), if anything."""
        tail, self._stderr = self._stderr, None
        shown = tail.finish() if tail is not None else None
        if shown is not None:
            import structlog  # here, not at the top: the worker process imports this module too

            structlog.get_logger("storyteller.sandbox").warning(
                "the event-program worker wrote to stderr", pid=process.pid, exit_code=process.returncode,
                bytes_written=shown.written, bytes_shown=shown.shown, text=shown.text,
            )

    def _worker(self) -> subprocess.Popen[bytes]:
        if self._starting and self.process is not None:  # prestarted: wait for its ready frame
            self._starting = False
            preload, self._preload = self._preload, None
            try:
                self._await_ready(self.process)  # (a preloaded scene was read and loaded before)
            except EventProgramError:  # it died while starting: started again below, as any dead worker
                self.close()
            if preload is not None:  # done: the worker read it, or died
                preload.join()
        if self.process is None or self.process.poll() is not None:
            self.close()
            self.process = self._start()
        return self.process

    def close(self) -> None:
        """Stop the worker (the next program starts a new one)."""
        process, self.process = self.process, None
        self._starting = False
        preload, self._preload = self._preload, None
        if process is not None:
            self._stop(process, preload)

    def _stop(self, process: subprocess.Popen[bytes], preload: threading.Thread | None = None) -> None:
        """Kill ``process``, log what it wrote to stderr and close its pipes (after ``preload``,
        a thread writing to it, ended: its write ends with the process, a broken pipe)."""
        with contextlib.suppress(OSError):
            process.kill()
        process.wait()
        self._log_stderr(process)
        if preload is not None:
            preload.join()
        for stream in (process.stdin, process.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _ask(self, request: dict[str, Any], extra_seconds: float = 0.0) -> dict[str, Any]:
        """Send one request and wait for its answer; kill the worker on a timeout or death.

        ``extra_seconds`` is added to both limits (loading a scene is not the program's).
        """
        process = self._worker()
        assert process.stdin is not None and process.stdout is not None
        try:
            _write_frame(process.stdin, request)
        except OSError:
            self.close()
            raise BudgetExceededError(
                "the program's worker process died; it is restarted for the next program"
            ) from None
        stdout = process.stdout
        try:
            await_answer(
                lambda timeout: bool(select.select([stdout], [], [], timeout)[0]),
                lambda: process_cpu_seconds(process.pid),
                run_seconds=self.run_seconds + extra_seconds,
                wall_seconds=self.wall_seconds + extra_seconds,
            )
        except BudgetExceededError:
            self.close()
            raise
        answer = _read_frame(process.stdout)
        if answer is None:
            self.close()
            raise BudgetExceededError(
                "the program's worker process was stopped by an operating-system limit "
                "(memory or CPU time); use less memory and shorter loops"
            )
        return answer

    # -- the ProgramRunner call
    def _scene_key(self, scene: Scene) -> tuple[str, str]:
        if self._scene is None or self._scene[0] is not scene:
            text = scene.model_dump_json()
            self._scene = (scene, hashlib.sha256(text.encode("utf-8")).hexdigest(), text)
        return self._scene[1], self._scene[2]

    def __call__(
        self,
        scene: Scene,
        source: str,
        world: WorldView,
        *,
        seed: int,
        action_labels: Sequence[str] | None = None,
        graph: SceneGraph | None = None,
    ) -> list[CharacterPlan]:
        """Run ``source`` like ``run_event_program`` (``graph`` is unused: the worker keeps
        its own per scene)."""
        if not isinstance(source, str):
            raise EventProgramError("the program must be Python source text")
        limit = (self.budget or Budget()).source_chars
        if len(source) > limit:  # the checker's verdict, given here: a huge text never reaches a frame
            raise BudgetExceededError(f"the program has {len(source)} characters (limit {limit})")
        with self._lock:
            return self._run(scene, source, world, seed=seed, action_labels=action_labels)

    def _run(
        self, scene: Scene, source: str, world: WorldView, *, seed: int, action_labels: Sequence[str] | None
    ) -> list[CharacterPlan]:
        key, scene_text = self._scene_key(scene)
        request: dict[str, Any] = {
            "scene_key": key,
            "source": source,
            "world": WorldView.model_validate(world).model_dump(mode="json"),
            "seed": seed,
            "labels": None if action_labels is None else list(action_labels),
            "budget": None if self.budget is None else asdict(self.budget),
        }
        answer = self._ask(request)
        if answer.get("need_scene"):
            answer = self._ask({**request, "scene": scene_text}, START_SECONDS)
        if answer.get("ok") is True and isinstance(answer.get("plans"), list):
            return [CharacterPlan.model_validate(p) for p in answer["plans"]]
        raise error_from(answer.get("error"))


# ---------------------------------------------------------------- the child process


def _send_quietly(process: subprocess.Popen[bytes], message: dict[str, Any]) -> None:
    """Write ``message`` to the worker; a worker that died meanwhile is found by the next
    request (and restarted), so a failed write is not an error here."""
    assert process.stdin is not None
    with contextlib.suppress(OSError, ValueError):  # ValueError: the pipe was closed
        _write_frame(process.stdin, message)


def _limit_self(address_space_bytes: int) -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (address_space_bytes, address_space_bytes))


def _arm_cpu(cpu_seconds: int) -> None:
    """Allow ``cpu_seconds`` more CPU from now (SIGXCPU then ends the worker)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    used = int(usage.ru_utime + usage.ru_stime) + 1
    _, hard = resource.getrlimit(resource.RLIMIT_CPU)
    soft = used + cpu_seconds
    if hard != resource.RLIM_INFINITY:
        soft = min(soft, hard)
    resource.setrlimit(resource.RLIMIT_CPU, (soft, hard))


def load_scene(text: str) -> tuple[Scene, SceneGraph]:
    """A scene sent by the parent, with its scene graph, and everything the first program on
    it would otherwise pay inside its budget: the navigation grid the position sampler tests
    reachability on (``storyteller.tools.position_sampling.scene_nav_grid``, cached per scene) and the
    compiled clearance test it runs (importing numba and loading its kernels). Called when the
    worker loads the scene, before any program's CPU limit is armed or budget starts."""
    import numpy as np

    from storyteller.tools.position_sampling import FloorMap
    from storyteller.tools.scene_graph import build_scene_graph

    scene = Scene.model_validate_json(text)
    graph = build_scene_graph(scene)
    centre = (np.asarray(scene.bounds_min) + np.asarray(scene.bounds_max)) / 2.0
    FloorMap(scene).reachable(centre.reshape(1, 2))  # builds the grid, loads the kernels
    return scene, graph


def serve(address_space_bytes: int, cpu_seconds: int, *, scene_first: bool = False) -> None:
    """The worker loop: one request in, one answer out, until stdin closes. ``scene_first``:
    the first message is a scene to load (``scene_key``, ``scene``; no answer), read and loaded
    before the worker says it is ready."""
    import signal

    # Ctrl-C on a terminal reaches the whole process group: the run that owns this worker stops
    # cleanly and closes it; the worker itself must not die with a traceback meanwhile.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from storyteller.tools.event_program import run_event_program

    out = os.fdopen(os.dup(1), "wb")  # answers go to a private copy of stdout ...
    os.dup2(2, 1)  # ... and anything printed by accident goes to stderr
    inp = os.fdopen(0, "rb")
    _limit_self(address_space_bytes)
    scenes: OrderedDict[str, tuple[Scene, SceneGraph]] = OrderedDict()
    if scene_first:
        first = _read_frame(inp)
        if first is None:
            return
        text = first.get("scene")
        if isinstance(text, str):
            scenes[str(first.get("scene_key"))] = load_scene(text)
    _write_frame(out, {"ready": True})
    while True:
        request = _read_frame(inp)
        if request is None:
            return
        key = str(request.get("scene_key"))
        if key not in scenes:
            text = request.get("scene")
            if not isinstance(text, str):
                _write_frame(out, {"need_scene": True})
                continue
            scenes[key] = load_scene(text)
            while len(scenes) > SCENES_KEPT:
                scenes.popitem(last=False)
        scenes.move_to_end(key)
        scene, graph = scenes[key]
        budget_data = request.get("budget")
        budget = Budget(**budget_data) if isinstance(budget_data, dict) else None
        _arm_cpu(cpu_seconds)
        try:
            plans = run_event_program(
                scene,
                request["source"],
                WorldView.model_validate(request["world"]),
                seed=int(request["seed"]),
                action_labels=request.get("labels"),
                graph=graph,
                budget=budget,
                clock=time.thread_time,  # CPU time: a busy machine does not change the verdict
            )
        except EventProgramError as err:
            error = {
                "type": type(err).__name__,
                "feedback": err.feedback,
                "line": err.line,
                "steps": err.steps,
            }
            _write_frame(out, {"ok": False, "error": error})
            continue
        except MemoryError:
            _write_frame(out, {"ok": False, "error": _budget_error("uses too much memory")})
            continue
        _write_frame(out, {"ok": True, "plans": [p.model_dump(mode="json") for p in plans]})


def _budget_error(what: str) -> dict[str, Any]:
    return {"type": "BudgetExceededError", "feedback": f"the program {what}", "line": None}


if __name__ == "__main__":
    serve(int(sys.argv[1]), int(sys.argv[2]), scene_first="--scene-first" in sys.argv[3:])
