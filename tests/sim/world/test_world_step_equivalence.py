"""The world step gives exactly the output it gave before its speed-ups (recorded fingerprint).

A deterministic 10-character world in the reference Office runs for 420 frames: walkers sent to
random targets (some exact off-grid points) and re-sent whenever their event loops or fails, a
two-character group event (chat with partners, released later), a seated action on a chair and
a release. Everything the world produces is hashed: every motion query (label, seated, root,
heading, planned futures and future headings, targets, restart flag), every ``StepOutput``,
the track buffers (pelvis, rotations, labels, contacts, event ids), the final character states
and the navigator's counters. Floats are rounded to 1e-10 before hashing (so a last-bit
difference of an equivalent formula would not count, any real change would); a few exact
positions are compared as well.

The fingerprint was first recorded from the code before the speed-ups (commit cb21243) and
re-recorded once on purpose, when walkers began keeping still-valid plans by default
(``CrowdNavigator(reuse_plans=True)``; the speed-ups were checked against the first), and again
when the world began putting a seated pelvis on its seat's height (``storyteller.sim.world.contacts``:
poses of seated characters only; every root, query and output else the same), and when a pair
doing a partner action began standing at the action's distance (``storyteller.sim.world.partners``: the
chatting pair's points, so the final points of c0, c1 and c6 moved), and when a foot whose
animated toe is within ``storyteller.sim.body.foot_kernel.LAND_M`` of the floor began to be pinned with or
without the clip's contact flag (leg rotations only; roots the same), and when a drinking or
eating character's hand began going to its mouth (``storyteller.sim.world.contacts``: c2's arm while it
drinks seated), and when two walkers that both move in a step began keeping their legs apart
(``storyteller.sim.paths.move_tables.striding_safe``: c0, c1 and c6 end elsewhere at frame 420), and when an
arm that would pass into a box began swinging out of it at the shoulder (``storyteller.sim.world.arm_room``:
shoulder rotations only; every root, query, output and final point the same). If the
world's behaviour is changed on purpose, re-record it with
``python -m tests.sim.world.test_world_step_equivalence`` and say so in the commit message.
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

import numpy as np
import pytest

from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, heading_to_root
from storyteller.sim.motion.matching import MotionQuery, Pose
from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.world.events import AssignEvent, Assignment, ReleaseCharacters, StepOutput
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.reference import OFFICE, reference_or_skip

FRAMES = 420
EXPECTED_SHA256 = "ff697a5885e7d0e81b07307eac593a7f30744e82b1f06099700000b7a0154dec"
EXPECTED_FINAL_XY: dict[str, tuple[float, float]] = {
    "c0": (5.7989999999999995, 3.9526666666666657),
    "c1": (6.099, 5.152666666666667),
    "c2": (3.9989999999999997, 13.219333333333335),
    "c3": (5.199, 12.952666666666666),
    "c4": (5.365666666666667, 15.052666666666667),
    "c5": (4.4656666666666665, 8.286),
    "c6": (6.099, 4.552666666666666),
    "c7": (5.199, 15.652666666666669),
    "c8": (1.899, 13.519333333333334),
    "c9": (3.399, 10.252666666666666),
}


class RecordingMotion:
    """Rest pose on the world's root (pelvis lowered when seated), alternating foot contacts;
    hashes every query it gets."""

    def __init__(self) -> None:
        self.hash = hashlib.sha256()
        self.queries = 0

    def initial_state(self, label: str, root_xy: Any, heading: float, seated: bool = False) -> int:
        return 0

    def step(self, state: int, query: MotionQuery, dt: float) -> tuple[int, Pose]:
        h = self.hash
        h.update(f"{query.label}|{query.seated}|{query.force_search}|".encode())
        for v in (query.root_xy, query.heading, query.future_xy, query.future_heading, query.target_xy,
                  query.target_facing, query.seat_height):
            _feed(h, v)
        self.queries += 1
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        rot[0] = heading_to_root(float(query.heading or 0.0))
        sitting = query.seated or query.label in ("sit_down", "stand_up")
        z = 0.55 if sitting else float(REST_OFFSETS[0, 1])
        root = np.asarray(query.root_xy, dtype=float)
        contacts = np.array([state % 2 == 0, state % 3 == 0])
        return state + 1, Pose(np.array([*root, z]), rot, root, float(query.heading or 0.0), contacts)


def _feed(h: Any, v: Any) -> None:
    """Hash ``v`` (None, a float or an array) with floats rounded to 1e-10 (and -0.0 as 0.0)."""
    if v is None:
        h.update(b"N")
        return
    a = np.asarray(v, dtype=float)
    h.update(str(a.shape).encode())
    h.update((np.round(a, 10) + 0.0).tobytes())


def _out_text(o: StepOutput) -> str:
    fails = [(f.event_id, f.character, f.reason, f.message) for f in o.failures]
    return f"{o.frame}|{o.completed_events}|{o.looping_events}|{o.started_events}|{fails}|{o.available}"


Simulated = tuple[str, dict[str, tuple[float, float]], World, list[StepOutput]]
"""The scenario's digest, final positions, world and step outputs."""


