"""Adversarial fuzzing of every file the product reads back from a run folder, one target per
kind, through the command that reads it: ``session.snapshot``, ``run.json`` and
``trace.jsonl`` (``resume``, ``replay``), ``story.json``, ``story.jsonl``, ``motion/*.chunks``
and ``*.track.npz`` (``view --export``). Each example copies a short finished run, puts a
damaged or hostile version of one file in it (``tests/support/hostile_files.py``: truncations,
bit flips, deep nesting, huge numbers, NaN / Infinity, bytes that are not UTF-8, control and
bidi characters; for the binary formats, records and arrays rebuilt around the damage so it
gets past checksums and CRCs) and checks the outcome: exit 0, or one ``error:`` line and exit 2,
no traceback, nothing raw on the terminal (``clean_outcome``). Special files (a link to
``/dev/zero``, a FIFO, a folder, a 5 GB sparse file) are checked for every kind, and two heavy
cases run in a subprocess under an address-space limit.

The files a user hands the product (scene JSON, config TOML, instruction scripts, bench cases)
are fuzzed for one line / exit 2 in ``tests/orchestrator/cli/test_fuzz_bounded_inputs.py``; here they get the
special files and text that would reach the terminal raw.

Bounded for CI: ``derandomize=True`` (the same examples every run), a few examples per target
(``FUZZ_EXAMPLES=N`` asks for more on a local run), no deadline (tests never assert time). The
cases the fuzzing found are kept as plain tests at the end.
"""

from __future__ import annotations

import io
import json
import os
import pickletools
import shutil
import struct
import subprocess
import sys
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner, Result

from storyteller.orchestrator.cli.app import app
from tests.support.hostile_files import (
    bit_flipped,
    clean_outcome,
    hostile_bytes,
    truncated,
)

ROOT = Path(__file__).resolve().parents[3]
FUZZ = settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", "8")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
FEW = settings(FUZZ, max_examples=5)



@contextmanager
def copied(run: Path) -> Iterator[Path]:
    """A fresh copy of the run folder (each example damages its own)."""
    with tempfile.TemporaryDirectory() as tmp:
        yield Path(shutil.copytree(run, Path(tmp) / "run", symlinks=True))


def invoke(*args: str) -> Result:
    return CliRunner().invoke(app, list(args))


def resume(run: Path) -> Result:
    return invoke("resume", str(run), "--no-interactive", "--no-live")


def replay(run: Path) -> Result:
    return invoke("replay", str(run), "--out", str(run.parent / "replayed"), "--no-live")


def export(run: Path) -> Result:
    return invoke("view", str(run), "--export", str(run.parent / "story.html"))


# ----- run.json, trace.jsonl: resume and replay ---------------------------------------------------
def _manifest_loads(run: Path) -> bool:
    from storyteller.orchestrator.session.run_manifest import ManifestError, read_manifest

    try:
        read_manifest(run)
    except ManifestError:
        return False
    return True


@FUZZ
@given(data=st.data(), command=st.sampled_from([resume, replay]))
@pytest.mark.slow
def test_fuzzed_run_json(finished_run: Path, data: st.DataObject, command: Callable[[Path], Result]) -> None:
    valid = (finished_run / "run.json").read_bytes()
    with copied(finished_run) as run:
        (run / "run.json").write_bytes(data.draw(hostile_bytes(valid)))
        if _manifest_loads(run):
            return  # other arguments that read back: a run of them (a model call) is not a bad file
        result = command(run)
        clean_outcome(result)
        assert result.exit_code == 2


@FUZZ
@given(data=st.data(), command=st.sampled_from([replay, replay, resume]))
@pytest.mark.slow
def test_fuzzed_trace(finished_run: Path, data: st.DataObject, command: Callable[[Path], Result]) -> None:
    valid = (finished_run / "trace.jsonl").read_bytes()
    with copied(finished_run) as run:
        (run / "trace.jsonl").write_bytes(data.draw(hostile_bytes(valid)))
        result = command(run)
        if result.exit_code == 2 and "does not apply" in result.stderr:  # an answer changed: asks what was never recorded
            assert "error: cannot replay" in result.stderr, result.stderr[-2000:]
        clean_outcome(result)


