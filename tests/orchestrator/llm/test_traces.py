"""Trace files: record round trip, torn tails, corruption, reopen, and a writer killed mid-write."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import (
    AppliedRecord,
    AttemptRecord,
    ParsedRecord,
    RunRecord,
    TraceCorruptError,
    read_trace,
)
from storyteller.sim.bounded_files import MAX_OBJECT_KEYS
from tests.support.trace_records import attempt

REPO = Path(__file__).resolve().parents[3]


def test_round_trip_all_kinds(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TraceWriter(path, run_id="run1", fsync="close", meta={"scene": "Office"}) as w:
        rec = attempt(w)
        w.record_parsed(rec.seq, {"event": {"characters": ["Ann"]}})
        w.record_applied([rec.seq], sim_frame=95, step=0, requested_frame=10)
    contents = read_trace(path)
    assert contents.torn_tail is None
    kinds = [type(r) for r in contents.records]
    assert kinds == [RunRecord, AttemptRecord, ParsedRecord, AppliedRecord]
    assert [r.seq for r in contents.records] == [0, 1, 2, 3]
    assert all(r.run_id == "run1" for r in contents.records)
    back = contents.records[1]
    assert back == rec and back.request.sim_frame == 10
    applied = contents.records[3]
    assert isinstance(applied, AppliedRecord) and applied.ref_seqs == (rec.seq,) and applied.sim_frame == 95
    assert applied.step == 0 and applied.requested_frame == 10
    assert contents.applied_frame_by_seq() == {rec.seq: 95}
    assert path.read_bytes().count(b"\n") == 4


def test_torn_last_line_is_reported_not_fatal(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TraceWriter(path) as w:
        attempt(w)
        attempt(w)
    full = path.read_bytes()
    path.write_bytes(full[: len(full) - 40])  # cut the last record in the middle
    contents = read_trace(path)  # reported to the caller (resume cuts it off, replay refuses it: one line each)
    assert len(contents.records) == 2  # run + first attempt
    assert contents.torn_tail is not None and contents.torn_tail.line_no == 3


def test_corrupt_middle_line_raises_with_line_number(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TraceWriter(path) as w:
        attempt(w)
        attempt(w)
    lines = path.read_bytes().split(b"\n")
    lines[1] = lines[1][:30] + b"#garbage#" + lines[1][30:]
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(TraceCorruptError, match=r"line 2") as info:
        read_trace(path)
    assert info.value.line_no == 2 and str(path) in str(info.value)


def test_invalid_record_shape_is_corruption(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    path.write_text('{"kind": "attempt", "run_id": "r", "seq": 0}\n', encoding="utf-8")
    with pytest.raises(TraceCorruptError, match="line 1"):
        read_trace(path)
    path.write_text('{"kind": "mystery", "run_id": "r", "seq": 0, "time_unix": 0}\n', encoding="utf-8")
    with pytest.raises(TraceCorruptError, match="line 1"):
        read_trace(path)


def test_a_record_of_too_many_keys_is_refused_before_validation(tmp_path: Path) -> None:
    """Found by the hostile corpus: a record with 1.2 million unknown keys took 1.7 GB (one
    validation error per key) before the one-line refusal."""
    path = tmp_path / "t.jsonl"
    extra = ",".join(f'"k{i}": 0' for i in range(MAX_OBJECT_KEYS + 1))
    path.write_text('{"kind": "run", "run_id": "r", "seq": 0, "time_unix": 0, ' + extra + "}\n", encoding="utf-8")
    with pytest.raises(TraceCorruptError, match=r"more than .* keys"):
        read_trace(path)


def test_reopen_continues_seq_and_cuts_torn_tail(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TraceWriter(path, run_id="a") as w:
        attempt(w)
    with path.open("ab") as f:
        f.write(b'{"kind": "attempt", "run_id": "a", "se')  # a writer died here
    with TraceWriter(path, run_id="b") as w:
        rec = attempt(w)
    contents = read_trace(path)
    assert contents.torn_tail is None
    assert [r.seq for r in contents.records] == [0, 1, 2, 3] and rec.seq == 3
    assert [r.run_id for r in contents.records] == ["a", "a", "b", "b"]


def test_closed_writer_refuses(tmp_path: Path) -> None:
    w = TraceWriter(tmp_path / "t.jsonl", fsync="never")
    w.close()
    with pytest.raises(ValueError, match="closed"):
        attempt(w)


_WRITER = r"""
import sys, time
sys.path.insert(0, sys.argv[2])
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.orchestrator.llm.traces import AttemptRecord
from storyteller.orchestrator.llm.trace_writer import TraceWriter
w = TraceWriter(sys.argv[1], run_id="victim", fsync=sys.argv[3])
big = "x" * 200_000
i = 0
while True:
    req = LLMRequest(node="event_parser", messages=(ChatMessage(role="user", content=f"{i} {big}"),))
    seq = w.next_seq()
    w.write(AttemptRecord(run_id=w.run_id, seq=seq, time_unix=time.time(), call=seq, node="event_parser",
                          attempt=1, model="m", params={}, request=req, request_hash=req.content_hash(),
                          response_text=big, latency_s=0.0, final=True))
    i += 1