def simulate() -> Simulated:
    """(fingerprint, final exact positions, world, outputs) of the scenario."""
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    motion = RecordingMotion()
    cells = np.argwhere(grid.component == grid.main_component)
    rng = np.random.default_rng(7)
    chair = scene.get("chair_1")
    seat_cell = np.asarray(grid.approach_cell(chair))

    def cheb(a: np.ndarray, b: np.ndarray) -> int:
        return int(np.max(np.abs(a - b)))

    # c2 starts 4 cells from the chair's approach cell; c0 and c1 start near each other
    sitter = next(c for c in cells if cheb(c, seat_cell) == 4)
    free = {(int(i), int(j)) for i, j in cells}
    c0 = next(c for c in cells if cheb(c, seat_cell) >= 12
              and all((int(c[0]) + a, int(c[1]) + b) in free for a in range(-1, 6) for b in range(-1, 3)))
    c1 = c0 + np.array([4, 0])
    starts: list[np.ndarray] = [c0, c1, sitter]
    for c in (cells[k] for k in rng.permutation(len(cells))):
        if all(cheb(c, o) >= 3 for o in starts) and cheb(c, seat_cell) >= 3:
            starts.append(c)
        if len(starts) == 10:
            break
    names = [f"c{k}" for k in range(10)]
    world = World(scene, {nm: (tuple(grid.center_of(*c)), 0.3 * k) for k, (nm, c) in enumerate(zip(names, starts, strict=True))},
                  motion, grid=grid, planner=PathPlanner(grid, seed=5), config=WorldConfig(seed=5, initial_capacity=64))

    def xy(c: np.ndarray) -> tuple[float, float]:
        p = grid.center_of(int(c[0]), int(c[1]))
        return (float(p[0]), float(p[1]))

    count = dict.fromkeys(names, 0)

    def errand(nm: str) -> AssignEvent:
        count[nm] += 1
        c = cells[int(rng.integers(len(cells)))]
        p = np.asarray(xy(c))
        if rng.random() < 0.5:  # an exact off-grid point where a body fits
            q = p + rng.uniform(-0.12, 0.12, size=2)
            if grid.is_free_xy(q):
                p = q
        theta = float(rng.uniform(-math.pi, math.pi))
        action = ("idle", "wave", "drink")[int(rng.integers(3))]
        return AssignEvent(event_id=f"{nm}-{count[nm]}", assignments=(Assignment(
            character=nm, action=action, target_xy=(float(p[0]), float(p[1])),
            facing_xy=(math.cos(theta), math.sin(theta))),))

    first: list[AssignEvent | ReleaseCharacters] = [
        AssignEvent(event_id="talk", assignments=(
            Assignment(character="c0", action="chat", target_xy=xy(c0 + np.array([0, 1])), facing_xy=(1.0, 0.0), partners=("c1",)),
            Assignment(character="c1", action="chat", target_xy=xy(c0 + np.array([2, 1])), facing_xy=(-1.0, 0.0),
                       partners=("c0",)),
        )),
        AssignEvent(event_id="sit", assignments=(Assignment(
            character="c2", action="drink", target_xy=tuple(chair.seat_point()), facing_xy=chair.facing,
            seat="chair_1"),)),
    ]
    first += [errand(nm) for nm in names[3:]]
    schedule: dict[int, list[AssignEvent | ReleaseCharacters]] = {0: first, 240: [ReleaseCharacters(characters=("c0", "c1"))]}
    outs: list[StepOutput] = []
    todo: set[str] = set()
    for f in range(FRAMES):
        cmds = list(schedule.get(f, []))
        cmds += [errand(nm) for nm in sorted(todo)]
        _, out = step(world, cmds, world.dt)
        outs.append(out)
        done = out.looping_events + out.completed_events
        todo = {e.rsplit("-", 1)[0] for e in done if "-" in e}
        todo |= {fl.character for fl in out.failures if fl.character in names and fl.reason != "busy"}
        if "sit" in out.completed_events:
            todo |= {"c2"}  # the sitter stands up for a new errand
        if "talk" in out.completed_events:
            todo |= {"c0", "c1"}
    h = motion.hash
    for o in outs:
        h.update(_out_text(o).encode())
    b = world.buffers
    for arr in (b.pelvis[: b.length], b.rotations[: b.length]):
        _feed(h, arr)
    h.update(b.labels[: b.length].tobytes())
    h.update(b.contacts[: b.length].tobytes())
    h.update(b.events[: b.length].tobytes())
    h.update(repr(b.label_names).encode())
    for nm in names:
        c = world.characters[nm]
        h.update(f"{nm}|{c.phase}|{c.phase_frame}|{c.phase_length}|{c.event_id}|{c.waiting}|{c.seated}|"
                 f"{c.walker}|{c.goal_cell}|{c.anchor_cell}|{c.stalled_frames}|{c.motion_key}|{c.target}".encode())
        for v in (c.xy, c.heading, c.anchor_xy, c.seat_xy):
            _feed(h, v)
    nav = world.navigator.nav
    h.update(f"{nav.replans}|{nav.failures}|{nav.fallbacks}|{nav.leg_waits}|{motion.queries}".encode())
    final = {nm: (float(world.characters[nm].xy[0]), float(world.characters[nm].xy[1])) for nm in names}
    return h.hexdigest(), final, world, outs