# ----- session.snapshot: resume ----------------------------------------------------------------
def _payload_without_frames(snapshot: bytes) -> bytes:
    payload = snapshot[snapshot.index(b"\n") + 1:]
    cuts = [pos for op, _, pos in pickletools.genops(payload) if op.name == "FRAME" and pos is not None]
    for pos in reversed(cuts):
        payload = payload[:pos] + payload[pos + 9:]
    return payload


def _with_header(payload: bytes) -> bytes:
    import hashlib

    return b"storyteller-snapshot 6 sha256=%s\n" % hashlib.sha256(payload).hexdigest().encode() + payload


_VALUE_OPS = frozenset({"BININT", "BININT1", "BININT2", "LONG1", "BINFLOAT", "SHORT_BINUNICODE", "BINUNICODE",
                        "NONE", "NEWTRUE", "NEWFALSE", "EMPTY_TUPLE", "EMPTY_LIST", "EMPTY_DICT"})
_REPLACEMENTS = (
    b"N", b"\x88", b"\x89", b"K\x07", b"J\xff\xff\xff\xff", b"\x8a\x09" + b"\xff" * 8 + b"\x7f",
    b"\x8c\x01x", b"\x8c\x05\xe2\x80\xae\x1b]", b"G" + struct.pack(">d", float("nan")),
    b"G" + struct.pack(">d", float("inf")), b"G" + struct.pack(">d", 1e300), b"]", b")", b"}",
)


@st.composite
def snapshot_versions(draw: st.DrawFn, valid: bytes) -> bytes:
    """A damaged snapshot: bytes flipped or cut (the checksum stops them), or one value of the
    pickle replaced by a value of another type or an extreme one, with the checksum made to
    match (so the decoder and the checks after it see it)."""
    how = draw(st.sampled_from(["bytes", "value", "value", "value"]))
    if how == "bytes":
        return draw(st.one_of(truncated(valid), bit_flipped(valid)))
    payload = _payload_without_frames(valid)
    for _ in range(draw(st.integers(1, 2))):
        starts = [(pos, op.name) for op, _, pos in pickletools.genops(payload) if pos is not None]
        ends = {pos: nxt for (pos, _), (nxt, _) in zip(starts, [*starts[1:], (len(payload), "")], strict=True)}
        pos = draw(st.sampled_from([p for p, name in starts if name in _VALUE_OPS]))
        payload = payload[:pos] + draw(st.sampled_from(_REPLACEMENTS)) + payload[ends[pos]:]
    return _with_header(payload)


@FUZZ
@given(data=st.data())
@pytest.mark.slow
def test_fuzzed_snapshot(finished_run: Path, data: st.DataObject) -> None:
    valid = (finished_run / "session.snapshot").read_bytes()
    with copied(finished_run) as run:
        (run / "session.snapshot").write_bytes(data.draw(snapshot_versions(valid)))
        clean_outcome(resume(run))


@pytest.mark.slow
def test_a_snapshot_whose_nested_model_lost_a_field_is_one_line(finished_run: Path) -> None:
    """Found by the fuzzer: an assignment whose ``partners`` key became None. The event holding it
    is validated first, and its validator read the missing field (AttributeError, exit 1)."""
    payload = _payload_without_frames((finished_run / "session.snapshot").read_bytes())
    needle = b"\x8c\x08partners\x94"
    assert needle in payload
    with copied(finished_run) as run:
        (run / "session.snapshot").write_bytes(_with_header(payload.replace(needle, b"N\x94", 1)))
        result = resume(run)
        clean_outcome(result, codes=(2,))
        assert "cannot read the session checkpoint" in result.stderr


# ----- story.json, story.jsonl: view --export ------------------------------------------------------
@FUZZ
@given(data=st.data())
def test_fuzzed_story_json(finished_run: Path, data: st.DataObject) -> None:
    valid = (finished_run / "story.json").read_bytes()
    with copied(finished_run) as run:
        (run / "story.json").write_bytes(data.draw(hostile_bytes(valid)))
        clean_outcome(export(run))


@FUZZ
@given(data=st.data())
def test_fuzzed_story_stream_of_a_run_in_progress(finished_run: Path, data: st.DataObject) -> None:
    valid = (finished_run / "story.jsonl").read_bytes()
    with copied(finished_run) as run:
        (run / "story.json").unlink()  # a run in progress: the viewer reads the stream and the chunks
        for track in run.glob("*.track.npz"):
            track.unlink()
        (run / "story.jsonl").write_bytes(data.draw(hostile_bytes(valid)))
        clean_outcome(export(run))