"""


@pytest.mark.parametrize("fsync", ["never", "always"])
def test_writer_killed_mid_write_keeps_every_complete_record(tmp_path: Path, fsync: str) -> None:
    path = tmp_path / "victim.jsonl"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path), str(REPO), fsync])
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # wait until several records are on disk
            if path.exists() and path.stat().st_size > 3_000_000:
                break
            time.sleep(0.02)
        else:
            pytest.fail("writer produced too little output")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    data = path.read_bytes()
    complete_lines = data.count(b"\n")
    contents = read_trace(path)  # must not raise
    assert len(contents.records) == complete_lines >= 5
    attempts = [r for r in contents.records if isinstance(r, AttemptRecord)]
    assert [int(r.request.messages[0].content.split()[0]) for r in attempts] == list(range(len(attempts)))
    assert contents.torn_tail is None or contents.torn_tail.byte_offset == data.rfind(b"\n") + 1


def test_legacy_applied_record_with_one_ref_seq_still_reads(tmp_path: Path) -> None:
    path = tmp_path / "old.jsonl"
    path.write_text(
        '{"run_id":"r","seq":0,"time_unix":1.0,"kind":"applied","ref_seq":7,"sim_frame":30}\n', encoding="utf-8"
    )
    (rec,) = read_trace(path).records
    assert isinstance(rec, AppliedRecord) and rec.ref_seqs == (7,) and rec.step is None and rec.sim_frame == 30


def test_parsed_record_holds_output_or_typed_error(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TraceWriter(path, fsync="never") as w:
        rec = attempt(w)
        w.record_parsed(rec.seq, None, node="event_parser", error_type="NoCodeError", error_message="no code")
        w.record_parsed(rec.seq, {"plans": []}, node="event_parser")
    contents = read_trace(path)
    first, second = contents.parsed_by_seq()[rec.seq]
    assert not first.ok and first.error_type == "NoCodeError" and first.parsed_output is None
    assert second.ok and second.parsed_output == {"plans": []}


def test_a_trace_of_more_records_than_the_cap_is_refused_before_parsing(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """500,000 tiny records (75 MB, under the byte cap) took 1.6 GB to validate
    (benchmark/hostile_inputs.py): the record count is checked first."""
    import storyteller.orchestrator.llm.traces as traces

    path = tmp_path / "t.jsonl"
    with TraceWriter(path) as w:
        attempt(w)
    line = path.read_bytes().splitlines(keepends=True)[0]
    monkeypatch.setattr(traces, "MAX_TRACE_RECORDS", 10)
    path.write_bytes(line * 10)
    assert len(read_trace(path).records) == 10
    path.write_bytes(line * 11 + b"{not json")  # refused from the count: the bad line is never parsed
    with pytest.raises(TraceCorruptError, match="11 records, more than the 10"):
        read_trace(path)
