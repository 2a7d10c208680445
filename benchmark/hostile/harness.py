"""The harness of ``python -m storyteller.benchmark.hostile_inputs``: the limits and the hostile text, an
attack's folder (:class:`Box`) and what it runs (:class:`Spec`), the commands an attack runs
(``resume``, ``replay``, ``view --export``, ``scene inspect``, ``bench score``), the builders of
hostile data and the registry the attack modules fill (:func:`registrar`).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import shutil
import struct
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

AS_LIMIT = 4 << 30
"""Address space of an attacked command (bytes): a guard for the machine, the verdict reads RSS."""
RSS_LIMIT = 1 << 30
"""Max resident set size of an attacked command (bytes), as the issue asks."""
SLACK_S = 6.0
"""Seconds an attack may take beyond the clean run of the same command."""
CLI = [sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()"]
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
    check_output: Callable[[str], str | None] | None = None
    """A check of what the command printed (stdout, then stderr): a problem, or None."""
    stdin: bytes | None = None
    env: dict[str, str] = field(default_factory=dict)
    """Environment variables set (over the harness's) for the attacked command."""


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


def inspect(path: Path, expect: Expect = "bad", check_output: Callable[[str], str | None] | None = None) -> Spec:
    return Spec(["scene", "inspect", str(path)], "scene inspect", expect, check_output=check_output)


def score(box: Box, sweep: Path, expect: Expect = "bad") -> Spec:
    return Spec(["bench", "score", str(sweep)], "bench score", expect)


def glb_file(doc: dict[str, Any], binary: bytes = b"") -> bytes:
    """A ``.glb``: the glTF JSON ``doc`` and, if any, a binary chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I", len(text)) + b"JSON" + text
    if binary:
        chunks += struct.pack("<I", len(binary)) + b"BIN\0" + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def gltf_doc(nodes: list[dict[str, Any]], count: int = 3, uri: str | None = None) -> dict[str, Any]:
    """A glTF document of one point geometry of ``count`` VEC3 floats (in a buffer named ``uri``,
    or the GLB's own) and ``nodes``, all in the scene."""
    buffer: dict[str, Any] = {"byteLength": count * 12, **({"uri": uri} if uri else {})}
    return {"asset": {"version": "2.0"}, "buffers": [buffer],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": count * 12}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": count, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 1]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": nodes, "scenes": [{"nodes": list(range(len(nodes)))}], "scene": 0}


def sparse_file(path: Path, size: int) -> Path:
    """A regular file of ``size`` bytes that takes no room on disk (a hole)."""
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def deep_json(depth: int) -> str:
    return "[" * depth + "]" * depth


def snapshot_with(payload: bytes) -> bytes:
    """A ``session.snapshot`` of the current format holding ``payload`` with its right checksum."""
    return b"storyteller-snapshot 6 sha256=" + hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload


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
    """A scene of the project's JSON format holding ``objects``, valid but for what an attack puts in
    it: the floor is the rectangle 1 m around the objects' centres (``bounds_min`` and ``bounds_max``
    in ``extra`` replace it), so the scene reaches the code its hostile part targets."""
    xs = [float(o["center"][0]) for o in objects] or [0.0]
    ys = [float(o["center"][1]) for o in objects] or [0.0]
    floor = {"bounds_min": [min(xs) - 1.0, min(ys) - 1.0], "bounds_max": [max(xs) + 1.0, max(ys) + 1.0]}
    return json.dumps({"name": "hostile", **floor, "objects": objects, **extra})


def box_object(i: int, label: str = "chair", size: float = 0.5, x: float | None = None, y: float = 0.0) -> dict[str, Any]:
    """A valid object ``<label>_<i>`` of the project's scene JSON: a cube of ``size`` metres on the
    floor at (``x``, default ``i``; ``y``)."""
    cx = float(i) if x is None else x
    return {"name": f"{label}_{i}", "label": label, "idx": i, "center": [cx, y, size / 2], "size": [size, size, size]}


def refused_for(*words: str) -> Callable[[str], str | None]:
    """A :attr:`Spec.check_output` for an attack the product may refuse: a refusal must be for its
    hostile part, its ``error:`` line holding every one of ``words`` (the file, field or limit the
    attack targets); a refusal for anything else means the input never reached its target."""

    def check(printed: str) -> str | None:
        errors = [line for line in printed.splitlines() if line.startswith("error")]
        if errors and not all(word in errors[0] for word in words):
            return f"refused for another reason than {' '.join(words)!r}: {errors[0][:100]!r}"
        return None

    return check


def shown(text: str) -> Callable[[str], str | None]:
    """A :attr:`Spec.check_output` for an attack on an input the product must accept: the command
    prints ``text`` (a refusal, for whatever reason, means the input never reached its target)."""
    return lambda printed: None if text in printed else f"{text!r} not shown"


class Reduce:
    """Pickles as a call of ``os.system`` (the classic pickle payload)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (self.command,))


Attack = tuple[str, str, Callable[[Box], Spec]]
"""(kind, name, the function that prepares the attack in its box and returns what to run)."""


def registrar(into: list[Attack]) -> Callable[[str, str], Callable[[Callable[[Box], Spec]], Callable[[Box], Spec]]]:
    """The ``@attack(kind, name)`` decorator of an attack module: it appends to ``into``."""

    def attack(kind: str, name: str) -> Callable[[Callable[[Box], Spec]], Callable[[Box], Spec]]:
        def add(fn: Callable[[Box], Spec]) -> Callable[[Box], Spec]:
            into.append((kind, name, fn))
            return fn

        return add

    return attack
