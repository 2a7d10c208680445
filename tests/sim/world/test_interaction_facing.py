"""Characters face what they use and whom they talk to, within reach, before they act
(storyteller.sim.world.facing, the transition in and the stall rules of storyteller.sim.world.step).

Deterministic worlds with the rest-pose stand-in motion: the root's yaw is the world's heading
(``compose_poses``), so a track's root rotation is what is measured."""

from __future__ import annotations

import math

import numpy as np

from storyteller.sim.scene.authoring import Item, Layout, N, build_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment, StepOutput
from storyteller.sim.world.facing import REACH_M, focus_object, heading_to_object, surface_distance
from storyteller.sim.world.motion_layer import root_yaw
from storyteller.sim.world.phases import TURN_SPEED
from storyteller.sim.world.step import World, WorldConfig, step
from storyteller.tools.character_states import CharacterPlan
from tests.support.stand_in_motion import RestPoseMotion

AVA_SPOT = (1.407, 0.913)  # the README story's spot in front of the home coffee maker



def _angle(a: float, b: float) -> float:
    """Degrees between two yaws."""
    return abs(math.degrees((a - b + math.pi) % (2.0 * math.pi) - math.pi))


def _run(world: World, frames: int, commands: dict[int, list[AssignEvent]]) -> list[StepOutput]:
    return [step(world, commands.get(world.frame, []), world.dt)[1] for _ in range(frames)]


def _facing_errors(world: World, name: str, label: str, toward: np.ndarray | str) -> tuple[list[float], list[float]]:
    """Facing errors (degrees) and distances to the object (metres) at every frame of ``name``'s
    track labelled ``label``; ``toward`` is an object name or a fixed point."""
    t = world.track(name)
    yaw, xy = root_yaw(t.local_rotations[:, 0]), t.root_positions[:, :2]
    assert t.action_labels is not None
    errors, dists = [], []
    for f, lab in enumerate(t.action_labels):
        if lab != label:
            continue
        if isinstance(toward, str):
            obj = world.scene.by_name[toward]
            want = heading_to_object(obj, xy[f])
            dists.append(surface_distance(obj, xy[f]))
        else:
            d = toward - xy[f]
            want = math.atan2(d[1], d[0])
        assert want is not None
        errors.append(_angle(float(yaw[f]), want))
    return errors, dists


def _coffee(name: str, xy: tuple[float, float], facing: tuple[float, float], eid: str) -> AssignEvent:
    return AssignEvent(event_id=eid, assignments=(Assignment(
        character=name, action="use_coffee_maker", target_xy=xy, facing_xy=facing, focus="coffee_maker_1"),))


def test_a_stalled_walker_replans_a_spot_within_reach_and_acts_facing_the_object(home: Scene) -> None:
    """Ava stands at the coffee maker's spot; Ben is sent right next to her with a facing away
    from it (what a small planner wrote). Before: the stall rule let him act where he stopped,
    0.69 m off and 38 degrees away (140 with this facing). Now he walks to a free point within
    reach and turns to the coffee maker first."""
    w = World(home, {"Ava": ((2.5, 2.0), 0.0), "Ben": ((3.0, 4.5), 0.0)}, RestPoseMotion(),
              config=WorldConfig(foot_ik=False))
    outs = _run(w, 900, {0: [_coffee("Ava", AVA_SPOT, (-0.19, -0.982), "a")],
                         60: [_coffee("Ben", (1.30, 0.90), (0.0, 1.0), "b")]})
    assert [f for o in outs for f in o.failures] == []
    assert "b" in {e for o in outs for e in o.completed_events}
    ben = w.characters["Ben"]
    assert ben.target is not None and ben.target.fallback == "out_of_reach", ben.target
    for who in ("Ava", "Ben"):
        errors, dists = _facing_errors(w, who, "use_coffee_maker", "coffee_maker_1")
        assert len(errors) == 180  # the whole action, 6 s
        assert max(errors) < 1.0, (who, max(errors))
        assert dists[0] <= REACH_M + 1e-9, (who, dists[0])
    ava, ben_xy = w.track("Ava").root_positions[-1, :2], w.track("Ben").root_positions[-1, :2]
    assert np.linalg.norm(ava - ben_xy) >= 0.5 - 1e-9  # he found room beside her, not on her