# ----- motion/*.chunks: view --export of a stopped run, resume ----------------------------------
_CHUNK_HEADER = struct.Struct("<4sHHQIIQI")


def _records(data: bytes) -> list[tuple[tuple[int, ...], bytes]]:
    """The (header fields, payload) of every record of a chunk file."""
    out, at = [], 0
    while at < len(data):
        fields = _CHUNK_HEADER.unpack_from(data, at)
        size = fields[6]
        out.append((fields, data[at + _CHUNK_HEADER.size: at + _CHUNK_HEADER.size + size]))
        at += _CHUNK_HEADER.size + size
    return out


def _record(fields: tuple[int, ...], payload: bytes, **change: int) -> bytes:
    """A record with its CRC and payload size made to match ``payload`` (so it gets past them)."""
    magic, version, reserved, start, n, names_len, _, _ = fields
    values = {"start": start, "n": n, "names_len": names_len, **change}
    return _CHUNK_HEADER.pack(magic, version, reserved, values["start"], values["n"], values["names_len"],
                              len(payload), zlib.crc32(payload)) + payload


_NAME_TABLES = [b"[" * 5_000 + b"]" * 5_000, b'{"a": 1}', b"[1, 2, 3]", b'["\\ud800", "\\u202e\\u001b[31m"]',
                b"\xff\xfe", b"9" * 5_000, b'["' + b"a" * 100_000 + b'"]', b"null", b"[]"]


@st.composite
def chunk_versions(draw: st.DrawFn, valid: bytes) -> bytes:
    """A damaged chunk file: cut or flipped bytes (a torn or failed record), or a record rebuilt
    around a hostile part with a matching CRC: its name table, frame counts, start frame or
    a payload claimed far larger than the file."""
    how = draw(st.sampled_from(["bytes", "names", "counts", "huge", "payload"]))
    if how == "bytes":
        return draw(st.one_of(truncated(valid), bit_flipped(valid)))
    records = _records(valid)
    k = draw(st.integers(0, len(records) - 1))
    fields, payload = records[k]
    names_len = fields[5]
    if how == "names":
        table = draw(st.sampled_from(_NAME_TABLES))
        new = _record(fields, payload[: len(payload) - names_len] + table, names_len=len(table))
    elif how == "counts":
        new = _record(fields, payload, **{draw(st.sampled_from(["n", "names_len", "start"])):
                                          draw(st.sampled_from([0, 1, fields[4] + 1, 2**31, 2**32 - 1]))})
    elif how == "huge":  # a header that claims 4 GiB of payload (the file ends long before)
        new = _CHUNK_HEADER.pack(*fields[:6], 4 << 30, 0) + payload
    else:  # label and event indices out of range, NaN positions: the payload's numbers
        body = bytearray(payload)
        at = draw(st.integers(0, max(0, len(body) - names_len - 8)))
        body[at: at + 8] = draw(st.sampled_from([b"\xff" * 8, struct.pack("<d", float("nan")),
                                                 struct.pack("<d", float("inf")), b"\x7f\xff\xff\x7f" * 2]))
        new = _record(fields, bytes(body))
    return b"".join(new if i == k else _record(f, p) for i, (f, p) in enumerate(records))


@FUZZ
@given(data=st.data(), command=st.sampled_from(["export", "export", "resume"]))
@pytest.mark.slow
def test_fuzzed_chunk_file(finished_run: Path, data: st.DataObject, command: str) -> None:
    valid = (finished_run / "motion" / "Zoe.chunks").read_bytes()
    with copied(finished_run) as run:
        (run / "motion" / "Zoe.chunks").write_bytes(data.draw(chunk_versions(valid)))
        if command == "resume":
            clean_outcome(resume(run))
        else:
            for track in run.glob("*.track.npz"):  # a run stopped before its exports: the chunks are read
                track.unlink()
            clean_outcome(export(run))


