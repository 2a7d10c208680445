"""Attacks on how a run folder's files are opened and written (a second corpus, written from
outside the first): sparse gigabyte files under the names a command reads, FIFOs and sockets
under the names it writes or appends to, hard links of the files a resume rewrites, a chunk
file linked outside, a folder where a file is expected, floods of inbox lines, snapshot headers
that lie, and a file replaced between the check and the use.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import threading
import time
from pathlib import Path

from storyteller.benchmark.hostile.harness import (
    Attack,
    Box,
    Spec,
    export,
    registrar,
    replay,
    resume,
    snapshot_with,
    sparse_file,
    victim_intact,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)

_GB3 = 3 << 30


def _with_check(spec: Spec, box: Box) -> Spec:
    return Spec(**{**spec.__dict__, "check": victim_intact(box)})


@attack("sparse", "run.json a sparse 3 GB file (resume)")
def _sparse_runjson(box: Box) -> Spec:
    sparse_file(box.copy_run() / "run.json", _GB3)
    return resume(box)


@attack("sparse", "trace.jsonl a sparse 3 GB file (replay)")
def _sparse_trace(box: Box) -> Spec:
    sparse_file(box.copy_run() / "trace.jsonl", _GB3)
    return replay(box)


@attack("sparse", "story.json and story.jsonl sparse 3 GB files (export)")
def _sparse_story(box: Box) -> Spec:
    run = box.copy_run()
    sparse_file(run / "story.json", _GB3)
    sparse_file(run / "story.jsonl", _GB3)
    return export(box)


@attack("sparse", "motion/Zoe.chunks a sparse 3 GB file (resume)")
def _sparse_chunks(box: Box) -> Spec:
    sparse_file(box.copy_run() / "motion" / "Zoe.chunks", _GB3)
    return resume(box)


@attack("sparse", "session.snapshot a sparse 3 GB file (resume)")
def _sparse_snapshot(box: Box) -> Spec:
    sparse_file(box.copy_run() / "session.snapshot", _GB3)
    return resume(box)


@attack("sparse", "scene.json in the run folder a sparse 3 GB file (export)")
def _sparse_scene(box: Box) -> Spec:
    sparse_file(box.copy_run() / "scene.json", _GB3)
    return export(box)


@attack("sparse", "viewer_instructions.jsonl and viewer_controls.jsonl sparse 3 GB (resume)")
def _sparse_inbox(box: Box) -> Spec:
    run = box.copy_run()
    sparse_file(run / "viewer_instructions.jsonl", _GB3)
    sparse_file(run / "viewer_controls.jsonl", _GB3)
    return resume(box, "either")


@attack("special", "FIFOs named story.jsonl, story.md and metrics.json (resume writes them)")
def _fifo_outputs(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("story.jsonl", "story.md", "metrics.json"):
        box.fifo(run / name)
    return resume(box)


@attack("special", "a Unix socket named trace.jsonl (replay)")
def _socket_trace(box: Box) -> Spec:
    run = box.copy_run()
    (run / "trace.jsonl").unlink()
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(run / "trace.jsonl"))  # left bound: the file stays a socket while the command runs
    _KEEP.append(sock)
    return replay(box)


_KEEP: list[socket.socket] = []  # sockets the attacks bind live until the harness ends


@attack("special", "folders named run.json and session.snapshot (resume)")
def _folders_for_files(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("run.json", "session.snapshot"):
        (run / name).unlink()
        (run / name).mkdir()
        (run / name / "x").write_text("x", encoding="utf-8")
    return resume(box)


@attack("special", "motion/ a regular file, motion/Zoe.chunks gone (export)")
def _motion_file(box: Box) -> Spec:
    run = box.copy_run()
    shutil.rmtree(run / "motion")
    (run / "motion").write_bytes(b"\0" * 4096)
    return export(box, "either")


@attack("links", "motion/Zoe.chunks -> a copy outside (resume appends to it)")
def _link_chunks(box: Box) -> Spec:
    run = box.copy_run()
    shutil.copy(run / "motion" / "Zoe.chunks", box.outside / "Zoe.chunks")
    box.link(run / "motion" / "Zoe.chunks", box.outside / "Zoe.chunks")
    return resume(box)


@attack("links", "session.snapshot, run.json, scene.glb, topdown.png hard-linked outside (resume)")
def _hardlink_rewritten(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("session.snapshot", "run.json", "scene.glb", "topdown.png", "Zoe.track.npz", "metrics.json"):
        shutil.copy(run / name, box.outside / name)
        (run / name).unlink()
        os.link(box.outside / name, run / name)
    before = {name: (box.outside / name).read_bytes() for name in ("scene.glb", "topdown.png", "metrics.json")}

    def check() -> str | None:
        changed = [n for n, data in before.items() if (box.outside / n).read_bytes() != data]
        return f"wrote through hard links: {', '.join(changed)}" if changed else None

    return Spec(**{**resume(box, "either").__dict__, "check": check})


@attack("links", "viewer_controls.jsonl and viewer_instructions.jsonl -> victim (resume)")
def _link_inbox(box: Box) -> Spec:
    run = box.copy_run()
    box.link(run / "viewer_instructions.jsonl", box.victim())
    box.link(run / "viewer_controls.jsonl", box.victim())
    return _with_check(resume(box, "either"), box)


@attack("links", "replay --out is a link to a folder outside")
def _replay_out_link(box: Box) -> Spec:
    box.copy_run()
    out = box.root / "replayed"
    out.symlink_to(box.outside / "dir")
    return Spec(["replay", str(box.run), "--out", str(out), "--no-live"], "replay", "bad")


@attack("inbox", "viewer_instructions.jsonl of 1,000,000 valid lines (resume)")
def _inbox_flood(box: Box) -> Spec:
    run = box.copy_run()
    thread = json.loads((run / "run.json").read_text(encoding="utf-8"))["thread_id"]
    with open(run / "viewer_instructions.jsonl", "w", encoding="utf-8") as f:
        for i in range(1_000_000):
            f.write(json.dumps({"id": f"{i:032x}", "thread": thread, "text": "Zoe sits", "sent_unix": 1.7e9}) + "\n")
    return resume(box, "either")


@attack("inbox", "viewer_controls.jsonl of 1,000,000 pause/resume lines (resume)")
def _controls_flood(box: Box) -> Spec:
    run = box.copy_run()
    thread = json.loads((run / "run.json").read_text(encoding="utf-8"))["thread_id"]
    with open(run / "viewer_controls.jsonl", "w", encoding="utf-8") as f:
        for i in range(1_000_000):
            kind = "pause" if i % 2 == 0 else "resume"
            f.write(json.dumps({"id": f"{i:032x}", "thread": thread, "kind": kind, "sent_unix": 1.7e9}) + "\n")
    return resume(box, "either")


@attack("snapshot", "header of 40 MB with no newline")
def _snap_header(box: Box) -> Spec:
    (box.copy_run() / "session.snapshot").write_bytes(b"storyteller-snapshot 6 sha256=" + b"a" * 40_000_000)
    return resume(box)


@attack("snapshot", "a pickle of a billion-laughs list (checksum fixed)")
def _snap_laughs(box: Box) -> Spec:
    # 60 levels of a list holding its child twice: 2**60 items when walked, 120 opcodes.
    payload = b"\x80\x04]\x94"  # an empty list, memo 0
    for level in range(1, 61):
        payload += b"]\x94h" + bytes([level - 1]) + b"h" + bytes([level - 1]) + b"e"
    (box.copy_run() / "session.snapshot").write_bytes(snapshot_with(payload + b"."))
    return resume(box)


def _flip(path: Path, good: bytes, seconds: float = 15.0) -> None:
    """Replace ``path`` every millisecond, for ``seconds``, by turns with a FIFO and a link to
    ``/dev/zero`` and the ``good`` bytes (a check then a use of the path see different files)."""
    stop = time.monotonic() + seconds
    tmp = path.with_name("." + path.name + ".swap")

    def flip() -> None:
        turn = 0
        while time.monotonic() < stop:
            with contextlib.suppress(OSError):
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()
                if turn % 3 == 0:
                    os.mkfifo(tmp)
                elif turn % 3 == 1:
                    tmp.symlink_to("/dev/zero")
                else:
                    tmp.write_bytes(good)
                os.replace(tmp, path)
            turn += 1
            time.sleep(0.001)
        with contextlib.suppress(OSError):
            tmp.write_bytes(good)
            os.replace(tmp, path)

    threading.Thread(target=flip, daemon=True).start()


def _scratch(box: Box) -> Path:
    """A folder the harness does not watch (a race changes its files while the command runs)."""
    folder = box.root.parent / "scratch" / box.root.name
    folder.mkdir(parents=True)
    return folder


@attack("race", "trace.jsonl replaced by a FIFO and /dev/zero between check and use (replay)")
def _race_trace(box: Box) -> Spec:
    run = _scratch(box) / "run"
    shutil.copytree(box.base, run)
    _flip(run / "trace.jsonl", (run / "trace.jsonl").read_bytes())
    out = box.root / "replayed"
    return Spec(["replay", str(run), "--out", str(out), "--no-live"], "replay", "either", writable=(out,))


@attack("race", "a scene file replaced by a FIFO and /dev/zero between check and use (scene inspect)")
def _race_scene(box: Box) -> Spec:
    scene = _scratch(box) / "scene.json"
    scene.write_bytes((box.base / "scene.json").read_bytes())
    _flip(scene, scene.read_bytes())
    return Spec(["scene", "inspect", str(scene)], "scene inspect", "either")


@attack("text", "a run folder named with a newline, an OSC title escape, BEL and RLO (resume)")
def _folder_name(box: Box) -> Spec:
    box.run = box.root / "run\n\x1b]0;owned\x07\u202e[/]"
    box.copy_run()
    return resume(box, "either")


@attack("text", "a missing run folder named with ANSI clear-screen and a line separator (export)")
def _missing_name(box: Box) -> Spec:
    box.run = box.root / "gone\x1b[2J\u2028"
    return export(box)
