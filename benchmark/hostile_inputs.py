"""``python -m benchmark.hostile_inputs``: an outside attacker's corpus against every file the
CLI reads back, built at run time in a temporary folder, each attack run as a subprocess.

The base is real: a short scripted run (``benchmark.motion_metrics.scripted_story``, 3
simulated seconds, no LLM) and a one-run bench sweep of our own case 100 (the same kind of
scripted OpenAI-compatible server on 127.0.0.1). Each attack copies what it needs, breaks one
thing (a planted link or hard link, a FIFO, a link to ``/dev/zero``, deep nesting, huge numbers,
NaN, bytes that are not UTF-8, lone surrogates, control and bidi characters, duplicate keys,
compressed files, zip bombs, pickles, huge scenes and meshes, forged viewer requests) and runs
the command that reads it under an address-space limit (:data:`AS_LIMIT`) and a wall-clock
limit (the clean command's time + :data:`SLACK_S`).

The verdict holds the issue's targets (issue 22): within the time, max RSS under 1 GiB; a bad
file is exit 2 with exactly one ``error:`` line on stderr (``expect="bad"``), an attack the
product may also accept is exit 0 or that (``"either"``); never a traceback; no Unicode control
or format character (Cc, Cf, Zl, Zp, but newline and tab) on stdout or stderr; no file written
or changed outside the run folder and the command's own outputs; the canary file that a
successful code execution would create is absent; and a refused command leaves the run folder
as it was (nothing lost).

Prints one table row per attack (kind, attack, exit, seconds, max RSS, verdict) and a summary;
exit code 1 when an attack failed. ``--only SUBSTRING`` runs the attacks whose name holds it;
``--keep`` keeps the temporary folder. Several minutes on two cores (a clean ``resume`` takes
about 10 s): a benchmark, not a test. Regression tests for what it found are in ``tests/``.
"""

from __future__ import annotations

import argparse
import contextlib
import gzip
import hashlib
import http.client
import io
import json
import os
import pickle
import re
import resource
import shutil
import signal
import socket
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import time
import unicodedata
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Literal

from benchmark.motion_metrics.scripted_story import build_story

AS_LIMIT = 4 << 30
"""Address space of an attacked command (bytes): a guard for the machine, the verdict reads RSS."""
RSS_LIMIT = 1 << 30
"""Max resident set size of an attacked command (bytes), as the issue asks."""
SLACK_S = 6.0
"""Seconds an attack may take beyond the clean run of the same command."""
CLI = [sys.executable, "-c", "from orchestrator.cli.app import main; main()"]
CANARY = "CANARY"
BIDI = "\u202e\u2066\x1b[31m\x07\u200b\u2028"
"""Characters that must never reach the terminal raw (RLO, isolate, an escape sequence, BEL,
zero width space, line separator)."""
MARKER = "</script><img src=x onerror=alert(1)>"

Expect = Literal["bad", "either", "program"]
"""bad: exit 2 and one ``error:`` line; either: that or exit 0; program: a dry-run event program the
sandbox refuses is the command's answer, exit 1 and one ``error (kind):`` line, or exit 0 or 2."""
CLEAN_PROGRAM = ('def parse_event():\n    a = get_character("Zoe")\n    a.set_position(get_area_to_sit_on("couch_1"))\n'
                 '    a.set_target_action("sit")\n')


@dataclass
class Spec:
    """What an attack runs and what it may write (besides the run folder)."""

    argv: list[str]
    command: str
    expect: Expect = "bad"
    writable: tuple[Path, ...] = ()
    check: Callable[[], str | None] | None = None
    stdin: bytes | None = None


@dataclass
class Box:
    """One attack's folder: ``run`` (a copy of the base run when asked), ``outside`` (victim
    files that must stay as they are), the canary path a code execution would create."""

    root: Path
    base: Path
    sweep_base: Path
    canary: Path
    run: Path = field(init=False)
    outside: Path = field(init=False)

    def __post_init__(self) -> None:
        self.run = self.root / "run"
        self.outside = self.root / "outside"
        self.outside.mkdir(parents=True)
        (self.outside / "victim.txt").write_text("victim: must not change\n", encoding="utf-8")
        (self.outside / "secret.txt").write_text("SECRET-7f3a must not be read into outputs\n", encoding="utf-8")
        (self.outside / "dir").mkdir()

    def copy_run(self) -> Path:
        shutil.copytree(self.base, self.run, symlinks=True)
        return self.run

    def copy_sweep(self) -> Path:
        self.run = self.root / "sweep"  # the folder the command writes in
        shutil.copytree(self.sweep_base, self.run, symlinks=True)
        return self.run

    def victim(self) -> Path:
        return self.outside / "victim.txt"

    def fifo(self, path: Path) -> Path:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        os.mkfifo(path)
        return path

    def link(self, path: Path, target: Path | str) -> Path:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        path.symlink_to(target)
        return path

    def file(self, name: str, data: bytes | str) -> Path:
        path = self.root / name
        path.write_bytes(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data)
        return path

    def edit_json(self, path: Path, change: Callable[[Any], Any]) -> None:
        value = json.loads(path.read_text(encoding="utf-8"))
        path.write_text(json.dumps(change(value)), encoding="utf-8")


def resume(box: Box, expect: Expect = "bad") -> Spec:
    return Spec(["resume", str(box.run), "--no-interactive", "--no-live"], "resume", expect)


def replay(box: Box, expect: Expect = "bad") -> Spec:
    out = box.root / "replayed"
    return Spec(["replay", str(box.run), "--out", str(out), "--no-live"], "replay", expect, writable=(out,))


def export(box: Box, expect: Expect = "bad", check: Callable[[], str | None] | None = None) -> Spec:
    html = box.root / "view.html"
    return Spec(["view", str(box.run), "--export", str(html)], "view --export", expect, writable=(html,), check=check)


def inspect(path: Path, expect: Expect = "bad") -> Spec:
    return Spec(["scene", "inspect", str(path)], "scene inspect", expect)


def score(box: Box, sweep: Path, expect: Expect = "bad") -> Spec:
    return Spec(["bench", "score", str(sweep)], "bench score", expect)


def deep_json(depth: int) -> str:
    return "[" * depth + "]" * depth


def snapshot_with(payload: bytes) -> bytes:
    """A ``session.snapshot`` of the current format holding ``payload`` with its right checksum."""
    return b"storyteller-snapshot 5 sha256=" + hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload


def zip_bomb_npz(name: str, gigabytes: float) -> bytes:
    """An ``.npz`` whose one member inflates to ``gigabytes`` of zeros behind a true header."""
    header = b"\x93NUMPY\x01\x00"
    count = int(gigabytes * (1 << 30)) // 8
    text = f"{{'descr': '<f8', 'fortran_order': False, 'shape': ({count},), }}".encode()
    text += b" " * (63 - (len(text) + 10) % 64) + b"\n"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z, z.open(f"{name}.npy", "w", force_zip64=True) as f:
        f.write(header + struct.pack("<H", len(text)) + text)
        block = bytes(1 << 24)
        for _ in range(count * 8 // len(block)):
            f.write(block)
    return buf.getvalue()


def html_clean(box: Box) -> Callable[[], str | None]:
    def check() -> str | None:
        html = (box.root / "view.html").read_text(encoding="utf-8", errors="replace")
        if MARKER in html:
            return "export holds the story text's raw </script>: script injection"
        if "SECRET-7f3a" in html:
            return "export holds a file outside the run folder"
        return None

    return check


def victim_intact(box: Box) -> Callable[[], str | None]:
    def check() -> str | None:
        return None if box.victim().read_text(encoding="utf-8") == "victim: must not change\n" else "victim changed"

    return check


def scene_json(objects: list[dict[str, Any]], **extra: Any) -> str:
    return json.dumps({"name": extra.pop("name", "hostile"), "objects": objects, **extra})


def box_object(i: int, label: str = "chair", size: float = 0.5, x: float | None = None, y: float = 0.0) -> dict[str, Any]:
    cx = float(i) if x is None else x
    return {"label": label, "center": [cx, y, size / 2], "size": [size, size, size], "heading": 0.0}


# ---------------------------------------------------------------- the attacks


ATTACKS: list[tuple[str, str, Callable[[Box], Spec]]] = []


def attack(kind: str, name: str) -> Callable[[Callable[[Box], Spec]], Callable[[Box], Spec]]:
    def add(fn: Callable[[Box], Spec]) -> Callable[[Box], Spec]:
        ATTACKS.append((kind, name, fn))
        return fn

    return add


class _Reduce:
    """Pickles as a call of ``os.system`` (the classic pickle payload)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (self.command,))


@attack("snapshot", "pickle calls os.system, checksum fixed")
def _snap_system(box: Box) -> Spec:
    run = box.copy_run()
    (run / "session.snapshot").write_bytes(snapshot_with(pickle.dumps(_Reduce(f"touch {box.canary}"), protocol=4)))
    return resume(box)


@attack("snapshot", "pickle builds builtins.eval through STACK_GLOBAL")
def _snap_eval(box: Box) -> Spec:
    run = box.copy_run()
    code = f"open({str(box.canary)!r}, 'w').write('x')"
    payload = (b"\x80\x04\x8c\x08builtins\x94\x8c\x04eval\x94\x93\x94" + pickle.dumps((code,), protocol=4)[2:-1]
               + b"R.")
    (run / "session.snapshot").write_bytes(snapshot_with(payload))
    return resume(box)


@attack("snapshot", "pickle 200,000 lists deep, checksum fixed")
def _snap_deep(box: Box) -> Spec:
    run = box.copy_run()
    payload = b"\x80\x04" + b"]" * 200_000 + b"a" * 199_999 + b"."
    (run / "session.snapshot").write_bytes(snapshot_with(payload))
    return resume(box)


@attack("snapshot", "gzip of the real snapshot")
def _snap_gzip(box: Box) -> Spec:
    run = box.copy_run()
    path = run / "session.snapshot"
    path.write_bytes(gzip.compress(path.read_bytes()))
    return resume(box)


@attack("snapshot", "FIFO named session.snapshot")
def _snap_fifo(box: Box) -> Spec:
    box.fifo(box.copy_run() / "session.snapshot")
    return resume(box)


@attack("snapshot", "session.snapshot -> /dev/zero")
def _snap_zero(box: Box) -> Spec:
    box.link(box.copy_run() / "session.snapshot", "/dev/zero")
    return resume(box)


@attack("run.json", "nested 100,000 deep")
def _runjson_deep(box: Box) -> Spec:
    (box.copy_run() / "run.json").write_text(deep_json(100_000), encoding="utf-8")
    return resume(box)


@attack("run.json", "duplicate key: a second seed")
def _runjson_dup(box: Box) -> Spec:
    path = box.copy_run() / "run.json"
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace('"seed": 0,', '"seed": 0, "seed": 7,', 1), encoding="utf-8")
    return replay(box)


@attack("run.json", "config -> /dev/zero (replay)")
def _runjson_config_zero(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "config": "/dev/zero", "arguments": {**v["arguments"], "config": "/dev/zero"}})
    return replay(box)


@attack("run.json", "config is a FIFO (replay)")
def _runjson_config_fifo(box: Box) -> Spec:
    run = box.copy_run()
    fifo = str(box.fifo(box.outside / "cfg.toml"))
    box.edit_json(run / "run.json", lambda v: {**v, "config": fifo, "arguments": {**v["arguments"], "config": fifo}})
    return replay(box)


@attack("run.json", "duration 1e400")
def _runjson_inf(box: Box) -> Spec:
    path = box.copy_run() / "run.json"
    path.write_text(re.sub(r'"duration": [0-9.]+', '"duration": 1e400', path.read_text(encoding="utf-8")), encoding="utf-8")
    return resume(box)


@attack("run.json", "50 MB instruction")
def _runjson_huge(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "arguments": {**v["arguments"], "instruction": "a" * 50_000_000}})
    return replay(box)


@attack("run.json", "scene -> /dev/zero")
def _runjson_scene_zero(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "scene_name": "/dev/zero", "arguments": {**v["arguments"], "scene": "/dev/zero"}})
    return replay(box)


@attack("run.json", "thread id and instruction with escapes, bidi, lone surrogate")
def _runjson_text(box: Box) -> Spec:
    path = box.copy_run() / "run.json"
    value = json.loads(path.read_text(encoding="utf-8"))
    value["thread_id"] = value["thread_id"] + BIDI
    value["arguments"]["instruction"] = "\ud800 go" + BIDI
    path.write_text(json.dumps(value), encoding="utf-8")
    return replay(box, expect="either")


@attack("run folder", "trace.jsonl -> file outside")
def _link_trace(box: Box) -> Spec:
    box.link(box.copy_run() / "trace.jsonl", box.victim())
    return Spec(**{**resume(box).__dict__, "check": victim_intact(box)})


@attack("run folder", "story.md hard-linked to a file outside")
def _hardlink_story(box: Box) -> Spec:
    run = box.copy_run()
    (run / "story.md").unlink()
    os.link(box.victim(), run / "story.md")
    return Spec(**{**resume(box, "either").__dict__, "check": victim_intact(box)})


@attack("run folder", "motion/ -> folder outside")
def _link_motion(box: Box) -> Spec:
    run = box.copy_run()
    shutil.copytree(run / "motion", box.outside / "dir" / "motion")
    box.link(run / "motion", box.outside / "dir" / "motion")
    return resume(box)


@attack("run folder", "runs.sqlite hard-linked outside")
def _hardlink_db(box: Box) -> Spec:
    run = box.copy_run()
    shutil.copy(run / "runs.sqlite", box.outside / "runs.sqlite")
    (run / "runs.sqlite").unlink()
    os.link(box.outside / "runs.sqlite", run / "runs.sqlite")
    return resume(box)


@attack("run folder", "runs.sqlite-journal -> file outside")
def _link_journal(box: Box) -> Spec:
    box.link(box.copy_run() / "runs.sqlite-journal", box.victim())
    return resume(box)


@attack("run folder", "planted .tmp links beside every written file")
def _link_tmp(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("story.md", "story.json", "metrics.json", "run.json", "live.json", "scene.glb", "topdown.png",
                 "Zoe.bvh", "Zoe.track.npz", "Zoe.smplx.npz"):
        box.link(run / f"{name}.tmp", box.victim())
        box.link(run / f".{name}.tmp", box.victim())
    return Spec(**{**resume(box, "either").__dict__, "check": victim_intact(box)})


@attack("run folder", "live.json, metrics.json, Zoe.bvh -> file outside")
def _link_outputs(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("live.json", "metrics.json", "Zoe.bvh"):
        box.link(run / name, box.victim())
    return Spec(**{**resume(box).__dict__, "check": victim_intact(box)})


@attack("run folder", "the run folder's motion/ symlinked and the run folder a symlink")
def _link_runfolder(box: Box) -> Spec:
    real = box.copy_run()
    linked = box.root / "linked-run"
    linked.symlink_to(real)
    return Spec(["resume", str(linked), "--no-interactive", "--no-live"], "resume", "bad")


@attack("trace", "FIFO named trace.jsonl (replay)")
def _trace_fifo(box: Box) -> Spec:
    box.fifo(box.copy_run() / "trace.jsonl")
    return replay(box)


@attack("trace", "a 60 MB line without newline appended")
def _trace_long(box: Box) -> Spec:
    with open(box.copy_run() / "trace.jsonl", "ab") as f:
        f.write(b'{"run_id": "x", "seq": 9, "kind": "' + b"a" * 60_000_000)
    return replay(box)


@attack("trace", "gzip-compressed trace.jsonl")
def _trace_gzip(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    path.write_bytes(gzip.compress(path.read_bytes()))
    return replay(box)


def _trace_records(box: Box) -> tuple[Path, list[dict[str, Any]]]:
    path = box.copy_run() / "trace.jsonl"
    return path, [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]


def _write_records(path: Path, records: list[dict[str, Any]]) -> None:
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")


@attack("trace", "reply: a code fence and 150,000 spaces")
def _trace_fence(box: Box) -> Spec:
    path, records = _trace_records(box)
    for r in records:
        if r["kind"] == "attempt":
            r["response_text"] = "```" + " " * 150_000 + "x"
    _write_records(path, records)
    return replay(box, "either")


@attack("trace", "applied step at frame 10**9")
def _trace_frame(box: Box) -> Spec:
    path, records = _trace_records(box)
    for r in records:
        if r["kind"] == "applied":
            r["requested_frame"] = r["sim_frame"] = 10**9
    _write_records(path, records)
    return replay(box)


@attack("trace", "a 5,000-digit seq")
def _trace_digits(box: Box) -> Spec:
    path, records = _trace_records(box)
    text = "".join(json.dumps(r) + "\n" for r in records).replace('"seq": 2,', '"seq": ' + "9" * 5000 + ",", 1)
    path.write_text(text, encoding="utf-8")
    return replay(box)


@attack("trace", "bytes that are not UTF-8 and NUL in a reply")
def _trace_bytes(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    path.write_bytes(path.read_bytes().replace(b"def parse_event", b"def \xff\xfe\x00parse_event", 1))
    return replay(box)


@attack("trace", "NaN latency and duplicate kind keys")
def _trace_nan(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    text = path.read_text(encoding="utf-8").replace('"latency_s":', '"latency_s":NaN,"x_latency":', 1)
    text = text.replace('"kind":"parsed"', '"kind":"applied","kind":"parsed"', 1)
    path.write_text(text, encoding="utf-8")
    return replay(box)


@attack("story.json", "activity with </script>, bidi, ANSI (export)")
def _story_script(box: Box) -> Spec:
    run = box.copy_run()

    def change(v: Any) -> Any:
        for step in v["steps"]:
            step["activity"] = MARKER + BIDI + step["activity"]
        return v

    box.edit_json(run / "story.json", change)
    return export(box, "either", html_clean(box))


@attack("story.json", "lone surrogate in an activity (export)")
def _story_surrogate(box: Box) -> Spec:
    path = box.copy_run() / "story.json"
    text = path.read_text(encoding="utf-8").replace('"activity": "', '"activity": "\\udc80\\ud800', 1)
    path.write_text(text, encoding="utf-8")
    return export(box, "either", html_clean(box))


@attack("story.json", "nested 200,000 deep (export)")
def _story_deep(box: Box) -> Spec:
    (box.copy_run() / "story.json").write_text('{"steps": ' + deep_json(200_000) + "}", encoding="utf-8")
    return export(box)


@attack("story.json", "story.json -> secret file outside (export)")
def _story_link(box: Box) -> Spec:
    box.link(box.copy_run() / "story.json", box.outside / "secret.txt")
    return export(box, "either", html_clean(box))


@attack("story.jsonl", "a 40 MB line (export)")
def _stream_long(box: Box) -> Spec:
    run = box.copy_run()
    (run / "story.json").unlink()  # a live run: the viewer reads the stream
    with open(run / "story.jsonl", "ab") as f:
        f.write(b'{"kind": "event", "x": "' + b"b" * 40_000_000 + b'"}\n')
    return export(box, "either")


@attack("track", "zip bomb .track.npz (4 GB of zeros)")
def _track_bomb(box: Box) -> Spec:
    run = box.copy_run()
    (run / "Zoe.track.npz").write_bytes(zip_bomb_npz("root_positions", 4))
    shutil.rmtree(run / "motion")
    return export(box)


@attack("track", ".track.npz holding a pickled object array")
def _track_pickle(box: Box) -> Spec:
    run = box.copy_run()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z, z.open("root_positions.npy", "w") as f:
        text = b"{'descr': '|O', 'fortran_order': False, 'shape': (1,), }"
        text += b" " * (63 - (len(text) + 10) % 64) + b"\n"
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text)
        f.write(pickle.dumps([_Reduce(f"touch {box.canary}")], protocol=2))
    (run / "Zoe.track.npz").write_bytes(buf.getvalue())
    shutil.rmtree(run / "motion")
    return export(box)


@attack("chunks", "FIFO named motion/Zoe.chunks (export)")
def _chunk_fifo(box: Box) -> Spec:
    box.fifo(box.copy_run() / "motion" / "Zoe.chunks")
    return export(box, "either")  # the exports of a finished run are read; the FIFO need not be


@attack("chunks", "20,000 small chunk files (export)")
def _chunk_many(box: Box) -> Spec:
    run = box.copy_run()
    for i in range(20_000):
        (run / "motion" / f"x{i}.chunks").write_bytes(b"\0" * 16)
    return export(box, "either")


@attack("scene", "scene.json in the run folder: 30,000 boxes (export)")
def _run_scene_big(box: Box) -> Spec:
    run = box.copy_run()
    (run / "scene.json").write_text(scene_json([box_object(i % 170, y=i // 170 * 0.1) for i in range(30_000)]),
                                    encoding="utf-8")
    return export(box, "either")


@attack("scene", "JSON scene of 20,000 boxes")
def _scene_many(box: Box) -> Spec:
    objects = [box_object(i % 140, size=0.6, y=(i // 140) * 0.5) for i in range(20_000)]
    return inspect(box.file("many.json", scene_json(objects)))


@attack("scene", "400 dense boxes")
def _scene_dense(box: Box) -> Spec:
    objects = [box_object(i, size=0.9, x=(i % 20) * 0.5, y=(i // 20) * 0.5) for i in range(400)]
    return inspect(box.file("dense.json", scene_json(objects)), "either")


@attack("scene", "names and labels with markup, ANSI, bidi, line separators")
def _scene_text(box: Box) -> Spec:
    objects = [box_object(0, label="[/]" + BIDI + "chair"), box_object(2, label="table[bold red]x")]
    return inspect(box.file("text.json", scene_json(objects, name="[/]hostile" + BIDI)), "either")


@attack("scene", "cell size asking for 1e10 cells")
def _scene_cells(box: Box) -> Spec:
    objects = [box_object(0), box_object(1), {**box_object(2), "center": [90000.0, 90000.0, 0.25]}]
    return inspect(box.file("cells.json", scene_json(objects, cell_size=0.001)))


@attack("scene", "NaN and 1e999 in a box")
def _scene_nan(box: Box) -> Spec:
    text = scene_json([box_object(0), box_object(2)]).replace("[0.0, 0.0, 0.25]", "[NaN, 1e999, 0.25]", 1)
    return inspect(box.file("nan.json", text))


@attack("scene", "gzip-compressed .json scene")
def _scene_gzip(box: Box) -> Spec:
    return inspect(box.file("gz.json", gzip.compress(scene_json([box_object(0)]).encode())))


@attack("scene", "UTF-16 scene with BOM")
def _scene_utf16(box: Box) -> Spec:
    return inspect(box.file("u16.json", scene_json([box_object(0)]).encode("utf-16")), "either")


@attack("scene", "nested 100,000 deep")
def _scene_deep(box: Box) -> Spec:
    return inspect(box.file("deep.json", '{"name": "x", "objects": ' + deep_json(100_000) + "}"))


@attack("scene", "FIFO scene (run SCENE_FILE)")
def _scene_fifo(box: Box) -> Spec:
    fifo = box.fifo(box.root / "fifo.json")
    out = box.root / "o"
    return Spec(["run", str(fifo), "--out", str(out), "--no-interactive", "--no-live"], "run", "bad", writable=(out,))


@attack("scene", "/dev/zero named scene.json (scene inspect)")
def _scene_zero(box: Box) -> Spec:
    return inspect(box.link(box.root / "zero.json", "/dev/zero"))


@attack("mesh", ".obj with a 60,000-digit object name and 300,000 vertices")
def _mesh_obj(box: Box) -> Spec:
    lines = ["o " + "7" * 60_000 + BIDI]
    lines += [f"v {i % 97 * 0.01} {i % 89 * 0.01} {i % 83 * 0.01}" for i in range(300_000)]
    lines += [f"f {i + 1} {i + 2} {i + 3}" for i in range(0, 299_997, 3)]
    return inspect(box.file("big.obj", "\n".join(lines) + "\n"), "either")


@attack("mesh", ".ply claiming 10**15 vertices")
def _mesh_ply(box: Box) -> Spec:
    text = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\nproperty float x\n" \
           "property float y\nproperty float z\nend_header\n"
    return inspect(box.file("huge.ply", text.encode() + b"\0" * 1200))


@attack("mesh", ".glb JSON chunk claiming 4 GB, node names with control characters")
def _mesh_glb(box: Box) -> Spec:
    doc = json.dumps({"asset": {"version": "2.0"}, "nodes": [{"name": "\x1b[2J" + BIDI}], "scenes": [{"nodes": [0]}]})
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", 0xFFFFFFF0) + b"JSON" + body
    return inspect(box.file("huge.glb", glb))


@attack("mesh", ".glb with a 5,000-digit accessor index")
def _mesh_glb_index(box: Box) -> Spec:
    doc = '{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": {"POSITION": ' + "9" * 5000 + \
          '}}]}], "nodes": [{"mesh": 0, "name": "chair_1"}], "scenes": [{"nodes": [0]}]}'
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body
    return inspect(box.file("index.glb", glb))


def model_info(path: Path) -> Spec:
    return Spec(["model", "info", "--config", str(path)], "model info", "bad")


@attack("config", "backoff_base_s = inf")
def _config_inf(box: Box) -> Spec:
    return model_info(box.file("inf.toml", '[llm]\nmodel = "openai/x"\n[llm.retry]\nbackoff_base_s = inf\n'))


@attack("config", "arrays nested 50,000 deep")
def _config_deep(box: Box) -> Spec:
    return model_info(box.file("deep.toml", "x = " + "[" * 50_000 + "]" * 50_000 + "\n"))


@attack("config", "not UTF-8")
def _config_bytes(box: Box) -> Spec:
    return model_info(box.file("bytes.toml", b'[llm]\nmodel = "\xff\xfe"\n'))


@attack("config", "model and api_base with escapes and bidi")
def _config_text(box: Box) -> Spec:
    text = '[llm]\nmodel = "openai/x\\u001b[31m\\u202e"\napi_base = "http://a\\u0007\\u2028b"\n'
    return Spec(["model", "info", "--config", str(box.file("text.toml", text))], "model info", "either")


@attack("config", "FIFO config")
def _config_fifo(box: Box) -> Spec:
    return model_info(box.fifo(box.root / "fifo.toml"))


def script_run(box: Box, path: Path) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "--instructions", str(path), "--out", str(out), "--no-interactive", "--no-live"],
                "run", "bad", writable=(out,))


@attack("script", "instruction time of 400 nines")
def _script_nines(box: Box) -> Spec:
    return script_run(box, box.file("nines.txt", "9" * 400 + ":00 everyone sits\n"))


@attack("script", "a 30 MB line")
def _script_long(box: Box) -> Spec:
    return script_run(box, box.file("long.txt", "00:01 " + "a" * 30_000_000 + "\n"))


@attack("script", "NUL and bytes that are not UTF-8")
def _script_bytes(box: Box) -> Spec:
    return script_run(box, box.file("bytes.txt", b"00:01 go\x00\xff\xfe\n"))


@attack("script", "FIFO script")
def _script_fifo(box: Box) -> Spec:
    return script_run(box, box.fifo(box.root / "fifo.txt"))


def program_run(path: Path, expect: Expect = "bad") -> Spec:
    return Spec(["event-program", "home", "--program", str(path)], "event-program", expect)


@attack("program", "a 400 MB sparse program file")
def _program_sparse(box: Box) -> Spec:
    path = box.root / "sparse.py"
    with open(path, "wb") as f:
        f.truncate(400 << 20)
    return program_run(path)


@attack("program", "FIFO program")
def _program_fifo(box: Box) -> Spec:
    return program_run(box.fifo(box.root / "fifo.py"))


@attack("program", "a character name and action with escapes and bidi")
def _program_text(box: Box) -> Spec:
    text = ('def parse_event():\n    a = get_character("Zoe\\u202e\\x1b[31m")\n'
            '    a.set_position(get_area_to_sit_on("couch_1"))\n    a.set_target_action("sit\\u2066\\x07")\n')
    return program_run(box.file("text.py", text), "program")


@attack("program", "--states nested 100,000 deep")
def _program_states(box: Box) -> Spec:
    prog = box.file("ok.py", CLEAN_PROGRAM)
    spec = program_run(prog)
    spec.argv += ["--states", str(box.file("states.json", deep_json(100_000)))]
    return spec


def _sweep_trace(sweep: Path) -> Path:
    return next((sweep / "traces" / "runs").glob("*.jsonl"))


@attack("bench", "results.jsonl -> file outside")
def _bench_results_link(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(sweep / "results.jsonl", box.victim())
    return Spec(**{**score(box, sweep).__dict__, "check": victim_intact(box)})


@attack("bench", "report.md and plots/ -> outside")
def _bench_report_link(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(sweep / "report.md", box.victim())
    box.link(sweep / "plots", box.outside / "dir")
    return Spec(**{**score(box, sweep, "bad").__dict__, "check": victim_intact(box)})


@attack("bench", "results.csv hard-linked outside")
def _bench_csv_hardlink(box: Box) -> Spec:
    sweep = box.copy_sweep()
    (sweep / "results.csv").unlink()
    os.link(box.victim(), sweep / "results.csv")
    return Spec(**{**score(box, sweep, "either").__dict__, "check": victim_intact(box)})


@attack("bench", "run trace -> /dev/zero")
def _bench_trace_zero(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(_sweep_trace(sweep), "/dev/zero")
    return score(box, sweep)


@attack("bench", "run trace nested 100,000 deep")
def _bench_trace_deep(box: Box) -> Spec:
    sweep = box.copy_sweep()
    _sweep_trace(sweep).write_text(deep_json(100_000) + "\n", encoding="utf-8")
    return score(box, sweep)


@attack("bench", "a case named testcase_one.json and one not UTF-8")
def _bench_cases(box: Box) -> Spec:
    sweep = box.copy_sweep()
    cases = box.root / "cases" / "0_OA"
    cases.mkdir(parents=True)
    (cases / "testcase_one.json").write_text("{}", encoding="utf-8")
    (cases / "testcase_100.json").write_bytes(b'{"scene_name": "\xff\xfe"}')
    box.edit_json(sweep / "sweep.json", lambda v: {**v, "case_sets": [{**v["case_sets"][0], "path": str(cases.parent)}]})
    return score(box, sweep)


@attack("bench", "sweep.json: a 5,000-digit case id and duplicate keys")
def _bench_spec_digits(box: Box) -> Spec:
    sweep = box.copy_sweep()
    text = (sweep / "sweep.json").read_text(encoding="utf-8")
    text = text.replace('"case_ids": [', '"case_ids": [' + "9" * 5000 + ", ", 1)
    (sweep / "sweep.json").write_text(text, encoding="utf-8")
    return score(box, sweep)


@attack("bench", "description FIFO and results.jsonl line of escapes")
def _bench_fifo(box: Box) -> Spec:
    sweep = box.copy_sweep()
    for desc in (sweep / "descriptions").glob("*.json"):
        box.fifo(desc)
    with open(sweep / "results.jsonl", "a", encoding="utf-8") as f:
        f.write(json.dumps({"run_id": BIDI * 3}) + "\n")
    return score(box, sweep)


@attack("run folder", "viewer_instructions.jsonl: a 30 MB line, bidi text, deep nesting")
def _inbox(box: Box) -> Spec:
    run = box.copy_run()
    lines = [json.dumps({"text": "sit" + BIDI, "time_unix": 0}), deep_json(50_000), "x" * 30_000_000]
    (run / "viewer_instructions.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (run / "viewer_controls.jsonl").write_text('{"kind": "speed", "speed": 1e999}\n' + deep_json(50_000) + "\n",
                                               encoding="utf-8")
    return resume(box, "either")


@attack("chunks", "motion/Zoe.chunks cut mid-record, as a kill leaves it (resume)")
def _chunk_cut(box: Box) -> Spec:
    path = box.copy_run() / "motion" / "Zoe.chunks"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 100])
    return resume(box, "either")


@attack("chunks", "motion/Zoe.chunks with one byte flipped mid-file (resume)")
def _chunk_flip(box: Box) -> Spec:
    path = box.copy_run() / "motion" / "Zoe.chunks"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    return resume(box, "either")  # the frames after the checkpoint are cut off and simulated again


@attack("smplx", "--smplx-model folder whose .npz holds a pickled object array")
def _smplx_pickle(box: Box) -> Spec:
    box.copy_run()
    folder = box.root / "smplx"
    folder.mkdir()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z, z.open("v_template.npy", "w") as f:
        text = b"{'descr': '|O', 'fortran_order': False, 'shape': (1,), }"
        text += b" " * (63 - (len(text) + 10) % 64) + b"\n"
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text)
        f.write(pickle.dumps([_Reduce(f"touch {box.canary}")], protocol=2))
    for gender in ("NEUTRAL", "MALE", "FEMALE"):
        (folder / f"SMPLX_{gender}.npz").write_bytes(buf.getvalue())
    spec = export(box)
    spec.argv += ["--smplx-model", str(folder)]
    return spec


@attack("smplx", "--smplx-model folder whose .npz is a zip bomb")
def _smplx_bomb(box: Box) -> Spec:
    box.copy_run()
    folder = box.root / "smplx"
    folder.mkdir()
    for gender in ("NEUTRAL", "MALE", "FEMALE"):
        (folder / f"SMPLX_{gender}.npz").write_bytes(zip_bomb_npz("v_template", 3))
    spec = export(box)
    spec.argv += ["--smplx-model", str(folder)]
    return spec


@attack("motion config", "--motion-config naming /dev/zero and a FIFO as clips")
def _motion_config(box: Box) -> Spec:
    fifo = box.fifo(box.root / "clip.bvh")
    text = (f'root = "{box.root}"\nreplace_procedural = true\n[[clips]]\nfile = "/dev/zero"\nlabel = "walk"\n'
            f'[[clips]]\nfile = "{fifo.name}"\nlabel = "sit"\n')
    out = box.root / "o"
    return Spec(["run", "home", "--motion-config", str(box.file("motion.toml", text)), "--out", str(out), "-d", "2",
                 "--no-interactive", "--no-live"], "run", "bad", writable=(out,))


@attack("prompts", "plan --prompts folder of FIFOs and a 50 MB prompt")
def _prompts(box: Box) -> Spec:
    folder = box.root / "prompts" / "narrator"
    folder.mkdir(parents=True)
    box.fifo(folder / "system.md")
    (folder / "request.md").write_text("{{ x }}" * 5_000_000, encoding="utf-8")
    return Spec(["plan", "home", "--prompts", str(box.root / "prompts"), "--runs-db", ":memory:"], "plan", "bad")


@attack("plan", "plan --runs-db a FIFO, --replay a gzip trace")
def _plan_db(box: Box) -> Spec:
    trace = box.file("t.jsonl", gzip.compress(b'{"kind": "run"}\n'))
    return Spec(["plan", "home", "--runs-db", str(box.fifo(box.root / "db.sqlite")), "--replay", str(trace)],
                "plan", "bad")


@attack("trace", "an instruction record with bidi, escapes and 1 MB of text (replay prints it)")
def _trace_instruction(box: Box) -> Spec:
    path, records = _trace_records(box)
    records.insert(1, {"run_id": records[0]["run_id"], "seq": 100, "time_unix": 0.0, "kind": "instruction",
                       "text": "sit down" + BIDI + "\ud800" + "x" * 1_000_000, "source": "script" + BIDI,
                       "sim_frame": 1})
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    return replay(box, "either")


@attack("run folder", "replay --out into a folder with planted links and a hard-linked trace")
def _replay_out_links(box: Box) -> Spec:
    box.copy_run()
    out = box.root / "replayed"
    out.mkdir()
    box.link(out / "story.md", box.victim())
    os.link(box.victim(), out / "trace.jsonl")
    spec = replay(box)
    return Spec(**{**spec.__dict__, "check": victim_intact(box)})


@attack("chunks", "motion/Zoe.chunks hard-linked to a file outside (resume)")
def _chunk_hardlink(box: Box) -> Spec:
    run = box.copy_run()
    shutil.copy(run / "motion" / "Zoe.chunks", box.outside / "Zoe.chunks")
    (run / "motion" / "Zoe.chunks").unlink()
    os.link(box.outside / "Zoe.chunks", run / "motion" / "Zoe.chunks")
    return resume(box)


@attack("config", "timeout_s = 1e308, max_attempts of 5,000 digits, backoff_max_s = -1")
def _config_numbers(box: Box) -> Spec:
    return model_info(box.file("nums.toml", '[llm]\nmodel = "openai/x"\ntimeout_s = 1e308\n[llm.retry]\n'
                                            f"max_attempts = {'9' * 5000}\nbackoff_max_s = -1\n"))


@attack("script", "times with Arabic-Indic digits, negative and past the run")
def _script_digits(box: Box) -> Spec:
    return script_run(box, box.file("digits.txt", "\u0660\u0660:\u0660\u0661 sit\n-00:05 stand\n99999999:00 go\n"))


@attack("program", "100,000 nested parentheses")
def _program_parens(box: Box) -> Spec:
    text = "def parse_event():\n    x = " + "(" * 100_000 + "1" + ")" * 100_000 + "\n"
    return program_run(box.file("parens.py", text), "program")


@attack("program", "a 5 MB string literal and 50,000 statements")
def _program_big(box: Box) -> Spec:
    text = "def parse_event():\n    s = '" + "a" * 5_000_000 + "'\n" + "    x = 1\n" * 50_000
    return program_run(box.file("big.py", text), "program")


@attack("scene", "box sizes -1 and 1e300, heading 1e300")
def _scene_sizes(box: Box) -> Spec:
    objects = [box_object(0), {**box_object(1), "size": [-1.0, 0.5, 0.5]},
               {**box_object(2), "size": [1e300, 1e300, 1.0], "heading": 1e300}]
    return inspect(box.file("sizes.json", scene_json(objects)))


@attack("mesh", ".obj with 200,000 named objects and 5,000-digit face indices")
def _mesh_objects(box: Box) -> Spec:
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1"]
    for i in range(200_000):
        lines += [f"o chair_{i}", "f 1 2 3"]
    lines += ["o table_1", "f " + "9" * 5000 + " 2 3"]
    return inspect(box.file("objects.obj", "\n".join(lines) + "\n"), "either")


REFERENCE_HOUSE = Path(os.environ.get("STORYTELLER_REFERENCE", "/nonexistent")) / "configs" / "scenes" / "House"


def _reference_copy(box: Box) -> Path:
    folder = box.root / "House"
    if REFERENCE_HOUSE.is_dir():
        shutil.copytree(REFERENCE_HOUSE, folder)
    else:  # without the reference data: a folder of the same files, empty
        folder.mkdir()
        for name in ("objects.json", "scene.json", "scene_cfg.json", "grid_map.json"):
            (folder / name).write_text("{}", encoding="utf-8")
    return folder


@attack("scene", "reference folder: objects.json a FIFO, grid_map.json -> /dev/zero")
def _reference_special(box: Box) -> Spec:
    folder = _reference_copy(box)
    box.fifo(folder / "objects.json")
    box.link(folder / "grid_map.json", "/dev/zero")
    return inspect(folder)


@attack("scene", "reference folder: scene.json deep, scene_cfg.json with bidi and 5,000 digits")
def _reference_text(box: Box) -> Spec:
    folder = _reference_copy(box)
    (folder / "scene.json").write_text(deep_json(100_000), encoding="utf-8")
    (folder / "scene_cfg.json").write_text('{"name": "' + BIDI + '", "cell": ' + "9" * 5000 + "}", encoding="utf-8")
    return inspect(folder)


@attack("trace", "500,000 records (75 MB) of run lines")
def _trace_many(box: Box) -> Spec:
    path, records = _trace_records(box)
    line = (json.dumps(records[0]) + "\n").encode()
    with open(path, "ab") as f:
        f.write(line * 500_000)
    return replay(box, "either")


@attack("run.json", "a script of 100,000 instruction lines (replay)")
def _runjson_script(box: Box) -> Spec:
    run = box.copy_run()
    script = [{"time_s": i * 0.001, "text": f"line {i}" + BIDI} for i in range(100_000)]
    box.edit_json(run / "run.json", lambda v: {**v, "arguments": {**v["arguments"], "instructions": script}})
    return replay(box, "either")


@attack("story.jsonl", "1,000,000 event lines (export)")
def _stream_many(box: Box) -> Spec:
    run = box.copy_run()
    (run / "story.json").unlink()
    lines = (run / "story.jsonl").read_bytes().splitlines(keepends=True)
    with open(run / "story.jsonl", "ab") as f:
        f.write(lines[-1] * 1_000_000)
    return export(box, "either")


@attack("program", "--states with 10,000 characters named with bidi and 100 KB names")
def _program_states_names(box: Box) -> Spec:
    states = {"current_states": {f"Zoe{i}" + BIDI + "n" * 10: {"position": [1.0, 1.0], "action": "idle"}
                                 for i in range(10_000)}}
    states["current_states"]["x" * 100_000] = {"position": [1.0, 1.0]}
    spec = program_run(box.file("prog.py", CLEAN_PROGRAM), "program")
    spec.argv += ["--states", str(box.file("states.json", json.dumps(states)))]
    return spec


@attack("run.json", "run -d 1e308 and 24 characters for 2,000 s (a run.json resume refuses)")
def _run_duration(box: Box) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "-n", "24", "-d", "2000", "--out", str(out), "--no-interactive", "--no-live"],
                "run", "bad", writable=(out,))


# ---------------------------------------------------------------- viewer (a live server)


def _viewer_requests(box: Box, url: str) -> str | None:
    host, port = url.removeprefix("http://").split("/")[0].rsplit(":", 1)

    def get(path: str, headers: dict[str, str]) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection(host, int(port), timeout=5)
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        for k, v in {"Host": f"{host}:{port}", **headers}.items():
            conn.putheader(k, v)
        conn.endheaders()
        res = conn.getresponse()
        body = res.read(1 << 20)
        conn.close()
        return res.status, body

    ws = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
          "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="}
    problems = []
    if get("/", {"Origin": "http://evil.example"})[0] != 403:
        problems.append("page answered to another origin")
    if get("/", {"Host": "evil.example"})[0] != 403:
        problems.append("page answered to a rebound host name")
    if get("/", {**ws, "Origin": "http://evil.example"})[0] == 101:
        problems.append("websocket opened for another origin")
    if get("/", {**ws, "Origin": "null"})[0] == 101:
        problems.append("websocket opened for a null origin")
    for path in ("/../../../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "//etc/passwd",
                 "/..%2f..%2f..%2f..%2fetc%2fpasswd", "/" + "a/" * 20_000):
        with contextlib.suppress(OSError, http.client.HTTPException):
            _status, body = get(path, {})
            if b"root:" in body:
                problems.append(f"served /etc/passwd for {path[:30]}")
    # A websocket of the right origin sends a frame claiming 2**40 bytes: the server must live on.
    with contextlib.suppress(OSError), socket.create_connection((host, int(port)), timeout=5) as s:
        lines = ["GET / HTTP/1.1", f"Host: {host}:{port}", f"Origin: http://{host}:{port}",
                 *(f"{k}: {v}" for k, v in ws.items()), "", ""]
        s.sendall("\r\n".join(lines).encode())
        s.recv(4096)
        s.sendall(b"\x82\xff" + struct.pack(">Q", 1 << 40) + b"\0\0\0\0" + b"\0" * (1 << 20))
    if get("/", {})[0] != 200:
        problems.append("viewer stopped answering after a huge websocket frame")
    return "; ".join(problems) or None


VIEWER_KIND = ("viewer", "forged Origin / Host, websocket, traversal, a 2**40-byte frame")


# ---------------------------------------------------------------- running


@dataclass
class Outcome:
    kind: str
    name: str
    code: int | None
    seconds: float
    rss: int
    problems: list[str]

    @property
    def verdict(self) -> str:
        return "ok" if not self.problems else "FAIL: " + "; ".join(self.problems)


def tree_state(root: Path, skip: tuple[Path, ...]) -> dict[str, tuple[int, int, int]]:
    """Every entry under ``root`` but ``skip``: (mode, size, mtime) from lstat, links not followed."""
    state: dict[str, tuple[int, int, int]] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if here / d not in skip]
        for name in (*dirnames, *filenames):
            path = here / name
            if path in skip:
                continue
            st = os.lstat(path)  # a folder's own times change as its outputs are written: its mode only
            state[str(path)] = (st.st_mode, 0, 0) if stat.S_ISDIR(st.st_mode) else (st.st_mode, st.st_size, st.st_mtime_ns)
    return state


def digest(root: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    if not root.is_dir() or root.is_symlink():
        return out
    for path in sorted(root.rglob("*")):
        if path.is_symlink() or not path.is_file():
            out[str(path)] = "special"
        elif path.stat().st_size < (64 << 20):
            out[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def bad_characters(text: str) -> list[str]:
    return sorted({f"U+{ord(c):04X}" for c in text
                   if unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp") and c not in "\n\t"})


def limit_child() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def run_command(argv: list[str], timeout: float, env: dict[str, str], cwd: Path,
                stdin: bytes | None = None) -> tuple[int | None, float, int, str, str]:
    """Run the CLI with ``argv``: (exit code or None after a kill at ``timeout``, seconds, max
    RSS in bytes, stdout, stderr)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.monotonic()
        proc = subprocess.Popen([*CLI, *argv], stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env, cwd=cwd,
                                preexec_fn=limit_child, start_new_session=True)
        code: int | None = None
        rss = 0
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                rss = usage.ru_maxrss * 1024
                break
            if time.monotonic() - start > timeout:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                _, status, usage = os.wait4(proc.pid, 0)
                rss = usage.ru_maxrss * 1024
                break
            time.sleep(0.05)
        seconds = time.monotonic() - start
        proc.returncode = -1  # reaped here
        out.seek(0)
        err.seek(0)
        return code, seconds, rss, out.read().decode("utf-8", "replace"), err.read().decode("utf-8", "replace")


def judge(spec: Spec, code: int | None, seconds: float, rss: int, stdout: str, stderr: str, limit: float) -> list[str]:
    problems = []
    if code is None:
        problems.append(f"killed after {limit:.0f} s")
    elif seconds > limit:
        problems.append(f"{seconds:.1f} s > {limit:.1f} s")
    if rss > RSS_LIMIT:
        problems.append(f"RSS {rss >> 20} MiB")
    lines = [line for line in stderr.splitlines() if line.strip()]
    if "Traceback" in stdout + stderr:
        problems.append("traceback")
    one_line = code == 2 and len(lines) == 1 and lines[0].startswith("error:")
    refused_program = code == 1 and len(lines) == 1 and lines[0].startswith("error (")
    accepted = spec.expect in ("either", "program") and code == 0
    if code is not None and not (one_line or accepted or (spec.expect == "program" and refused_program)):
        shown = (lines[-1] if lines else "")[:120]
        problems.append(f"exit {code} with {len(lines)} stderr lines ({shown!r})")
    bad = bad_characters(stdout + stderr)
    if bad:
        problems.append("raw " + ",".join(bad[:4]))
    return problems


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


def run_viewer(box: Box, env: dict[str, str]) -> Outcome:
    box.copy_run()
    start = time.monotonic()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([*CLI, "view", str(box.run), "--port", "0"], stdout=subprocess.PIPE, stderr=err, env=env,
                                preexec_fn=limit_child, start_new_session=True)
        problems: list[str] = []
        rss = 0
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline().decode("utf-8", "replace")
            url = next((w for w in line.split() if w.startswith("http://")), None)
            if url is None:
                problems.append(f"no URL printed: {line[:100]!r}")
            else:
                found = _viewer_requests(box, url)
                if found:
                    problems.append(found)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            _, _, usage = os.wait4(proc.pid, 0)
            rss = usage.ru_maxrss * 1024
            proc.returncode = -1
        if rss > RSS_LIMIT:
            problems.append(f"RSS {rss >> 20} MiB")
    return Outcome(VIEWER_KIND[0], VIEWER_KIND[1], None, time.monotonic() - start, rss, problems)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmark.hostile_inputs", description=__doc__.splitlines()[0])
    p.add_argument("--only", default="", help="run only the attacks whose kind or name holds this text")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args(argv)
    chosen = [a for a in ATTACKS if args.only.lower() in f"{a[0]} {a[1]}".lower()]
    env = {k: v for k, v in os.environ.items() if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL")}
    env["STORYTELLER_SCRIPTED_STORY_KEY"] = "scripted"  # not a secret: the local scripted servers ignore it
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    with workspace(args.keep) as root:
        base = root / "base"
        if build_story(base, seconds=3, names=("Zoe", "Max"), quiet=True) != 0:
            print("error: the base run failed", file=sys.stderr)
            return 2
        sweep = build_sweep(root, env) if any(kind == "bench" for kind, _, _ in chosen) else root
        shutil.copytree(base, root / "clean-resume")
        if sweep != root:
            shutil.copytree(sweep, root / "clean-sweep")
        (root / "clean.py").write_text(CLEAN_PROGRAM, encoding="utf-8")
        clean: dict[str, float] = {}  # the clean command's seconds, measured before its first attack
        outcomes = []
        print(f"{'kind':<11} {'attack':<66} {'exit':>4} {'s':>6} {'MiB':>5}  verdict", flush=True)
        for i, (kind, name, build) in enumerate(chosen):
            box = Box(root / "attacks" / f"{i:02d}", base, sweep, root / "attacks" / f"{i:02d}" / CANARY)
            outcome = attempt(kind, name, build, box, root, sweep, env, clean)
            outcomes.append(outcome)
            print(row(outcome), flush=True)
        if args.only.lower() in f"{VIEWER_KIND[0]} {VIEWER_KIND[1]}".lower():
            box = Box(root / "attacks" / "viewer", base, sweep, root / "attacks" / "viewer" / CANARY)
            outcome = run_viewer(box, env)
            outcomes.append(outcome)
            print(row(outcome), flush=True)
        failed = [o for o in outcomes if o.problems]
        kinds: dict[str, int] = {}
        for o in outcomes:
            kinds[o.kind] = kinds.get(o.kind, 0) + 1
        print(f"{len(outcomes)} attacks ({', '.join(f'{k} {n}' for k, n in kinds.items())}): "
              f"{len(outcomes) - len(failed)} held, {len(failed)} failed")
        return 1 if failed else 0


def attempt(kind: str, name: str, build: Callable[[Box], Spec], box: Box, root: Path, sweep: Path,
            env: dict[str, str], clean: dict[str, float]) -> Outcome:
    spec = build(box)
    if spec.command not in clean:
        code, seconds, rss, _, _ = run_command(BASE_COMMANDS[spec.command](root, box.base, sweep), 600, env, root)
        clean[spec.command] = seconds
        print(f"{'(clean)':<11} {spec.command:<66} {code!s:>4} {seconds:6.1f} {rss >> 20:5d}", flush=True)
    limit = clean[spec.command] + SLACK_S
    skip = (box.run, *spec.writable, Path(env.get("HOME", "/nonexistent")))
    before_tree = tree_state(root, (*skip, root / "attacks" / "scratch"))
    before_run = digest(box.run)
    code, seconds, rss, stdout, stderr = run_command(spec.argv, limit, env, box.root, spec.stdin)
    problems = judge(spec, code, seconds, rss, stdout, stderr, limit)
    after_tree = tree_state(root, (*skip, root / "attacks" / "scratch"))
    changed = sorted(k for k in set(before_tree) | set(after_tree) if before_tree.get(k) != after_tree.get(k))
    if changed:
        problems.append("wrote outside the run folder: " + ", ".join(str(Path(c).relative_to(root)) for c in changed[:3]))
    if box.canary.exists():
        problems.append("CODE RAN (canary file created)")
    if code == 2 and before_run and digest(box.run) != before_run:
        problems.append("refused, yet the run folder changed")
    if spec.check is not None and code == 0:
        found = spec.check()
        if found:
            problems.append(found)
    return Outcome(kind, name, code, seconds, rss, problems)


def row(o: Outcome) -> str:
    return f"{o.kind:<11} {o.name[:66]:<66} {o.code!s:>4} {o.seconds:6.1f} {o.rss >> 20:5d}  {o.verdict}"


if __name__ == "__main__":
    raise SystemExit(main())
