"""Attacks on the values inside files that parse (a second corpus, written from outside the
first): ``run.json`` numbers at the edge of their types, trace records whose ids repeat and
whose frames go backwards, a story whose frame rate or frame count asks for the impossible,
mesh indices out of range, glTF buffers that name the network or a data URI, scenes whose
objects share a name, TOML nested through inline tables and dotted keys, scripts at their caps
and bench sweeps whose case folder is the whole disk or a link loop.
"""

from __future__ import annotations

import base64
import json
import os
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Expect,
    Spec,
    export,
    glb_file,
    gltf_doc,
    inspect,
    refused_for,
    registrar,
    replay,
    score,
    shown,
)
from storyteller.benchmark.hostile.inputs import model_info, program_run, script_run

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


def _arguments(box: Box, **changes: Any) -> None:
    box.edit_json(box.copy_run() / "run.json", lambda v: {**v, "arguments": {**v["arguments"], **changes}})


@attack("run.json", "seed 2**70 in both places (replay)")
def _seed_big(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "seed": 2**70, "arguments": {**v["arguments"], "seed": 2**70}})
    return replay(box)


@attack("run.json", "seed -1 in both places (replay)")
def _seed_negative(box: Box) -> Spec:
    run = box.copy_run()
    box.edit_json(run / "run.json", lambda v: {**v, "seed": -1, "arguments": {**v["arguments"], "seed": -1}})
    return replay(box)


@attack("run.json", "realtime pace at speed 5e-324 (replay)")
def _speed_tiny(box: Box) -> Spec:
    _arguments(box, pace="realtime", speed=5e-324)
    return replay(box)


@attack("run.json", "duration 5e-324 and max_retries 10**18 (replay)")
def _duration_tiny(box: Box) -> Spec:
    _arguments(box, duration=5e-324, max_retries=10**18)
    return replay(box)


@attack("run.json", "scene: a relative path to a secret file outside (replay)")
def _scene_relative(box: Box) -> Spec:
    _arguments(box, scene="../outside/secret.txt")
    return replay(box)


@attack("run.json", "a script line at -0.0 s and one at 5e-324 s, texts with U+2028 (replay)")
def _script_edges(box: Box) -> Spec:
    _arguments(box, instructions=[{"time_s": -0.0, "text": "Zoe sits\u2028down"},
                                  {"time_s": 5e-324, "text": "Max\u0085waits\u200f"}])
    return replay(box, "either")


def _records(box: Box) -> tuple[Path, list[dict[str, Any]]]:
    path = box.copy_run() / "trace.jsonl"
    return path, [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]


def _write(path: Path, records: list[dict[str, Any]]) -> None:
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")


@attack("trace", "a second attempt record under the same seq and call, another reply (replay)")
def _trace_repeat(box: Box) -> Spec:
    path, records = _records(box)
    first = next(i for i, r in enumerate(records) if r["kind"] == "attempt")
    twin = {**records[first], "response_text": records[first]["response_text"].replace("Zoe", "Max")}
    records.insert(first + 1, twin)
    _write(path, records)
    return replay(box)


@attack("trace", "applied steps whose frames go backwards (replay)")
def _trace_backwards(box: Box) -> Spec:
    path, records = _records(box)
    applied = [r for r in records if r["kind"] == "applied"]
    applied[0]["requested_frame"] = applied[0]["sim_frame"] = 60
    applied[-1]["requested_frame"] = applied[-1]["sim_frame"] = 3
    _write(path, records)
    return replay(box)


@attack("trace", "a reply of a code fence around 200,000 nested brackets (replay)")
def _trace_brackets(box: Box) -> Spec:
    path, records = _records(box)
    for r in records:
        if r["kind"] == "attempt":
            r["response_text"] = "```python\ndef parse_event():\n    x = " + "[" * 200_000 + "]" * 200_000 + "\n```"
    _write(path, records)
    return replay(box, "either")


@attack("trace", "an instruction record at frame -5 (replay)")
def _trace_instruction_frames(box: Box) -> Spec:
    path, records = _records(box)
    run_id = records[0]["run_id"]
    records.insert(1, {"run_id": run_id, "seq": 90, "time_unix": 0.0, "kind": "instruction", "text": "sit",
                       "source": "script", "sim_frame": -5})
    _write(path, records)
    return replay(box)


