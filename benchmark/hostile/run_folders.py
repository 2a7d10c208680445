"""Attacks on a run folder's own files: ``session.snapshot``, ``run.json`` and the folder's
layout (planted links and hard links, a linked ``motion/``, ``.tmp`` links, the viewer's inbox).
"""

from __future__ import annotations

import gzip
import json
import os
import pickle
import re
import shutil

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Reduce,
    Spec,
    deep_json,
    refused_for,
    registrar,
    replay,
    resume,
    snapshot_with,
    victim_intact,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("snapshot", "pickle calls os.system, checksum fixed")
def _snap_system(box: Box) -> Spec:
    run = box.copy_run()
    (run / "session.snapshot").write_bytes(snapshot_with(pickle.dumps(Reduce(f"touch {box.canary}"), protocol=4)))
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
    """The scene a link named like a scene file (``/dev/zero`` itself was refused for its name,
    before it was opened)."""
    run = box.copy_run()
    zero = str(box.link(box.root / "zero.json", "/dev/zero"))
    box.edit_json(run / "run.json", lambda v: {**v, "scene_name": zero, "arguments": {**v["arguments"], "scene": zero}})
    spec = replay(box)
    spec.check_output = refused_for("zero.json", "not a regular file")
    return spec


@attack("run.json", "thread id and instruction with escapes, bidi, lone surrogate")
def _runjson_text(box: Box) -> Spec:
    path = box.copy_run() / "run.json"
    value = json.loads(path.read_text(encoding="utf-8"))
    value["thread_id"] = value["thread_id"] + BIDI
    value["arguments"]["instruction"] = "\ud800 go" + BIDI
    path.write_text(json.dumps(value), encoding="utf-8")
    return replay(box, expect="either")


@attack("run.json", "a script of 100,000 instruction lines (replay)")
def _runjson_script(box: Box) -> Spec:
    run = box.copy_run()
    script = [{"time_s": i * 0.001, "text": f"line {i}" + BIDI} for i in range(100_000)]
    box.edit_json(run / "run.json", lambda v: {**v, "arguments": {**v["arguments"], "instructions": script}})
    return replay(box, "either")


@attack("run.json", "run -d 1e308 and 24 characters for 2,000 s (a run.json resume refuses)")
def _run_duration(box: Box) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "-n", "24", "-d", "2000", "--out", str(out), "--no-interactive", "--no-live"],
                "run", "bad", writable=(out,))


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


@attack("run folder", "viewer_instructions.jsonl: a 30 MB line, bidi text, deep nesting")
def _inbox(box: Box) -> Spec:
    run = box.copy_run()
    lines = [json.dumps({"text": "sit" + BIDI, "time_unix": 0}), deep_json(50_000), "x" * 30_000_000]
    (run / "viewer_instructions.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (run / "viewer_controls.jsonl").write_text('{"kind": "speed", "speed": 1e999}\n' + deep_json(50_000) + "\n",
                                               encoding="utf-8")
    return resume(box, "either")


@attack("run folder", "replay --out into a folder with planted links and a hard-linked trace")
def _replay_out_links(box: Box) -> Spec:
    box.copy_run()
    out = box.root / "replayed"
    out.mkdir()
    box.link(out / "story.md", box.victim())
    os.link(box.victim(), out / "trace.jsonl")
    spec = replay(box)
    return Spec(**{**spec.__dict__, "check": victim_intact(box)})


@attack("run.json", "UTF-16 with BOM (replay)")
def _runjson_utf16(box: Box) -> Spec:
    path = box.copy_run() / "run.json"
    path.write_bytes(path.read_text(encoding="utf-8").encode("utf-16"))
    return replay(box)


@attack("run.json", "names Zoe and zoe, one file name on a case-blind disk (replay)")
def _runjson_case(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "arguments": {**v["arguments"], "names": ["Zoe", "zoe"]}})
    return replay(box)


@attack("run folder", "run --names Zoe,zoe (two characters, one chunk file name)")
def _run_names_case(box: Box) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "--names", "Zoe,zoe", "--out", str(out), "--no-interactive", "--no-live"], "run", "bad",
                writable=(out,))


@attack("run folder", "trace.jsonl and story.jsonl hard-linked outside, a parent folder a symlink")
def _hardlink_appended(box: Box) -> Spec:
    run = box.copy_run()
    for name in ("trace.jsonl", "story.jsonl"):
        shutil.copy(run / name, box.outside / name)
        (run / name).unlink()
        os.link(box.outside / name, run / name)
    via = box.root / "via"
    via.symlink_to(box.root)
    return Spec(["resume", str(via / "run"), "--no-interactive", "--no-live"], "resume", "bad")
