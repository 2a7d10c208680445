"""Attacks on inputs other than scenes reach what they target: each file is one the product reads
but for its hostile part, and each check fails on the refusal that hid the target before.

Before, the two ``--states`` attacks gave a reference ``current_states`` as a mapping (the format
holds a list of area texts), refused unread; the 40 MB ``story.jsonl`` line had no ``event``;
the instruction record held a lone surrogate, refused as JSON before replay printed it; and
run.json named ``/dev/zero`` itself as its scene, refused for its name before it was opened.
"""

from __future__ import annotations

import json
from pathlib import Path

from storyteller.benchmark.hostile.harness import BIDI, Box, Spec
from storyteller.benchmark.hostile.runner import ATTACKS
from storyteller.orchestrator.llm.traces import InstructionRecord
from storyteller.orchestrator.session.story_stream import StoryEventRecord, StreamEvent, StreamStart
from storyteller.tools.character_states import WorldView


def _base(root: Path) -> Path:
    """The files of a run folder these attacks read: a trace, story.json and story.jsonl."""
    base = root / "base"
    base.mkdir(parents=True)
    run = {"run_id": "r1", "seq": 0, "time_unix": 0.0, "kind": "run"}
    (base / "trace.jsonl").write_text(json.dumps(run) + "\n", encoding="utf-8")
    manifest = {"scene_name": "home", "arguments": {"scene": "home"}}
    (base / "run.json").write_text(json.dumps(manifest), encoding="utf-8")
    (base / "story.json").write_text("{}", encoding="utf-8")
    start = StreamStart(scene="home", characters=("Zoe",), instruction="", fps=30.0, frame=0)
    event = StoryEventRecord(event_id="event-0000", index=0, characters=("Zoe",), activity="Zoe waves",
                             requested_frame=1, applied_frame=1, state="ongoing", finished_frame=None,
                             failure=None, text="Zoe waves.")
    lines = [json.dumps(line.model_dump(mode="json")) + "\n" for line in (start, StreamEvent(event=event))]
    (base / "story.jsonl").write_text("".join(lines), encoding="utf-8")  # as StoryStream writes them
    return base


def _built(tmp_path: Path, name: str) -> tuple[Box, Spec]:
    (build,) = [fn for _, attack_name, fn in ATTACKS if attack_name == name]
    box = Box(tmp_path / "box", _base(tmp_path), tmp_path / "sweep", tmp_path / "box" / "CANARY")
    return box, build(box)


def _states(spec: Spec) -> WorldView:
    path = Path(spec.argv[spec.argv.index("--states") + 1])
    return WorldView.model_validate_json(path.read_text(encoding="utf-8"))


def test_the_states_attacks_are_world_views(tmp_path: Path) -> None:
    _, spec = _built(tmp_path / "names", "--states with 10,000 characters named with bidi and 100 KB names")
    names = _states(spec).names
    assert len(names) == 10_000 and BIDI in names[0] and len(names[-1]) == 100_000
    _, edges = _built(tmp_path / "edges", "--states with positions 1e308 and 5e-324, facing [0, 0]")
    (zoe,) = _states(edges).characters
    assert zoe.position == (1e308, 5e-324) and zoe.facing == (0.0, 0.0)
    refused = "error: states.json: field 'current_states': expected a list\n"
    assert spec.check_output is not None and spec.check_output(refused) is not None
    assert edges.check_output is not None and edges.check_output(refused) is not None


def test_the_long_story_line_is_an_event(tmp_path: Path) -> None:
    box, spec = _built(tmp_path, "a 40 MB line (export)")
    last = (box.run / "story.jsonl").read_text(encoding="utf-8").splitlines()[-1]
    assert len(StreamEvent.model_validate_json(last).event.text) == 40_000_000
    assert spec.check_output is not None
    assert spec.check_output("error: story.jsonl: line 4: field 'event.event': required field is missing\n")


def test_the_instruction_record_is_read_and_must_be_printed(tmp_path: Path) -> None:
    box, spec = _built(tmp_path, "an instruction record with bidi, escapes and 1 MB of text (replay prints it)")
    line = (box.run / "trace.jsonl").read_text(encoding="utf-8").splitlines()[1]
    assert InstructionRecord.model_validate_json(line).text.startswith("sit down" + BIDI)
    assert spec.check_output is not None
    refused = "error: trace.jsonl: line 2: corrupt trace record (Invalid JSON: unexpected end of hex escape)\n"
    assert spec.check_output(refused) is not None


def test_the_run_json_scene_is_a_device_named_like_a_scene_file(tmp_path: Path) -> None:
    box, spec = _built(tmp_path, "scene -> /dev/zero")
    scene = Path(json.loads((box.run / "run.json").read_text(encoding="utf-8"))["arguments"]["scene"])
    assert scene.suffix == ".json" and scene.resolve() == Path("/dev/zero")
    assert spec.check_output is not None
    assert spec.check_output("error: /dev/zero: unsupported scene file type 'zero'\n") is not None