def _story(box: Box, change: Any) -> Spec:
    box.edit_json(box.copy_run() / "story.json", change)
    return export(box)


@attack("story.json", "fps 5e-324 and frames 10**60 (export)")
def _story_fps(box: Box) -> Spec:
    return _story(box, lambda v: {**v, "fps": 5e-324, "frames": 10**60})


@attack("story.json", "steps applied at frame 10**60, 30,000 characters named with bidi (export)")
def _story_frames(box: Box) -> Spec:
    def change(v: Any) -> Any:
        for step in v["steps"]:
            step["applied_frame"] = 10**60
        v["characters"] = [f"C{i}{BIDI}" for i in range(30_000)]
        return v

    return _story(box, change)


# Each mesh and scene below is one the loader would read but for its hostile part, one to an
# attack (a second would be refused first and test nothing); each check fails on a refusal for
# another reason (``refused_for``) or when what must be accepted is not shown (``shown``).

def _obj_face(box: Box, face: str, expect: Expect, check: Callable[[str], str | None]) -> Spec:
    text = f"o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf {face}\nf 2 3 4\n"
    return inspect(box.file("idx.obj", text), expect, check)


@attack("mesh", ".obj with relative index -9,999,999")
def _obj_negative(box: Box) -> Spec:
    return _obj_face(box, "-9999999 2 3", "bad", refused_for("idx.obj", "-9999999"))


@attack("mesh", ".obj with index 0")
def _obj_zero(box: Box) -> Spec:
    return _obj_face(box, "0 1 2", "either", refused_for("idx.obj", "index"))


PLY_TRIANGLE = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                b"property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                + np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes())


@attack("mesh", "binary .ply face naming vertex 2**31-1")
def _ply_big_index(box: Box) -> Spec:
    faces = struct.pack("<Biii", 3, 0, 1, 2**31 - 1) + struct.pack("<Biii", 3, 0, 1, 2)
    return inspect(box.file("idx.ply", PLY_TRIANGLE + faces), check_output=refused_for("idx.ply", "2147483647"))


@attack("mesh", "binary .ply face naming vertex -7")
def _ply_negative_index(box: Box) -> Spec:
    faces = struct.pack("<Biii", 3, -7, 1, 2) + struct.pack("<Biii", 3, 0, 1, 2)
    return inspect(box.file("idx.ply", PLY_TRIANGLE + faces), check_output=refused_for("idx.ply", "-7"))


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()


@attack("mesh", ".glb: an index accessor past the vertices")
def _glb_index_past(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}])
    doc["buffers"][0]["byteLength"] = 48
    doc["bufferViews"].append({"buffer": 0, "byteOffset": 36, "byteLength": 12})
    doc["accessors"].append({"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"})
    doc["meshes"][0]["primitives"][0]["indices"] = 1
    indices = struct.pack("<III", 0, 1, 4_000_000_000)
    return inspect(box.file("ranges.glb", glb_file(doc, TRIANGLE + indices)), "either",
                   check_output=refused_for("ranges.glb", "index"))


@attack("mesh", ".glb: a buffer view 1 TB past its buffer")
def _glb_view_past(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}])
    doc["bufferViews"][0]["byteOffset"] = 1 << 40
    return inspect(box.file("ranges.glb", glb_file(doc, TRIANGLE)),
                   check_output=refused_for("ranges.glb", "cannot read mesh file"))


@attack("mesh", ".glb: a buffer view of stride 1")
def _glb_stride(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}])
    doc["bufferViews"][0]["byteStride"] = 1
    return inspect(box.file("ranges.glb", glb_file(doc, TRIANGLE)), "either",
                   check_output=refused_for("ranges.glb", "stride"))


def _gltf_uri(box: Box, uri: str, expect: Expect, check: Callable[[str], str | None]) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}], uri=uri)
    doc["buffers"][0]["byteLength"] = 36
    return inspect(box.file("uris.gltf", json.dumps(doc)), expect, check)


@attack("mesh", ".gltf buffer http://127.0.0.1:9/buf.bin")
def _gltf_http(box: Box) -> Spec:
    uri = "http://127.0.0.1:9/buf.bin"
    return _gltf_uri(box, uri, "bad", refused_for(uri, "not found"))