# ----- *.track.npz: view --export -------------------------------------------------------------
def _npz(arrays: dict[str, Any]) -> bytes:
    """``arrays`` (name -> array) as the bytes of an .npz file."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


_ARRAY_VALUES: list[np.ndarray] = [
    np.array(float("nan")), np.array([1.0, 2.0]), np.array("x"), np.array("\ud800"), np.array("\u202e\x1b[31mZoe"),
    np.array(["a", "b"]), np.array(10**18), np.zeros((0, 3)), np.zeros((2, 2, 2)), np.array(True),
    np.full((3, 3), np.inf), np.array("a" * 100_000), np.zeros(5, dtype=np.complex128),
]


@st.composite
def track_versions(draw: st.DrawFn, valid: bytes) -> bytes:
    """A damaged track: its zip cut or flipped, an entry dropped, or one array replaced by another
    shape, dtype or value (NaN, a lone surrogate, control characters in the name...)."""
    how = draw(st.sampled_from(["bytes", "array", "array", "drop"]))
    if how == "bytes":
        return draw(st.one_of(truncated(valid), bit_flipped(valid)))
    with np.load(io.BytesIO(valid)) as data:
        arrays = {k: data[k] for k in data.files}
    key = draw(st.sampled_from(sorted(arrays)))
    if how == "drop":
        del arrays[key]
    else:
        arrays[key] = draw(st.sampled_from(_ARRAY_VALUES))
    return _npz(arrays)


@FUZZ
@given(data=st.data())
def test_fuzzed_track_file(finished_run: Path, data: st.DataObject) -> None:
    valid = (finished_run / "Zoe.track.npz").read_bytes()
    with copied(finished_run) as run:
        (run / "Zoe.track.npz").write_bytes(data.draw(track_versions(valid)))
        clean_outcome(export(run))


# ----- special files in place of each file read: links to devices, FIFOs, folders, sparse giants ----
def _dev_zero(path: Path) -> None:
    path.symlink_to("/dev/zero")


def _fifo(path: Path) -> None:
    os.mkfifo(path)  # a reader that blocked on it would hang the test: every reader must refuse it


def _folder(path: Path) -> None:
    path.mkdir()


def _sparse_5_gb(path: Path) -> None:
    with path.open("wb") as f:
        f.truncate(5 << 30)  # a hole: no disk used, but reading it whole would ask for 5 GB


def _dangling(path: Path) -> None:
    path.symlink_to(path.parent / "nowhere")


def _loop(path: Path) -> None:
    path.symlink_to(path)


SPECIALS: dict[str, Callable[[Path], None]] = {
    "/dev/zero": _dev_zero, "fifo": _fifo, "folder": _folder, "sparse 5 GB": _sparse_5_gb,
    "dangling link": _dangling, "link loop": _loop,
}


def _without_tracks(run: Path) -> None:
    for track in run.glob("*.track.npz"):
        track.unlink()


def _live(run: Path) -> None:
    (run / "story.json").unlink()
    _without_tracks(run)


RUN_FOLDER_FILES: list[tuple[str, Callable[[Path], None], Callable[[Path], Result]]] = [
    ("session.snapshot", lambda run: None, resume),
    ("run.json", lambda run: None, resume),
    ("run.json", lambda run: None, replay),
    ("trace.jsonl", lambda run: None, replay),
    ("trace.jsonl", lambda run: None, resume),
    ("story.json", lambda run: None, export),
    ("story.jsonl", _live, export),
    ("motion/Zoe.chunks", _without_tracks, export),
    ("motion/Zoe.chunks", lambda run: None, resume),
    ("Zoe.track.npz", lambda run: None, export),
]


@FUZZ
@given(kind=st.sampled_from(RUN_FOLDER_FILES), special=st.sampled_from(sorted(SPECIALS)))
def test_special_files_in_a_run_folder(finished_run: Path, kind: tuple[str, Callable[[Path], None],
                                       Callable[[Path], Result]], special: str) -> None:
    name, prepare, command = kind
    with copied(finished_run) as run:
        prepare(run)
        (run / name).unlink(missing_ok=True)
        SPECIALS[special](run / name)
        clean_outcome(command(run))


# ----- the files a user hands over: special files, and text that must not reach the terminal raw ----
def _scene_bytes() -> bytes:
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.sim.scene.files import save_scene_json

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        save_scene_json(load_bundled_scene("home"), path)
        doc = json.loads(path.read_text(encoding="utf-8"))
    doc["objects"] = doc["objects"][:4]
    return json.dumps(doc).encode()


USER_FILES: dict[str, bytes] = {
    "scene": _scene_bytes(),
    "config": (b'[llm]\nmodel = "openai/gpt-4o-mini"\ntemperature = 0.0\ntimeout_s = 30.0\n'
               b"[llm.retry]\nmax_attempts = 2\nbackoff_base_s = 0.5\nseed = 3\n"),
    "script": b"00:05 Ava sits down\n# a comment\n01:10 Ben makes coffee\n",
    "case": sorted((ROOT / "benchmark" / "cases" / "ours").rglob("testcase_*.json"))[0].read_bytes(),
}


def _user_file_command(kind: str, folder: Path) -> tuple[Path, list[str]]:
    """Where the ``kind`` file goes under ``folder``, and the command that reads it."""
    if kind == "scene":
        return folder / "scene.json", ["scene", "inspect", str(folder / "scene.json")]
    if kind == "config":
        return folder / "storyteller.toml", ["model", "info", "--config", str(folder / "storyteller.toml")]
    if kind == "script":
        return folder / "script.txt", ["run", "home", "--instructions", str(folder / "script.txt"),
                                       "--out", str(folder / "out"), "--no-live", "--no-interactive"]
    (folder / "cases" / "0_OA").mkdir(parents=True)
    return folder / "cases" / "0_OA" / "testcase_7.json", [
        "bench", "run", "--cases", str(folder / "cases"), "--out", str(folder / "sweep"), "--method", "ours",
        "--model", "local/x"]


def _starts_a_story(kind: str, path: Path) -> bool:
    """Whether the file reads (a script or a case that reads would start a story with a model)."""
    if kind == "script":
        from storyteller.orchestrator.session.instruction_script import (
            InstructionScriptError,
            read_instruction_script,
        )

        try:
            read_instruction_script(path)
        except InstructionScriptError:
            return False
        return True
    if kind == "case":
        from storyteller.benchmark.reference_cases import BenchmarkCaseError, case_files, load_case

        try:
            [load_case(p) for p in case_files(path.parent.parent)]
        except BenchmarkCaseError:
            return False
        return True
    return False


@FUZZ
@given(kind=st.sampled_from(sorted(USER_FILES)), data=st.data())
def test_user_files_with_hostile_text_or_special_files(kind: str, data: st.DataObject) -> None:
    special = data.draw(st.none() | st.sampled_from(sorted(SPECIALS)))
    with tempfile.TemporaryDirectory() as tmp:
        path, args = _user_file_command(kind, Path(tmp))
        if special is None:
            path.write_bytes(data.draw(hostile_bytes(USER_FILES[kind])))
        else:
            SPECIALS[special](path)
        if _starts_a_story(kind, path):
            return
        clean_outcome(invoke(*args))


# ----- memory: heavy cases in a subprocess under an address-space limit -----------------------------
LIMIT_BYTES = 1 << 30
"""Address space of the subprocess (the export of the finished run fits in well under this)."""
_UNDER_LIMIT = (
    "import resource, sys\n"
    f"resource.setrlimit(resource.RLIMIT_AS, ({LIMIT_BYTES}, {LIMIT_BYTES}))\n"
    "sys.argv = ['storyteller', *sys.argv[1:]]\n"
    "from storyteller.orchestrator.cli.app import main\n"
    "main()\n"
)


def _under_limit(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", _UNDER_LIMIT, *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=300, check=False)


@pytest.mark.slow
def test_a_track_array_claiming_2_gb_is_refused_within_1_gib(finished_run: Path, tmp_path: Path) -> None:
    """An .npz of a few KB whose rotations' .npy header claims 2 GB (numpy would allocate the
    whole array before reading a byte of it)."""
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    with np.load(run / "Zoe.track.npz") as data:
        arrays = {k: data[k] for k in data.files}
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for key, value in arrays.items():
            with zf.open(f"{key}.npy", "w") as f:
                if key == "local_rotations":
                    np.lib.format.write_array_header_2_0(f, {"descr": "<f8", "fortran_order": False,
                                                             "shape": ((2 << 30) // (22 * 9 * 8), 22, 3, 3)})
                    f.write(bytes(1024))
                else:
                    np.lib.format.write_array(f, value, allow_pickle=False)
    (run / "Zoe.track.npz").write_bytes(buffer.getvalue())
    done = _under_limit("view", str(run), "--export", str(tmp_path / "story.html"))
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "MemoryError" not in done.stderr, done.stderr[-2000:]
    (line,) = [s for s in done.stderr.splitlines() if s.strip()]
    assert line.startswith("error: ") and "Zoe.track.npz" in line and "claims more bytes" in line, line


def test_a_track_file_whose_zip_declares_more_than_the_limit_is_refused_before_inflating(tmp_path: Path) -> None:
    from storyteller.sim.world.character_track import MAX_TRACK_ARRAY_BYTES, CharacterTrack, CharacterTrackError

    path = tmp_path / "Zoe.track.npz"
    with zipfile.ZipFile(path, "w") as zf:  # an entry that says it unpacks past the limit
        info = zipfile.ZipInfo("local_rotations.npy")
        zf.writestr(info, b"x")
    data = bytearray(path.read_bytes())
    at = data.rfind(b"PK\x01\x02")  # the central directory's uncompressed size of the entry
    data[at + 24: at + 28] = struct.pack("<I", MAX_TRACK_ARRAY_BYTES + 1)
    path.write_bytes(bytes(data))
    with pytest.raises(CharacterTrackError, match="unpack to"):
        CharacterTrack.load(path)


@pytest.mark.slow
def test_a_chunk_record_claiming_2_gb_of_a_sparse_file_is_refused_within_1_gib(finished_run: Path,
                                                                               tmp_path: Path) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _without_tracks(run)
    path = run / "motion" / "Zoe.chunks"
    fields, _ = _records(path.read_bytes())[0]
    size = 2 << 30
    with path.open("wb") as f:  # one record: its header, then a 2 GB hole (the CRC is never reached)
        f.write(_CHUNK_HEADER.pack(*fields[:6], size, 0))
        f.truncate(_CHUNK_HEADER.size + size)
    done = _under_limit("view", str(run), "--export", str(tmp_path / "story.html"))
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "MemoryError" not in done.stderr, done.stderr[-2000:]
    (line,) = [s for s in done.stderr.splitlines() if s.strip()]
    assert line.startswith("error: ") and "Zoe.chunks" in line, line


# ----- what the fuzzing found, kept as plain cases -----------------------------------------------
@pytest.mark.parametrize(
    ("key", "value", "needle"),
    [
        ("fps", np.array([30.0, 30.0]), "field 'fps': expected one value"),
        ("action_labels", np.array("walk"), "field 'action_labels': expected one text per frame"),
        ("betas", np.zeros(10, dtype=np.complex128), "field 'betas': expected real numbers"),
        ("name", np.array(3), "field 'name': expected text"),
        ("name", np.array("\ud800\u202e\x1b[31m"), None),  # shown escaped: exit 0
    ],
    ids=["fps-array", "labels-scalar", "complex", "numeric-name", "surrogate-name"],
)
def test_track_files_the_fuzzing_found(finished_run: Path, tmp_path: Path, key: str, value: np.ndarray,
                                       needle: str | None) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    with np.load(run / "Zoe.track.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays[key] = value
    (run / "Zoe.track.npz").write_bytes(_npz(arrays))
    result = export(run)
    clean_outcome(result)
    if needle is None:
        from storyteller.orchestrator.viewer.run_folder import load_run

        assert result.exit_code == 0
        assert "\\ud800\\u202e\\x1b[31m" in [t.name for t in load_run(run).tracks]
    else:
        assert result.exit_code == 2 and needle in result.stderr and result.stderr.count("Zoe.track.npz") == 1


@pytest.mark.parametrize(
    ("table", "needle"),
    [(b"[" * 5_000 + b"]" * 5_000, "nested more than"), (b'{"a": 1}', "a JSON list of strings"),
     (b"[1, 2]", "a JSON list of strings"), (b'[""]', "outside its name table")],
    ids=["deep", "object", "numbers", "index-out-of-range"],
)
def test_chunk_name_tables_the_fuzzing_found(finished_run: Path, tmp_path: Path, table: bytes, needle: str) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _without_tracks(run)
    path = run / "motion" / "Zoe.chunks"
    records = _records(path.read_bytes())
    fields, payload = records[0]
    first = _record(fields, payload[: len(payload) - fields[5]] + table, names_len=len(table))
    path.write_bytes(first + b"".join(_record(f, p) for f, p in records[1:]))
    result = export(run)
    clean_outcome(result)
    assert result.exit_code == 2 and needle in result.stderr, result.stderr


# ----- a snapshot of values no run could have made: one line at resume, not a run stopping later ----
class _AnyShared(dict[str, object]):
    """The world's shared objects as stand-ins, one per name a checkpoint refers to."""

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str)

    def __missing__(self, key: str) -> object:
        self[key] = stand_in = type("Shared", (), {})()
        return stand_in


