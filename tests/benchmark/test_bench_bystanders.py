"""``python -m storyteller.benchmark.bystanders`` on a hand-made run folder: which bystander events count as
their own, and the frames where two characters use one single-user object."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from storyteller.benchmark.bystanders import check_run, main, report, shared_seat_frames
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.tools.areas import seat_slots

README = "Ava makes coffee, then sits on the couch and drinks it."


def _plan(who: str, action: str, obj: str, xy: tuple[float, float], seat: str | None = None) -> dict[str, object]:
    area = f"sit on {obj}" if seat else f"interact with {obj}"
    return {"character": who, "action": action, "area": area, "position": list(xy), "facing": [0.0, 1.0], "seat": seat}


def _write_run(folder: Path) -> None:
    home = load_bundled_scene("home")
    maker = home.by_name["coffee_maker_1"].center
    at_maker = (float(maker[0]), float(maker[1]) - 0.5)
    steps = [
        (0, "Ava makes coffee.", _plan("Ava", "use_coffee_maker", "coffee_maker_1", at_maker)),
        (1, "", _plan("Ben", "use_coffee_maker", "coffee_maker_1", at_maker)),  # the instruction's activity
        (2, "", _plan("Ben", "read_book", "armchair_1", (1.0, 1.0), seat="armchair_1")),
        (3, "", _plan("Ben", "read_book", "chair_5", (1.0, 2.0), seat="chair_5")),  # a repeat
        (4, "", _plan("Ben", "use_toaster", "toaster_1", (1.0, 3.0))),
    ]
    story = {
        "scene": "home", "characters": ["Ava", "Ben"], "instruction": README,
        "instructions": [{"frame": 0, "time_s": 0.0, "source": "command line", "text": README}],
        "fps": 30.0, "frames": 20,
        "steps": [{"index": i, "kind": "event", "characters": [p["character"]], "activity": "", "plans": [p]}
                  for i, _, p in steps],
        "events": [{"event_id": f"event-{i:04d}", "index": i, "characters": [p["character"]], "activity": "",
                    "requested_frame": i, "applied_frame": i, "state": "completed", "finished_frame": i + 1,
                    "failure": None, "part": part} for i, part, p in steps],
    }  # fmt: skip
    folder.mkdir()
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    for name, label in (("Ava", "use_coffee_maker"), ("Ben", "use_coffee_maker")):
        labels = np.array([label] * 8 + ["idle"] * 12)  # both at the coffee maker for 8 frames
        positions = np.tile(np.array([*at_maker, 0.9]), (20, 1))
        np.savez(folder / f"{name}.track.npz", action_labels=labels, root_positions=positions)


def test_bystander_events_and_shared_frames_are_counted(tmp_path: Path) -> None:
    _write_run(tmp_path / "run")
    check = check_run(tmp_path / "run")
    assert check.error is None
    assert (check.events, check.own) == (4, 2)  # the coffee and the second book are not his own
    assert any("use_coffee_maker (the instruction's activity)" in m for m in check.misses)
    assert any("read_book (a repeat)" in m for m in check.misses)
    assert check.shared_frames == 8 and check.frames == 20
    assert len(check.areas) >= 2
    text = report([check])
    assert "2/4 (50.0%) (target 95% not met)" in text and "8 of 20 (target 0)" in text


def test_the_command_reads_run_folders_and_refuses_a_missing_one(tmp_path: Path) -> None:
    _write_run(tmp_path / "run")
    assert main(["--runs", str(tmp_path)]) == 0
    assert main(["--runs", str(tmp_path / "nowhere")]) == 2


def test_two_characters_seated_in_one_seat_place_are_counted() -> None:
    """From the story suite replayed at c842af8: Ava and Cleo both sat on office chair_5 for 474
    frames (two planning steps gave it to each); a chair is a single-user object too."""
    office = load_bundled_scene("office")
    (one,) = seat_slots(office.by_name["chair_5"])
    (other,) = seat_slots(office.by_name["chair_4"])
    ava = np.array([one.position] * 10)
    cleo = np.array([one.position] * 6 + [other.position] * 4)
    labels = {"Ava": ["attend_meeting@seated"] * 10, "Cleo": ["walk"] * 2 + ["attend_meeting@seated"] * 8}
    assert shared_seat_frames(labels, {"Ava": ava, "Cleo": cleo}, office) == 4  # frames 2-5; then chair_4
    couch = load_bundled_scene("home")
    a, b, *_ = seat_slots(couch.by_name["couch_1"])
    two = {"Ava": np.array([a.position] * 3), "Ben": np.array([b.position] * 3)}
    assert shared_seat_frames({"Ava": ["drink@seated"] * 3, "Ben": ["drink@seated"] * 3}, two, couch) == 0  # two places