def test_a_walker_with_no_spot_within_reach_waits_and_never_acts_facing_away(home: Scene) -> None:
    """The same stall with re-planning switched off: Ben waits for room (none comes) and the
    event fails as stuck; he never plays the action out of reach or facing away."""
    w = World(home, {"Ava": ((2.5, 2.0), 0.0), "Ben": ((3.0, 4.5), 0.0)}, RestPoseMotion(),
              config=WorldConfig(foot_ik=False, max_replans=0, stuck_after_s=12.0))
    outs = _run(w, 900, {0: [_coffee("Ava", AVA_SPOT, (-0.19, -0.982), "a")],
                         60: [_coffee("Ben", (1.30, 0.90), (0.0, 1.0), "b")]})
    failures = [f for o in outs for f in o.failures]
    assert [(f.event_id, f.reason) for f in failures] == [("b", "stuck")]
    labels = w.track("Ben").action_labels
    assert labels is not None and "use_coffee_maker" not in labels


def test_a_point_out_of_reach_is_replaced_by_one_within_reach_when_assigned(home: Scene) -> None:
    """The planner put the character a metre from the coffee maker ('close to'): it stands within
    reach instead, and says why."""
    w = World(home, {"Ava": ((2.5, 2.0), 0.0)}, RestPoseMotion(), config=WorldConfig(foot_ik=False))
    far = (1.3, 1.55)
    assert surface_distance(home.by_name["coffee_maker_1"], far) > 1.0
    outs = _run(w, 400, {0: [_coffee("Ava", far, (0.0, -1.0), "a")]})
    assert "a" in {e for o in outs for e in o.completed_events}
    target = w.characters["Ava"].target
    assert target is not None and target.fallback == "out_of_reach" and "out of reach" in target.message
    _, dists = _facing_errors(w, "Ava", "use_coffee_maker", "coffee_maker_1")
    assert dists[0] <= REACH_M + 1e-9


def test_a_character_arriving_with_its_back_to_the_object_turns_in_place_first() -> None:
    """A dispenser alone in a room; the walker comes from behind it to its front and arrives
    sideways, with a planner facing pointing away. It turns on the spot (the root stays put, the
    turn is bounded, idle plays) and acts facing the dispenser."""
    scene = build_scene(Layout("room", (5.0, 5.0), (Item("water_dispenser", 2.5, 2.5, 0.35, 0.35, 1.1, N),)))
    obj = scene.by_name["water_dispenser_1"]
    w = World(scene, {"ann": ((2.5, 0.8), 0.0)}, RestPoseMotion(), config=WorldConfig(foot_ik=False))
    a = Assignment(character="ann", action="use_water_dispenser", target_xy=(2.5, 3.1), facing_xy=(0.0, 1.0),
                   focus="water_dispenser_1")
    _run(w, 300, {0: [AssignEvent(event_id="e", assignments=(a,))]})
    t = w.track("ann")
    labels = t.action_labels
    assert labels is not None
    yaw, xy = root_yaw(t.local_rotations[:, 0]), t.root_positions[:, :2]
    start = labels.index("use_water_dispenser")
    walk_end = max(f for f in range(start) if labels[f] == "walk")
    want = heading_to_object(obj, xy[start])
    assert want is not None
    assert _angle(float(yaw[walk_end]), want) > 60.0  # it arrived not facing the dispenser
    assert _angle(float(yaw[start]), want) < 10.0
    turn = range(walk_end + 1, start)
    assert len(turn) >= 9 and all(labels[f] == "idle" for f in turn)
    assert float(np.max(np.linalg.norm(xy[walk_end + 1 : start + 1] - xy[start], axis=1))) < 1e-9  # no sliding
    steps = [_angle(float(yaw[f]), float(yaw[f - 1])) for f in range(walk_end + 1, start + 1)]
    # smoothstep's peak is 1.5x the mean speed of pi rad/s (the frame count is rounded: +5% here)
    assert 0.0 < max(steps) <= math.degrees(1.6 * TURN_SPEED / 30.0)