def _rewritten_snapshot(path: Path, change: Callable[[Any], None]) -> None:
    """``path``'s checkpoint decoded (shared objects as stand-ins), changed, written back with its
    checksum made to match (so the checksum is not what stops it)."""
    from storyteller.orchestrator.session import snapshot_file

    shared = _AnyShared()
    checkpoint = snapshot_file._Unpickler(io.BytesIO(_payload_without_frames(path.read_bytes())), shared,
                                          snapshot_file._resolve_classes()).load()
    change(checkpoint)
    buffer = io.BytesIO()
    snapshot_file._Pickler(buffer, {id(obj): name for name, obj in shared.items()}).dump(checkpoint)
    path.write_bytes(_with_header(buffer.getvalue()))


def _negative_frame(cp: Any) -> None:
    cp.world.frame = -1


def _unknown_event(cp: Any) -> None:
    next(iter(cp.world.characters.values())).event_id = "event-0999"


def _nan_position(cp: Any) -> None:
    next(iter(cp.world.characters.values())).xy = np.array([float("nan"), 0.0])


def _unknown_seat(cp: Any) -> None:
    from storyteller.sim.world.events import Assignment

    name = next(iter(cp.world.characters))
    cp.world.characters[name].assignment = Assignment(character=name, action="sit_idle", target_xy=(1.0, 1.0),
                                                      facing_xy=(1.0, 0.0), seat="throne_9")