@attack("mesh", ".gltf buffer file:///etc/passwd")
def _gltf_file_uri(box: Box) -> Spec:
    return _gltf_uri(box, "file:///etc/passwd", "bad", refused_for("file:///etc/passwd", "not found"))


@attack("mesh", ".gltf buffer /etc/passwd")
def _gltf_absolute(box: Box) -> Spec:
    return _gltf_uri(box, "/etc/passwd", "bad", refused_for("/etc/passwd", "outside its folder"))


@attack("mesh", ".gltf buffer: a data URI that is not base64")
def _gltf_bad_data(box: Box) -> Spec:
    uri = "data:application/octet-stream;base64,!!!" + "A" * 100
    return _gltf_uri(box, uri, "either", refused_for("uris.gltf"))


@attack("mesh", ".gltf buffer: a 40 MB data URI claiming 36 bytes")
def _gltf_data_uri(box: Box) -> Spec:
    data = base64.b64encode(b"\0" * 30_000_000).decode()
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}], uri="data:application/octet-stream;base64," + data)
    # glTF 2.0 (3.6.1.1): a buffer's resource may be longer than its byteLength; the file is valid,
    # the attack is its cost (the mesh file's cap bounds it)
    return inspect(box.file("data.gltf", json.dumps(doc)), "either", check_output=shown("data: 1 objects"))


def _objects(count: int, name: str | None = None, label: str = "chair") -> list[dict[str, Any]]:
    return [{"name": name or f"{label}_{i + 1}", "label": label, "idx": i + 1, "center": [1.0 + i, 1.0, 0.25],
             "size": [0.5, 0.5, 0.5], "facing": [0.0, 1.0], "has_facing": True, "sit_offset_horizontal": 0.0,
             "sit_offset_vertical": 0.0, "interactive": True} for i in range(count)]


def _scene(objects: list[dict[str, Any]], **extra: Any) -> str:
    return json.dumps({"format": "storyteller-scene/1", "name": "s", "floor_z": 0.0, "bounds_min": [0, 0],
                       "bounds_max": [10, 10], "objects": objects, **extra})


@attack("scene", "two objects both named chair_1 (one would be lost)")
def _scene_same_name(box: Box) -> Spec:
    return inspect(box.file("same.json", _scene(_objects(2, name="chair_1"))), "bad",
                   refused_for("chair_1", "duplicate"))


@attack("scene", "bounds_min past bounds_max")
def _scene_bounds(box: Box) -> Spec:
    text = _scene(_objects(2), bounds_min=[10, 10], bounds_max=[0, 0])
    return inspect(box.file("bounds.json", text), "bad",
                   refused_for("bounds_max must be greater than bounds_min"))


@attack("scene", "a box of size 5e-324")
def _scene_tiny_box(box: Box) -> Spec:
    objects = _objects(2)
    objects[1]["size"] = [5e-324, 5e-324, 5e-324]
    return inspect(box.file("tiny.json", _scene(objects)), "either", shown("s: 2 objects"))


@attack("scene", "an object name of 1 MB")
def _scene_long_name(box: Box) -> Spec:
    objects = _objects(2)
    objects[0]["name"] = "chair_" + "9" * 1_000_000
    return inspect(box.file("long.json", _scene(objects)), "bad", refused_for("field 'name'"))


@attack("scene", "a label of 10,000 combining marks")
def _scene_long_label(box: Box) -> Spec:
    objects = _objects(2)
    objects[1]["label"] = "a" + "\u0301" * 10_000
    objects[1]["name"] = objects[1]["label"] + "_2"
    return inspect(box.file("long.json", _scene(objects)), "bad", refused_for("field 'label'"))


@attack("scene", "overlong UTF-8 (C0 AF) in a name")
def _scene_overlong(box: Box) -> Spec:
    text = _scene(_objects(1)).encode().replace(b"chair_1", b"chair\xc0\xaf1")
    return inspect(box.file("overlong.json", text), "bad", refused_for("overlong.json", "UTF-8"))


@attack("config", "inline tables nested 50,000 deep")
def _toml_inline(box: Box) -> Spec:
    return model_info(box.file("inline.toml", "x = " + "{a = " * 50_000 + "1" + "}" * 50_000 + "\n"))


