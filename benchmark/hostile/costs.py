"""Attacks whose files parse and are small but ask for work or hold values no run writes (a
second corpus, written from outside the first): a sweep of a billion repeats or a million case
ids, a character track of 150,000 frames deflated to a few hundred kilobytes, a track at 1e-300
fps with NaN positions, PLY headers of a hundred thousand elements, OBJ vertices at 1e308 and NaN.
"""

from __future__ import annotations

import io
import json
import zipfile
from typing import Any

import numpy as np

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Spec,
    export,
    inspect,
    refused_for,
    registrar,
    replay,
    score,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("bench", "sweep.json: repeats 10**9")
def _bench_repeats(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.edit_json(sweep / "sweep.json", lambda v: {**v, "repeats": 10**9})
    return score(box, sweep)


@attack("bench", "sweep.json: 1,000,000 case ids and 100,000 levels")
def _bench_ids(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.edit_json(sweep / "sweep.json", lambda v: {**v, "case_ids": list(range(1_000_000)),
                                                   "levels": list(range(100_000))})
    return score(box, sweep)


def _track(box: Box, **arrays: np.ndarray) -> Spec:
    run = box.copy_run()
    path = run / "Zoe.track.npz"
    with np.load(path) as npz:
        values = {k: npz[k] for k in npz.files}
    values.update(arrays)
    buf = io.BytesIO()
    np.savez_compressed(buf, **values)
    path.write_bytes(buf.getvalue())
    return export(box, "either")


@attack("track", "Zoe.track.npz of 150,000 frames of zeros, deflated (export)")
def _track_long(box: Box) -> Spec:
    frames = 150_000
    return _track(box, root_positions=np.zeros((frames, 3)), local_rotations=np.zeros((frames, 22, 3, 3)),
                  action_labels=np.array(["idle"] * frames))


@attack("track", "Zoe.track.npz at fps 1e-300, NaN positions, a name with bidi (export)")
def _track_values(box: Box) -> Spec:
    spec = _track(box, fps=np.array(1e-300), name=np.array("Zoe" + BIDI),
                  root_positions=np.full((90, 3), np.nan))
    return Spec(**{**spec.__dict__, "expect": "bad"})


@attack("mesh", "ASCII .ply header of 100,000 empty elements of 10 properties")
def _ply_header(box: Box) -> Spec:
    head = ["ply", "format ascii 1.0"]
    for i in range(100_000):
        head += [f"element e{i} 0"] + [f"property float p{j}" for j in range(10)]
    head += ["element vertex 3", "property float x", "property float y", "property float z", "end_header",
             "0 0 0", "1 0 0", "0 1 0"]
    # empty elements are valid PLY: a refusal must be for them
    return inspect(box.file("header.ply", "\n".join(head) + "\n"), "either", refused_for("header.ply", "element"))


@attack("mesh", ".obj vertices at 1e308 and -1e308")
def _obj_values(box: Box) -> Spec:
    text = "o chair_1\nv 1e308 0 0\nv -1e308 1 0\nv 0 0 1\nv 0 0 0\nf 1 2 3\nf 2 3 4\n"
    return inspect(box.file("values.obj", text), "bad", refused_for("object 'chair_1', field 'size"))


@attack("mesh", ".obj vertex at nan")
def _obj_nan(box: Box) -> Spec:
    text = "o chair_1\nv 0 0 0\nv 1 1 0\nv nan 0 1\nv 0 0 1\nf 1 2 3\nf 2 3 4\n"
    return inspect(box.file("nan.obj", text), "either", refused_for("nan.obj", "non-finite"))


@attack("track", "a .track.npz whose zip holds 100,000 empty members (export)")
def _track_members(box: Box) -> Spec:
    run = box.copy_run()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for i in range(100_000):
            z.writestr(f"m{i}.npy", b"")
    (run / "Zoe.track.npz").write_bytes(buf.getvalue())
    return export(box)


@attack("track", "Zoe.track.npz at fps 1e-300 (export)")
def _track_fps(box: Box) -> Spec:
    return Spec(**{**_track(box, fps=np.array(1e-300)).__dict__, "expect": "bad"})


@attack("story.json", "an event finished 50 frames before it was applied (export)")
def _story_backwards(box: Box) -> Spec:
    def change(v: Any) -> Any:
        for e in v["events"]:
            e["applied_frame"], e["finished_frame"] = 80, 30
        return v

    box.edit_json(box.copy_run() / "story.json", change)
    return export(box)


def _facing(box: Box, facing: list[float]) -> Spec:
    """A valid scene of two seats but for the second one's ``facing``: one a bad facing cannot be."""
    objects = [{"name": f"chair_{i + 1}", "label": "chair", "idx": i + 1, "center": [1.0 + 2 * i, 1.0, 0.25],
                "size": [0.5, 0.5, 0.5], "facing": [0.0, 1.0] if i == 0 else facing, "has_facing": True,
                "sit_offset_horizontal": 0.0, "sit_offset_vertical": 0.4, "interactive": True} for i in range(2)]
    text = json.dumps({"format": "storyteller-scene/1", "name": "facing", "floor_z": 0.0, "bounds_min": [0, 0],
                       "bounds_max": [6, 4], "objects": objects})
    return inspect(box.file("facing.json", text), "bad", refused_for("object 'chair_2', field 'facing'"))


@attack("scene", "a seat facing [0, 0]")
def _scene_facing(box: Box) -> Spec:
    return _facing(box, [0.0, 0.0])


@attack("scene", "a seat facing [1e-320, 0] (a subnormal length)")
def _scene_facing_tiny(box: Box) -> Spec:
    return _facing(box, [1e-320, 0.0])


@attack("trace", "usage of 10**60 tokens and a latency of 1e308 s in every attempt (replay)")
def _trace_usage(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    records = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    for r in records:
        if r["kind"] == "attempt":
            r["usage"] = {"prompt_tokens": 10**60, "completion_tokens": 10**60}
            r["latency_s"] = 1e308
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    return replay(box, "either")


@attack("trace", "applied steps naming reply seqs that do not exist (replay)")
def _trace_refs(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    records = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    for r in records:
        if r["kind"] == "applied":
            r["ref_seqs"] = [10**18, -3]
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    # either: a replay matches replies by request hash and applies steps at their frames; ref_seqs
    # are provenance only (legacy traces hold references to attempts they do not include)
    return replay(box, "either")


@attack("trace", "records of a second run id interleaved with the first (replay)")
def _trace_two_runs(box: Box) -> Spec:
    path = box.copy_run() / "trace.jsonl"
    records = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    twins = [{**r, "run_id": "f" * 12, "seq": r["seq"] + 1000} for r in records]
    mixed = [r for pair in zip(records, twins, strict=True) for r in pair]
    path.write_text("".join(json.dumps(r) + "\n" for r in mixed), encoding="utf-8")
    return replay(box, "either")
