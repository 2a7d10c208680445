"""Raw websocket frames against the viewer (issue 22): what a program on this machine, not the
viewer's page, can send once its handshake passed.

``storyteller view`` serves a recorded run in a subprocess (its stderr is the log). A client of
the ``websockets`` package opens a connection with the viewer's own Origin and sends one attack:
invalid UTF-8 in a text frame, a text frame, random bytes, truncated msgpack, msgpack claiming a
4 GiB string, a message naming an unknown type or missing its fields, msgpack nested past any
depth, a 16 MiB frame, GUI updates the frame slider cannot take (a word, NaN, ``1e300``: that
one made every later page fail with an internal error), an input named by a list instead of a
uuid, a form named by a list, a camera message of words or 1e300 pixels wide, a property other
than the value, and
10,000 small well-formed messages in a row. A connection from a forged Origin is refused at the
handshake.

Each attack must close only its own connection, with the close code that names the fault
(``1007`` invalid data or a field of the wrong type, ``1003`` a text frame, ``1008`` a GUI update viser cannot apply,
``1009`` too big), or leave it open when the messages were well formed; afterwards a new client
gets the whole scene (viser's replay up to its ``ReplayDoneMessage``, every kind of message the
first client got); the viewer's log has no traceback; and its peak RSS stays within
:data:`MEMORY_GROWTH` of what it was before the first attack. The unit tests at the end check
:func:`~storyteller.orchestrator.viewer.inbound.update_problem` on a table.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import msgspec
import pytest
import viser
import zstandard
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.frames import Frame, Opcode
from websockets.sync.client import ClientConnection, connect
from websockets.sync.connection import Connection
from websockets.typing import Subprotocol

from storyteller.orchestrator.viewer.inbound import MAX_MESSAGE_BYTES, fits, update_problem
from tests.support.story_planner import interact_program, recorded_home_run

PROTOCOL = Subprotocol(f"viser-v{viser.__version__}")
MEMORY_GROWTH = 128 << 20  # bytes of peak RSS the attacks may add (the 16 MiB frame must not be read)
WAIT_S = 30.0  # a hang detector only: every answer here comes far sooner
CLI = [sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()"]


@dataclass
class Viewer:
    """A running ``storyteller view``: its process, address and log."""

    proc: subprocess.Popen[bytes]
    authority: str
    log: Path
    baseline_rss: int
    scene_types: frozenset[str] = frozenset()

    @property
    def url(self) -> str:
        return f"ws://{self.authority}"

    def open(self) -> ClientConnection:
        """A websocket as the viewer's own page opens it."""
        return connect(self.url, subprotocols=[PROTOCOL], additional_headers={"Origin": f"http://{self.authority}"},
                       open_timeout=WAIT_S, max_size=None)  # fmt: skip

    def status(self, key: str) -> int:
        """A ``/proc`` memory figure of the viewer (``VmRSS``, ``VmHWM``), bytes."""
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1]) * 1024
        raise AssertionError(f"no {key} in /proc/{self.proc.pid}/status")