@attack("config", "a dotted key of 50,000 parts")
def _toml_dotted(box: Box) -> Spec:
    return model_info(box.file("dotted.toml", "[llm]\n" + ".".join(["a"] * 50_000) + " = 1\n"))


@attack("config", "a table header of 30,000 parts and 60,000 keys")
def _toml_header(box: Box) -> Spec:
    text = "[" + ".".join(["t"] * 30_000) + "]\n" + "".join(f"k{i} = 1\n" for i in range(60_000))
    return model_info(box.file("header.toml", text))


@attack("config", "UTF-16 TOML with BOM")
def _toml_utf16(box: Box) -> Spec:
    return model_info(box.file("u16.toml", '[llm]\nmodel = "openai/x"\n'.encode("utf-16")))


@attack("config", "--config path named with escapes and bidi, missing")
def _config_name(box: Box) -> Spec:
    return model_info(box.root / ("cfg\x1b[2J\u202e\u2028.toml"))


@attack("config", "timeout_s 5e-324, max_attempts 0, api_base file:///etc/passwd")
def _toml_edges(box: Box) -> Spec:
    text = ('[llm]\nmodel = "openai/x"\napi_base = "file:///etc/passwd"\ntimeout_s = 5e-324\n'
            "[llm.retry]\nmax_attempts = 0\n")
    return model_info(box.file("edges.toml", text))


@attack("script", "an instruction of 2,001 combining marks after one letter")
def _script_marks(box: Box) -> Spec:
    # (a valid script is not an attack the harness can time: the run would then plan with a model)
    return script_run(box, box.file("marks.txt", "00:01 a" + "\u0301" * 2_001 + "\n"))


@attack("script", "UTF-16 script, CR-only line ends")
def _script_utf16(box: Box) -> Spec:
    return script_run(box, box.file("u16.txt", "00:01 sit\r00:02 stand\r".encode("utf-16")))


@attack("script", "times 1e3:00, 0x10:00, 00:01:00:00 and 00:00.000...1")
def _script_times(box: Box) -> Spec:
    text = "1e3:00 a\n0x10:00 b\n00:01:00:00 c\n00:00." + "0" * 28 + "1 d\n"
    return script_run(box, box.file("times.txt", text))


@attack("bench", "sweep.json: the case folder is / (the whole disk)")
def _bench_root(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.edit_json(sweep / "sweep.json",
                  lambda v: {**v, "case_sets": [{**v["case_sets"][0], "path": "/", "scenes_root": "/"}]})
    return score(box, sweep)


@attack("bench", "a case folder with a link loop and a case -> /dev/zero")
def _bench_loop(box: Box) -> Spec:
    sweep = box.copy_sweep()
    cases = box.root / "cases" / "0_OA"
    cases.mkdir(parents=True)
    (cases / "loop").symlink_to(cases)
    (cases / "testcase_100.json").symlink_to("/dev/zero")
    os.mkfifo(cases / "testcase_101.json")
    box.edit_json(sweep / "sweep.json", lambda v: {**v, "case_sets": [{**v["case_sets"][0], "path": str(cases.parent)}]})
    return score(box, sweep)


@attack("bench", "50,000 empty run traces beside the real one")
def _bench_traces(box: Box) -> Spec:
    sweep = box.copy_sweep()
    runs = sweep / "traces" / "runs"
    for i in range(50_000):
        (runs / f"x{i}.jsonl").write_bytes(b"")
    return score(box, sweep, "either")


@attack("program", "--states with positions 1e308 and 5e-324, facing [0, 0]")
def _states_edges(box: Box) -> Spec:
    """A world view (``characters``) valid but for Zoe's numbers (a reference ``current_states``
    holds area texts in a list: the mapping of numbers it was given was refused unread)."""
    states = {"characters": [{"name": "Zoe", "position": [1e308, 5e-324], "facing": [0.0, 0.0], "action": "idle"}]}
    spec = program_run(box.file("prog.py", 'def parse_event():\n    get_character("Zoe").set_target_action("sit")\n'),
                       "program")
    spec.argv += ["--states", str(box.file("states.json", json.dumps(states)))]
    spec.check_output = refused_for("states.json", "characters.0")
    return spec