@pytest.mark.parametrize(
    ("change", "needle"),
    [(_negative_frame, "world is at frame -1"), (_unknown_event, "event 'event-0999', which its world does not hold"),
     (_nan_position, "xy is (nan, 0), not a point of the scene"), (_unknown_seat, "seat is 'throne_9'")],
    ids=["negative-frame", "event-nowhere", "nan-position", "unknown-seat"],
)
def test_a_snapshot_no_run_could_have_made_is_one_line_at_resume(finished_run: Path, tmp_path: Path,
                                                                 change: Callable[[Any], None], needle: str) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _rewritten_snapshot(run / "session.snapshot", change)
    result = resume(run)
    clean_outcome(result)
    assert result.exit_code == 2 and "session.snapshot" in result.stderr and needle in result.stderr, result.stderr


# ----- motion/*.chunks past the size caps: one line, exit 2 in view --export ------------------------
def test_a_chunk_file_past_its_cap_is_refused_from_its_size(finished_run: Path, tmp_path: Path) -> None:
    from storyteller.sim.world.track_chunks import MAX_CHUNK_FILE_BYTES

    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _without_tracks(run)
    path = run / "motion" / "Zoe.chunks"
    with path.open("r+b") as f:  # its whole records, then a hole up to one byte past the cap
        f.truncate(MAX_CHUNK_FILE_BYTES + 1)
    result = export(run)
    clean_outcome(result)
    assert result.exit_code == 2 and f"{MAX_CHUNK_FILE_BYTES + 1} bytes, more than the {MAX_CHUNK_FILE_BYTES}" \
        in result.stderr, result.stderr


