"""Attacks on what a run wrote and ``replay``, ``resume`` and ``view --export`` read back: the
trace, ``story.json`` and ``story.jsonl``, the ``.track.npz`` tracks and the ``motion/`` chunks.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import pickle
import re
import shutil
import struct
import zipfile
from pathlib import Path
from typing import Any

from storyteller.benchmark.hostile.harness import (
    BIDI,
    MARKER,
    Attack,
    Box,
    Reduce,
    Spec,
    deep_json,
    export,
    html_clean,
    refused_for,
    registrar,
    replay,
    resume,
    shown,
    zip_bomb_npz,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


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


@attack("trace", "an instruction record with bidi, escapes and 1 MB of text (replay prints it)")
def _trace_instruction(box: Box) -> Spec:
    path, records = _trace_records(box)
    records.insert(1, {"run_id": records[0]["run_id"], "seq": 100, "time_unix": 0.0, "kind": "instruction",
                       "text": "sit down" + BIDI + "x" * 1_000_000, "source": "script" + BIDI,
                       "sim_frame": 1})
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    # (with a lone surrogate in the text the record was refused as JSON, before anything printed it)
    spec = replay(box, "either")
    spec.check_output = shown("instruction (replay): sit down\\u202e\\u2066\\x1b[31m\\x07\\u200b\\u2028xxx")
    return spec


@attack("trace", "500,000 records (75 MB) of run lines")
def _trace_many(box: Box) -> Spec:
    path, records = _trace_records(box)
    line = (json.dumps(records[0]) + "\n").encode()
    with open(path, "ab") as f:
        f.write(line * 500_000)
    return replay(box, "either")


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
    """An event line valid but for its 40 MB text (a line of no event was refused at its missing
    ``event``, after it was read and before anything the text costs)."""
    run = box.copy_run()
    (run / "story.json").unlink()  # a live run: the viewer reads the stream
    lines = (run / "story.jsonl").read_text(encoding="utf-8").splitlines()
    event = json.loads(next(line for line in lines if '"kind": "event"' in line))
    event["event"]["text"] = "b" * 40_000_000
    with open(run / "story.jsonl", "a", encoding="utf-8") as f:
        f.write(json.dumps(event) + "\n")
    spec = export(box, "either")
    spec.check_output = refused_for("story.jsonl", "field 'event.text'")  # a refusal must be for the text
    return spec


@attack("story.jsonl", "1,000,000 event lines (export)")
def _stream_many(box: Box) -> Spec:
    run = box.copy_run()
    (run / "story.json").unlink()
    lines = (run / "story.jsonl").read_bytes().splitlines(keepends=True)
    with open(run / "story.jsonl", "ab") as f:
        f.write(lines[-1] * 1_000_000)
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
        f.write(pickle.dumps([Reduce(f"touch {box.canary}")], protocol=2))
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


@attack("chunks", "motion/Zoe.chunks hard-linked to a file outside (resume)")
def _chunk_hardlink(box: Box) -> Spec:
    run = box.copy_run()
    shutil.copy(run / "motion" / "Zoe.chunks", box.outside / "Zoe.chunks")
    (run / "motion" / "Zoe.chunks").unlink()
    os.link(box.outside / "Zoe.chunks", run / "motion" / "Zoe.chunks")
    return resume(box)


@attack("trace", "a record with 1.2 million unknown keys (14 MB line)")
def _trace_keys(box: Box) -> Spec:
    path, records = _trace_records(box)
    records[1].update({f"k{i}": 0 for i in range(1_200_000)})
    path.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in records), encoding="utf-8")
    return replay(box)


@attack("trace", "CRLF line ends and a UTF-8 BOM")
def _trace_crlf(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes().replace(b"\n", b"\r\n"))
    return replay(box, "either")


@attack("story.json", "a step with 1.2 million unknown keys (export)")
def _story_keys(box: Box) -> Spec:
    path = box.copy_run() / "story.json"
    value = json.loads(path.read_text(encoding="utf-8"))
    value["steps"][0].update({f"k{i}": 0 for i in range(1_200_000)})
    path.write_text(json.dumps(value, separators=(",", ":")), encoding="utf-8")
    return export(box)


@attack("story.json", "UTF-16 with BOM, then CRLF and -0.0 times (export)")
def _story_encodings(box: Box) -> Spec:
    path = box.copy_run() / "story.json"
    text = re.sub(r'("time_s": )[0-9.]+', r"\1-0.0", path.read_text(encoding="utf-8"))
    path.write_bytes(text.replace("\n", "\r\n").encode("utf-16"))
    return export(box, "either")


@attack("story.jsonl", "a line with 1.2 million unknown keys (export of a live run)")
def _stream_keys(box: Box) -> Spec:
    run = box.copy_run()
    (run / "story.json").unlink()
    with open(run / "story.jsonl", "ab") as f:
        f.write(b'{"kind": "event", ' + b",".join(b'"k%d":0' % i for i in range(1_200_000)) + b"}\n")
    return export(box, "either")


@attack("story.json", "120,000 steps and 60,000 events (50 MB, export)")
def _story_many(box: Box) -> Spec:
    path = box.copy_run() / "story.json"
    value = json.loads(path.read_text(encoding="utf-8"))
    value["steps"] = value["steps"] * (120_000 // len(value["steps"]))
    value["events"] = value["events"] * (60_000 // len(value["events"]))
    path.write_text(json.dumps(value, separators=(",", ":")), encoding="utf-8")
    return export(box)


@attack("story.json", "9,000 overlapping events of 2,000-character texts (export)")
def _story_texts(box: Box) -> Spec:
    path = box.copy_run() / "story.json"
    value = json.loads(path.read_text(encoding="utf-8"))
    value["events"] = [{**value["events"][0], "text": "x" * 2000 + BIDI, "finished_frame": None}] * 9000
    path.write_text(json.dumps(value, separators=(",", ":")), encoding="utf-8")
    return export(box, "either", html_clean(box))
