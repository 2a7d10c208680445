"""The facing measure (benchmark/motion_facing.py): errors at interaction start and while it
lasts, distances, run folders, and the scripted story with and without the world's facing."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from storyteller.benchmark.motion_facing import (
    first_run,
    format_summary_table,
    measure_interaction,
    run_folder_interactions,
    scripted_story,
    summarize,
    used_object,
)
from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.character_track import CharacterTrack
from tests.support.stand_in_motion import RestPoseMotion

SPOT = (1.407, 0.913)  # in front of the home coffee maker, whose front face is straight -y of it



def test_first_run_finds_the_first_stretch_of_a_label_inside_the_window() -> None:
    labels = ["idle", "drink", "drink", "idle", "drink", "drink", "drink"]
    assert first_run(labels, "drink", 0, 7) == (1, 2)
    assert first_run(labels, "drink", 3, 7) == (4, 3)
    assert first_run(labels, "drink", 3, 5) == (4, 1)
    assert first_run(labels, "wave", 0, 7) is None


def test_errors_are_measured_against_the_objects_nearest_point_and_the_partners(home: Scene) -> None:
    cm = home.by_name["coffee_maker_1"]
    n = 10
    xy = np.tile(SPOT, (n, 1))
    away = measure_interaction("Ben", "use_coffee_maker", np.full(n, math.pi / 2), xy, (2, 5), cm, None)
    toward = measure_interaction("Ava", "use_coffee_maker", np.full(n, -math.pi / 2), xy, (2, 5), cm, None)
    assert away is not None and toward is not None
    assert away.start_error == pytest.approx(180.0) and toward.start_error == pytest.approx(0.0, abs=1e-9)
    assert away.start_distance == pytest.approx(0.403) and len(away.errors) == 5
    # partners: the mean of their positions, frame by frame (from frame 4 one stands to the side)
    east, north = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    partner = np.stack([xy + east, xy + east])
    partner[1, 4:] = xy[4:] + 2.0 * north - east
    chat = measure_interaction("Ava", "chat", np.zeros(n), xy, (2, 5), None, partner[:1])
    assert chat is not None and chat.start_distance is None and max(chat.errors) == pytest.approx(0.0, abs=1e-9)
    both = measure_interaction("Ava", "chat", np.zeros(n), xy, (2, 5), None, partner)
    assert both is not None and both.start_error == 0.0
    assert both.errors[2:] == pytest.approx([90.0] * 3)  # the mean is now straight north
    assert measure_interaction("Ava", "drink", np.zeros(n), xy, (0, 3), None, None) is None
    s = summarize([away, toward])
    assert s.count == 2 and s.start_median == pytest.approx(90.0) and s.within_25 == 0.5
    assert not s.meets_targets and summarize([toward]).meets_targets
    assert "NOT met" in format_summary_table([("x", s)])


def test_the_object_is_the_one_the_action_names_or_the_area_names_for_hands_on_actions(home: Scene) -> None:
    assert used_object(home, "use_coffee_maker", SPOT, "interact with coffee_maker_1") == home.by_name["coffee_maker_1"]
    assert used_object(home, "take_out_book", (0.6, 6.5), "adjacent to bookshelf_1") == home.by_name["bookshelf_1"]
    assert used_object(home, "drink", (2.2, 1.9), "adjacent to table_1") is None


def test_a_run_folder_with_a_character_acting_facing_away_is_measured_so(home: Scene, tmp_path: Path) -> None:
    n = 40
    labels = tuple(["walk"] * 10 + ["idle"] * 5 + ["use_coffee_maker"] * 20 + ["idle"] * 5)
    rot = np.tile(np.eye(3), (n, NUM_JOINTS, 1, 1))
    rot[:, 0] = heading_to_root(math.pi / 2)  # its back to the counter
    pelvis = np.column_stack([np.tile(SPOT, (n, 1)), np.full(n, 0.9)])
    CharacterTrack(name="Ben", root_positions=pelvis, local_rotations=rot, fps=30.0,
                   action_labels=labels).save(tmp_path / "Ben.track.npz")
    save_scene_json(home, tmp_path / "scene.json")
    plan = {"character": "Ben", "action": "use_coffee_maker", "area": "interact with coffee_maker_1",
            "position": list(SPOT), "facing": [0.0, 1.0], "seat": None}
    story = {"characters": ["Ben"], "steps": [
        {"index": 0, "applied_frame": 1, "kind": "event", "characters": ["Ben"], "plans": [plan]},
        {"index": 1, "applied_frame": 2, "kind": "wait"}],
        "events": [{"event_id": "event-0000", "index": 0, "applied_frame": 1, "finished_frame": 35}]}
    (tmp_path / "story.json").write_text(json.dumps(story), encoding="utf-8")
    (item,) = run_folder_interactions(tmp_path)
    assert (item.character, item.toward, item.start_frame, item.frames) == ("Ben", "coffee_maker_1", 15, 20)
    assert item.start_error == pytest.approx(180.0) and item.start_distance == pytest.approx(0.403)


@pytest.mark.slow
def test_the_scripted_story_meets_the_targets_only_with_the_worlds_facing() -> None:
    """The same story, planned the same way: acting on the planner's facing where the character
    stopped misses the targets by far; facing from where it stands meets them."""
    after = summarize(scripted_story(RestPoseMotion(), seconds=100.0))
    before = summarize(scripted_story(RestPoseMotion(), keep_focus=False, seconds=100.0))
    assert after.count >= 10 and before.count >= 8
    assert after.meets_targets and after.start_max < 10.0 and after.distance_max <= 0.85
    assert not before.meets_targets and before.start_p95 > 90.0