def test_a_chunk_file_of_valid_records_past_a_lowered_cap_is_refused(finished_run: Path, tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Every record whole and valid: the size alone refuses it (the cap lowered below this file)."""
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _without_tracks(run)
    size = (run / "motion" / "Zoe.chunks").stat().st_size
    monkeypatch.setattr("storyteller.sim.world.track_chunks.MAX_CHUNK_FILE_BYTES", size - 1)
    result = export(run)
    clean_outcome(result)
    assert result.exit_code == 2 and "Zoe.chunks" in result.stderr and "a chunk file may hold" in result.stderr


def test_a_run_folders_chunk_files_past_their_total_cap_are_refused(finished_run: Path, tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    _without_tracks(run)
    total = sum(p.stat().st_size for p in (run / "motion").glob("*.chunks"))
    monkeypatch.setattr("storyteller.sim.world.track_chunks.MAX_RUN_CHUNK_BYTES", total - 1)
    result = export(run)
    clean_outcome(result)
    assert result.exit_code == 2
    assert f"{run / 'motion'}: the chunk files hold more than the {total - 1} bytes" in result.stderr, result.stderr
    monkeypatch.setattr("storyteller.sim.world.track_chunks.MAX_RUN_CHUNK_BYTES", total)
    assert export(run).exit_code == 0  # at the cap: read