def scene_of(viewer: Viewer) -> list[str]:
    """The message types a new page gets, up to the end of viser's replay of the scene."""
    types: list[str] = []
    with viewer.open() as ws:
        while "ReplayDoneMessage" not in types:
            message = ws.recv(timeout=WAIT_S)
            assert isinstance(message, bytes)
            size = int.from_bytes(message[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(message[16 : 16 + size], max_output_size=1 << 30)
            types += [m["type"] for m in msgspec.msgpack.decode(inner)["messages"]]
    return types


def gui_uuid(viewer: Viewer, label: str) -> str:
    """The uuid of the panel input labelled ``label``."""
    with viewer.open() as ws:
        while True:
            message = ws.recv(timeout=WAIT_S)
            assert isinstance(message, bytes)
            size = int.from_bytes(message[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(message[16 : 16 + size], max_output_size=1 << 30)
            for m in msgspec.msgpack.decode(inner)["messages"]:
                if isinstance(m.get("props"), dict) and m["props"].get("label") == label:
                    return str(m["uuid"])
                assert m["type"] != "ReplayDoneMessage", f"no input labelled {label}"


def close_code(ws: Connection) -> int | None:
    """Read until the viewer closes the connection: its close code (None: it stayed open)."""
    try:
        while True:
            ws.recv(timeout=2.0)
    except TimeoutError:
        return None
    except ConnectionClosed as closed:
        assert closed.rcvd is not None, "the connection dropped without a close frame"
        return closed.rcvd.code


@pytest.fixture(scope="module")
def viewer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Viewer]:
    tmp = tmp_path_factory.mktemp("raw-frames")
    run = recorded_home_run(tmp, [interact_program("Ava", "coffee_maker_1", "use_coffee_maker")], seconds=6, max_events=1)
    log = tmp / "view.log"
    with log.open("wb") as err:
        proc = subprocess.Popen([*CLI, "view", str(run), "--port", "0"], stdout=subprocess.PIPE, stderr=err,
                                start_new_session=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()
        url = next((w for w in line.split() if w.startswith("http://")), None)
        assert url is not None, f"no URL printed: {line!r}; log: {log.read_text(errors='replace')[-2000:]}"
        shown = Viewer(proc, url.removeprefix("http://").rstrip("/"), log, baseline_rss=0)
        shown.scene_types = frozenset(scene_of(shown))
        assert {"ReplayDoneMessage", "GuiSliderMessage"} <= shown.scene_types
        shown.baseline_rss = shown.status("VmRSS")
        yield shown
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGINT)
        proc.wait(WAIT_S)
        if proc.stdout is not None:  # the pipe's reader, or pytest reports it unclosed at exit (CI fails)
            proc.stdout.close()


def raw_frame(ws: Connection, opcode: Opcode, payload: bytes) -> None:
    """Send one frame as bytes on the socket, past the client's own checks (UTF-8, size)."""
    with contextlib.suppress(OSError):  # the viewer may close before a large frame is all sent
        ws.socket.sendall(Frame(opcode, payload).serialize(mask=True, extensions=[]))


def packed(message: object) -> bytes:
    return msgspec.msgpack.encode(message)


CAMERA_FIELDS = {"type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, -4.0, 3.0],
                 "fov": 1.0, "near": 0.01, "far": 100.0, "image_height": 600, "image_width": 800,
                 "look_at": [0.0, 0.0, 0.0], "up_direction": [0.0, 0.0, 1.0]}  # fmt: skip
CAMERA = packed(CAMERA_FIELDS)  # what a page sends as its camera moves


def _many(ws: Connection) -> None:
    for _ in range(10_000):
        ws.send(CAMERA)


Attack = Callable[[Connection, str], None]
ATTACKS: dict[str, tuple[Attack, int | None]] = {  # what is sent (given the slider's uuid), the close code
    "invalid UTF-8 in a text frame": (lambda ws, _: raw_frame(ws, Opcode.TEXT, b"Ben \xff\xfe\xc0\x80 waves"), 1007),
    "a text frame": (lambda ws, _: ws.send('{"type": "GuiUpdateMessage"}'), 1003),
    "random bytes": (lambda ws, _: ws.send(bytes(range(256)) * 16 + os.urandom(4096)), 1007),
    "truncated msgpack": (lambda ws, u: ws.send(packed({"type": "GuiUpdateMessage", "uuid": u, "updates": {"value": 3}})[:-4]), 1007),
    "msgpack claiming a 4 GiB string": (lambda ws, _: ws.send(b"\x81\xa4type\xdb\xff\xff\xff\xff" + b"x" * 64), 1007),
    "an unknown message type": (lambda ws, _: ws.send(packed({"type": "RunShellMessage", "command": "id"})), 1007),
    "a known type without its fields": (lambda ws, _: ws.send(packed({"type": "ViewerCameraMessage"})), 1007),
    "not a map": (lambda ws, _: ws.send(packed([1, 2, 3])), 1007),
    "msgpack nested 200,000 deep": (lambda ws, _: ws.send(b"\x91" * 200_000), 1007),
    "a 16 MiB frame": (lambda ws, _: raw_frame(ws, Opcode.BINARY, b"\0" * (16 << 20)), 1009),
    "the slider given a word": (lambda ws, u: ws.send(packed({"type": "GuiUpdateMessage", "uuid": u, "updates": {"value": "abc"}})), 1008),
    "the slider given NaN": (lambda ws, u: ws.send(packed({"type": "GuiUpdateMessage", "uuid": u, "updates": {"value": math.nan}})), 1008),
    "the slider given 1e300": (lambda ws, u: ws.send(packed({"type": "GuiUpdateMessage", "uuid": u, "updates": {"value": 1e300}})), 1008),
    "an input named by a list": (lambda ws, _: ws.send(packed({"type": "GuiUpdateMessage", "uuid": [1], "updates": {"value": 1}})), 1007),
    "a form named by a list": (lambda ws, _: ws.send(packed({"type": "GuiFormSubmitMessage", "uuid": [1]})), 1007),
    "a camera of words": (lambda ws, _: ws.send(packed({**CAMERA_FIELDS, "wxyz": "abc", "fov": "wide"})), 1007),
    "a camera 1e300 pixels wide": (lambda ws, _: ws.send(packed({**CAMERA_FIELDS, "image_width": 1e300})), 1007),
    "a property other than the value": (lambda ws, u: ws.send(packed({"type": "GuiUpdateMessage", "uuid": u, "updates": {"visible": False}})), 1008),
    "10,000 small messages": (lambda ws, _: _many(ws), None),
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("name", list(ATTACKS))
def test_a_raw_frame_closes_only_its_connection_and_leaves_no_traceback(viewer: Viewer, name: str) -> None:
    attack, expected = ATTACKS[name]
    slider = gui_uuid(viewer, "Frame")
    with viewer.open() as ws:
        attack(ws, slider)
        assert close_code(ws) == expected
    assert viewer.proc.poll() is None, "the viewer exited"
    got = scene_of(viewer)  # a new page still gets the whole scene
    assert viewer.scene_types <= set(got), sorted(viewer.scene_types - set(got))
    log = viewer.log.read_text(errors="replace")
    assert "Traceback" not in log and "Error" not in log, log[-3000:]
    assert viewer.status("VmHWM") - viewer.baseline_rss < MEMORY_GROWTH


@pytest.mark.slow
def test_a_forged_origin_is_refused_at_the_handshake(viewer: Viewer) -> None:
    for origin in ("http://evil.example", "null", f"https://{viewer.authority}"):
        with pytest.raises(InvalidStatus) as refused:
            connect(viewer.url, subprotocols=[PROTOCOL], additional_headers={"Origin": origin}, open_timeout=WAIT_S)
        assert refused.value.response.status_code == 403, origin
    assert "ReplayDoneMessage" in scene_of(viewer)


# ----- the GUI update rule ----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("updates", "current", "allowed"),
    [
        ({"value": 5}, 0, True),
        ({"value": 5.0}, 0, True),  # JavaScript sends a whole number as a float at times
        ({"value": "Ben waves"}, "", True),
        ({"value": "x" * (1 << 20)}, "", True),  # a pasted megabyte: refused by the box, with its reason
        ({"value": True}, False, True),
        ({"value": [0.1, 0.2, 0.3]}, (0.0, 0.0, 0.0), True),
        ({"value": 7}, None, True),  # no such input: viser ignores it
        ({"value": "abc"}, 0, False),
        ({"value": math.nan}, 0.0, False),
        ({"value": math.inf}, 0, False),
        ({"value": 1e300}, 0, False),
        ({"value": 2**60}, 0, False),
        ({"value": None}, "", False),
        ({"value": {"a": 1}}, "", False),
        ({"value": [[1]]}, (0,), False),
        ({"value": [1.0] * 65}, (0.0,), False),
        ({"value": 3}, (0.0, 0.0), False),
        ({"visible": False}, 0, False),
        ({"value": 1, "label": "x"}, 0, False),
        ({}, 0, False),
        ([1], 0, False),
    ],
)
def test_a_gui_update_sets_a_value_viser_can_apply(updates: object, current: object, allowed: bool) -> None:
    assert (update_problem(updates, current) is None) is allowed


@pytest.mark.parametrize(
    ("value", "annotation", "allowed"),
    [
        (3, int, True), (3.0, int, True), (3.5, int, False), (2**60, int, False), (True, int, False),
        (math.nan, float, True), ("3", float, False), ([1.0, 2.0, 3.0], tuple[float, float, float], True),
        ([1.0, 2.0], tuple[float, float, float], False), ([[1.0, 2.0]], tuple[tuple[float, float], ...], True),
        (None, int | None, True), ("click", Literal["click", "rect-select"], True), ("x", Literal["click"], False),
        ([1], str, False), ({"a": 1}, dict[str, Any], True), ([], dict[str, Any], False),
    ],
)  # fmt: skip
def test_a_field_holds_its_annotated_type(value: object, annotation: object, allowed: bool) -> None:
    assert fits(value, annotation) is allowed


def test_the_message_limit_holds_a_pasted_megabyte_in_any_characters() -> None:
    assert len(packed({"type": "GuiUpdateMessage", "uuid": "u", "updates": {"value": "\U0001f600" * (1 << 20)}})) < MAX_MESSAGE_BYTES