@pytest.fixture(scope="module")
def result() -> Simulated:
    reference_or_skip()
    return simulate()


def test_the_scenario_exercises_walkers_groups_seats_and_releases(result: Simulated) -> None:
    _, _, world, outs = result
    started = {e for o in outs for e in o.started_events}
    assert {"talk", "sit"} <= started
    labels = set(world.buffers.label_names)
    assert {"walk", "chat", "sit_down", "drink@seated", "stand_up"} <= labels
    assert any(o.completed_events for o in outs) and any(o.looping_events for o in outs)
    assert world.navigator.nav.replans > 20
    targets = [world.characters[n].target for n in world.names]
    assert any(t is not None and t.off_grid for t in targets)


def test_world_output_matches_the_recorded_fingerprint(result: Simulated) -> None:
    digest, final, _, _ = result
    assert final == EXPECTED_FINAL_XY
    assert digest == EXPECTED_SHA256


def test_the_worlds_query_constructor_builds_the_same_queries() -> None:
    from storyteller.sim.world.frame_assembly import _new_query

    kw: dict[str, Any] = dict(label="walk", seated=False, root_xy=np.array([1.0, 2.0]), heading=0.5,
                              future_xy=np.zeros((3, 2)), future_heading=np.ones(3), target_xy=None, target_facing=None,
                              seat_height=0.45, force_search=True)
    fast, plain = _new_query(**kw), MotionQuery(**kw)
    assert type(fast) is MotionQuery
    assert list(vars(fast)) == list(vars(plain))
    assert all(vars(fast)[k] is vars(plain)[k] for k in kw)
    with pytest.raises(AttributeError):  # still frozen
        fast.__setattr__("label", "idle")  # assigning to a frozen field is what is tested


def test_poses_without_contact_flags_give_no_contacts() -> None:
    from types import SimpleNamespace

    from storyteller.sim.world.frame_assembly import _contacts_of

    poses = [SimpleNamespace(contacts=np.array([True, False])), SimpleNamespace(contacts=None), SimpleNamespace()]
    assert _contacts_of(poses).tolist() == [[True, False], [False, False], [False, False]]
    assert _contacts_of(poses[:1]).tolist() == [[True, False]]


def test_the_fingerprint_notices_a_changed_position(result: Simulated) -> None:
    # The hash is sensitive at the 1e-9 m level: a nudged value gives another digest.
    h1, h2 = hashlib.sha256(), hashlib.sha256()
    _feed(h1, np.array([1.0, 2.0]))
    _feed(h2, np.array([1.0, 2.0 + 1e-9]))
    assert h1.hexdigest() != h2.hexdigest()


if __name__ == "__main__":
    d, xy, w, _ = simulate()
    print(f'EXPECTED_SHA256 = "{d}"')
    print("EXPECTED_FINAL_XY = {")
    for k, v in xy.items():
        print(f'    "{k}": ({v[0]!r}, {v[1]!r}),')
    print("}")
    print("labels", w.buffers.label_names, "replans", w.navigator.nav.replans)