def test_chat_partners_face_each_other_whatever_the_planner_wrote(home: Scene) -> None:
    w = World(home, {"Ava": ((5.55, 2.55), 0.0), "Ben": ((6.15, 4.05), 0.0)}, RestPoseMotion(),
              config=WorldConfig(foot_ik=False))
    ev = AssignEvent(event_id="talk", assignments=(
        Assignment(character="Ava", action="chat", target_xy=(5.55, 3.15), facing_xy=(1.0, 0.0), partners=("Ben",)),
        Assignment(character="Ben", action="chat", target_xy=(6.15, 3.75), facing_xy=(1.0, 0.0), partners=("Ava",)),
    ))
    outs = _run(w, 300, {0: [ev]})
    assert "talk" in {e for o in outs for e in o.looping_events}
    for me, other in (("Ava", "Ben"), ("Ben", "Ava")):
        errors, _ = _facing_errors(w, me, "chat", w.track(other).root_positions[-1, :2])
        assert errors and max(errors) < 1.0, (me, errors[:3])


def test_plans_name_the_object_an_action_uses(home: Scene) -> None:
    # the action names it, wherever the planner looked (a small model set_orientation's a bystander)
    assert focus_object(home, "use_coffee_maker", AVA_SPOT, "interact with coffee_maker_1") == "coffee_maker_1"
    assert focus_object(home, "use_coffee_maker", (1.3, 1.6), "close to table_1") == "coffee_maker_1"
    # hands on an object the action does not name: the area's object
    assert focus_object(home, "take_out_book", (0.6, 6.5), "adjacent to bookshelf_1") == "bookshelf_1"
    # nothing to work on: the planner's facing stands
    assert focus_object(home, "drink", (2.2, 1.9), "adjacent to table_1") is None
    assert focus_object(home, "wave", (2.2, 1.9), "adjacent to table_1") is None
    # too far from any coffee maker to be meant: what the area names, or nothing
    assert focus_object(home, "use_coffee_maker", (6.0, 6.0), "close to couch_1") == "couch_1"
    assert focus_object(home, "use_coffee_maker", (6.0, 6.0), "") is None
    # AssignEvent.from_plans fills it in for standing plans only
    plans = [CharacterPlan(character="Ava", action="use_coffee_maker", position=AVA_SPOT, facing=(0.0, 1.0),
                           area="interact with coffee_maker_1"),
             CharacterPlan(character="Ben", action="drink", position=(4.0, 5.59), facing=(0.0, 1.0),
                           area="sit on couch_1", seat="couch_1")]
    ava, ben = AssignEvent.from_plans("e", plans, home).assignments
    assert ava.focus == "coffee_maker_1" and ben.focus is None


def test_an_unknown_focus_fails_the_event_as_a_whole(home: Scene) -> None:
    w = World(home, {"Ava": ((2.5, 2.0), 0.0)}, RestPoseMotion(), config=WorldConfig(foot_ik=False))
    ev = AssignEvent(event_id="e", assignments=(Assignment(
        character="Ava", action="use_coffee_maker", target_xy=AVA_SPOT, facing_xy=(0.0, -1.0), focus="kettle_9"),))
    (out,) = _run(w, 1, {0: [ev]})
    assert [(f.reason, f.message) for f in out.failures] == [("unknown_object", "no object called 'kettle_9' in the scene")]
    assert w.characters["Ava"].phase == "idle" and w.characters["Ava"].assignment is None


def test_replanning_and_turning_are_deterministic_and_survive_snapshots(home: Scene) -> None:
    commands = {0: [_coffee("Ava", AVA_SPOT, (-0.19, -0.982), "a")], 60: [_coffee("Ben", (1.30, 0.90), (0.0, 1.0), "b")]}

    def world() -> World:
        return World(home, {"Ava": ((2.5, 2.0), 0.0), "Ben": ((3.0, 4.5), 0.0)}, RestPoseMotion(),
                     config=WorldConfig(foot_ik=False))

    first, second = world(), world()
    _run(first, 700, commands)
    _run(second, 420, commands)  # Ben has re-planned and walks to his new point
    assert second.characters["Ben"].replans == 1
    resumed = second.restore(second.snapshot())
    _run(resumed, 280, commands)
    for name in ("Ava", "Ben"):
        a, b = first.track(name), resumed.track(name)
        assert np.array_equal(a.root_positions, b.root_positions) and np.array_equal(a.local_rotations, b.local_rotations)
