"""Facing and distance when interactions start: do characters face what they use and whom they talk to?

For every *standing* interaction (an action done with a scene object or with partners; seated
ones face their seat's front and are left out) the measure reads the character's track:

- the interaction is the first run of frames, within its event, whose action label is the
  action's; it starts at the run's first frame;
- facing error (degrees): the root's forward yaw (``storyteller.sim.world.motion_layer.root_yaw``) against
  the direction from the root to the nearest point of the object's footprint (to its centre
  from inside it), or to the mean position of the partners at that frame; at the start and at
  every frame of the run ("during");
- distance at start (metres): root to the object's footprint (object interactions only).

The object of an interaction is ``storyteller.sim.world.facing.focus_object``'s: the one its action names
(``use_coffee_maker`` -> the nearest ``coffee_maker`` within 1.5 m of the planned point), else,
for an action whose hands work on an object, the first object the plan's area names ("adjacent
to bookshelf_1"), else none: drinking, waving and the like are not counted. It is never where
the planner looked, which is part of what is checked. (The world faces the same object: for a
run made before the world did, the figures say how far off it was.)

Sources: a scripted story (``scripted_story``: five characters in the bundled home scene,
events planned through the real spatial API and ``AssignEvent.from_plans``, some with the
contention and stray orientations a small planning model produces: two characters sent to the
same coffee maker, ``set_orientation`` to a bystander), run once as the world does it and once
with the object left out of every assignment (the world before facing was checked: acting on
the planner's facing where the character stopped); and any run folders given (``story.json``
plans, ``<name>.track.npz``, ``scene.json``). Targets: median <= 10 and p95 <= 25 degrees at
the start.

``python -m storyteller.benchmark.motion_facing [RUN_DIR ...]``; ``python -m storyteller.benchmark.motion_quality``
prints the same table after its own.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.action_labels import action_spec, database_key
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.facing import focus_object, heading_to_object, surface_distance
from storyteller.sim.world.motion_layer import MotionLayer, root_yaw

START_MEDIAN_TARGET = 10.0  # degrees
START_P95_TARGET = 25.0  # degrees


@dataclass(frozen=True)
class Interaction:
    """One standing interaction measured on a track (angles in degrees, distances in metres)."""

    character: str
    action: str
    toward: str  # the object's name, or "partners: A, B"
    start_frame: int
    frames: int
    start_error: float
    errors: tuple[float, ...]  # every frame of the run, the start first
    start_distance: float | None  # to the object's footprint; None for partners


@dataclass(frozen=True)
class FacingSummary:
    """Figures over several interactions (degrees, metres; nan where there is nothing)."""

    count: int
    start_median: float
    start_p95: float
    start_max: float
    during_median: float
    during_p95: float
    within_25: float  # share of starts within 25 degrees
    distance_median: float
    distance_max: float

    @property
    def meets_targets(self) -> bool:
        return self.count > 0 and self.start_median <= START_MEDIAN_TARGET and self.start_p95 <= START_P95_TARGET


def used_object(scene: Scene, action: str, position: Sequence[float], area: str = "") -> SceneObject | None:
    """The object an interaction uses (see the module docstring), or None."""
    name = focus_object(scene, action, position, area)
    return None if name is None else scene.by_name[name]


def _angle_error(yaw: float, want: float | None) -> float:
    if want is None:
        return 0.0
    return abs(math.degrees((want - yaw + math.pi) % (2.0 * math.pi) - math.pi))


def first_run(labels: Sequence[str], key: str, start: int, end: int) -> tuple[int, int] | None:
    """(first frame, frames) of the first run of ``key`` in ``labels[start:end]``, or None."""
    i = next((k for k in range(max(0, start), min(end, len(labels))) if labels[k] == key), None)
    if i is None:
        return None
    j = i
    while j < min(end, len(labels)) and labels[j] == key:
        j += 1
    return i, j - i


def measure_interaction(
    character: str, action: str, yaw: NDArray[np.float64], xy: NDArray[np.float64], run: tuple[int, int],
    obj: SceneObject | None, partner_xy: NDArray[np.float64] | None,
) -> Interaction | None:
    """The figures of one interaction: ``yaw`` (F,) and ``xy`` (F, 2) of the character's root,
    ``run`` its (first frame, frames); toward ``obj``, or toward the mean of ``partner_xy``
    (P, F, 2) when given; None when it has neither."""
    first, n = run
    frames = range(first, first + n)
    wants: list[float | None]
    if partner_xy is not None and len(partner_xy):
        centre = np.asarray(partner_xy, dtype=float).mean(axis=0)
        wants = [math.atan2(float(centre[f, 1] - xy[f, 1]), float(centre[f, 0] - xy[f, 0])) for f in frames]
        toward, distance = "partners", None
    elif obj is not None:
        wants = [heading_to_object(obj, xy[f]) for f in frames]
        toward, distance = obj.name, surface_distance(obj, xy[first])
    else:
        return None
    errors = tuple(_angle_error(float(yaw[f]), w) for f, w in zip(frames, wants, strict=True))
    return Interaction(character, action, toward, first, n, errors[0], errors, distance)


def summarize(items: Sequence[Interaction]) -> FacingSummary:
    """Median / p95 / max of the start errors, median / p95 of every frame's error, the share
    of starts within 25 degrees and the median / max distance to objects at the start."""
    if not items:
        nan = math.nan
        return FacingSummary(0, nan, nan, nan, nan, nan, nan, nan, nan)
    start = np.array([i.start_error for i in items])
    during = np.concatenate([np.asarray(i.errors) for i in items])
    dist = np.array([i.start_distance for i in items if i.start_distance is not None])
    return FacingSummary(
        count=len(items),
        start_median=float(np.median(start)),
        start_p95=float(np.percentile(start, 95)),
        start_max=float(start.max()),
        during_median=float(np.median(during)),
        during_p95=float(np.percentile(during, 95)),
        within_25=float(np.mean(start <= 25.0)),
        distance_median=float(np.median(dist)) if len(dist) else math.nan,
        distance_max=float(dist.max()) if len(dist) else math.nan,
    )


# ----- run folders ------------------------------------------------------------------------------
def run_folder_interactions(folder: Path) -> list[Interaction]:
    """The standing interactions of a finished run folder (``story.json``, ``scene.json`` and
    ``<name>.track.npz``)."""
    from storyteller.sim.scene.files import load_scene

    story = json.loads((folder / "story.json").read_text(encoding="utf-8"))
    scene = load_scene(folder / "scene.json")
    tracks: dict[str, tuple[NDArray[np.float64], NDArray[np.float64], list[str]]] = {}
    for name in story.get("characters", []):
        path = folder / f"{name}.track.npz"
        if path.is_file():
            with np.load(path, allow_pickle=False) as t:
                tracks[name] = (root_yaw(np.asarray(t["local_rotations"], dtype=float)[:, 0]),
                                np.asarray(t["root_positions"], dtype=float)[:, :2], [str(x) for x in t["action_labels"]])
    ends = {e["index"]: (e.get("applied_frame") or 0, e.get("finished_frame")) for e in story.get("events", [])}
    out: list[Interaction] = []
    for step in story.get("steps", []):
        if step.get("kind") != "event":
            continue
        start, end = ends.get(step["index"], (step.get("applied_frame") or 0, None))
        for plan in step.get("plans", []):
            name, action = plan["character"], plan["action"]
            if plan.get("seat") is not None or name not in tracks:
                continue
            yaw, xy, labels = tracks[name]
            run = first_run(labels, database_key(action), start, len(labels) if end is None else end + 1)
            if run is None:
                continue
            partners = [p for p in step.get("characters", []) if p != name and p in tracks]
            pxy = (np.stack([tracks[p][1] for p in partners])
                   if partners and action_spec(action).family == "partner" else None)
            obj = None if pxy is not None else used_object(scene, action, plan["position"], plan.get("area", ""))
            item = measure_interaction(name, action, yaw, xy, run, obj, pxy)
            if item is not None:
                out.append(item)
    return out


# ----- the scripted story -----------------------------------------------------------------------
@dataclass(frozen=True)
class Part:
    """One character's part of a scripted event: ``area`` is a spatial-API area function and its
    object (``("get_area_to_interact_with", "coffee_maker_1")``); ``look`` what the program
    passes to ``set_orientation`` (None: nothing)."""

    character: str
    action: str
    area: tuple[str, str]
    look: str | None = None


SCRIPT: tuple[tuple[Part, ...], ...] = (
    (Part("Ava", "use_coffee_maker", ("get_area_to_interact_with", "coffee_maker_1")),),
    (Part("Ben", "use_coffee_maker", ("get_area_to_interact_with", "coffee_maker_1"), look="Ava"),),
    (Part("Cleo", "chat", ("get_area_close_to", "floor_lamp_1")), Part("Dan", "chat", ("get_area_close_to", "floor_lamp_1"))),
    (Part("Eve", "open_fridge", ("get_area_to_interact_with", "fridge_1"), look="tv_1"),),
    (Part("Ava", "use_microwave", ("get_area_to_interact_with", "microwave_1")),),
    (Part("Ben", "use_toaster", ("get_area_adjacent_to", "toaster_1")),),
    (Part("Eve", "turn_on_tv", ("get_area_in_front_of", "tv_1")),),
    (Part("Cleo", "turn_on_record_player", ("get_area_to_interact_with", "record_player_1")),),
    (Part("Dan", "take_out_book", ("get_area_adjacent_to", "bookshelf_1"), look="couch_1"),),
    (Part("Ava", "chat", ("get_area_adjacent_to", "table_1")), Part("Ben", "chat", ("get_area_adjacent_to", "table_1"))),
    (Part("Cleo", "take_out_drink", ("get_area_to_interact_with", "fridge_1")),),
    (Part("Eve", "handshake", ("get_area_close_to", "armchair_1")), Part("Dan", "handshake", ("get_area_close_to", "armchair_1"))),
    (Part("Ava", "clean_table", ("get_area_adjacent_to", "table_1"), look="Cleo"),),
    (Part("Ben", "use_dishwasher", ("get_area_to_interact_with", "dishwasher_1"), look="Eve"),),
)
START_XY = {"Ava": (2.5, 1.5), "Ben": (5.5, 3.0), "Cleo": (6.0, 6.0), "Dan": (1.2, 5.5), "Eve": (3.2, 4.2)}
LOOP_S = 4.0  # seconds a looping action (chat) goes on before the character's next event interrupts it


def scripted_story(motion: MotionLayer, *, keep_focus: bool = True, seconds: float = 150.0,
                   seed: int = 0) -> list[Interaction]:
    """Run ``SCRIPT`` in the bundled home scene and measure its interactions. Each event is
    planned through ``storyteller.tools.spatial_api.SpatialAPI`` (seeded) when all its characters are free
    (a looping one after ``LOOP_S``) and applied with ``AssignEvent.from_plans``;
    ``keep_focus=False`` drops the object from every assignment (the world before facing was
    checked). Deterministic."""
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.sim.world.events import AssignEvent
    from storyteller.sim.world.step import World, WorldConfig, step
    from storyteller.tools.character_states import CharacterState, WorldView
    from storyteller.tools.spatial_api import SpatialAPI

    scene = load_bundled_scene("home")
    fps = 30
    frames = round(seconds * fps)
    world = World(scene, {n: (xy, 0.0) for n, xy in START_XY.items()}, motion,
                  config=WorldConfig(seed=seed, initial_capacity=frames))
    pending = list(enumerate(SCRIPT))
    busy_until: dict[str, int] = {}
    planned: dict[str, tuple[tuple[Part, ...], dict[str, tuple[float, float]]]] = {}
    free = set(world.available())
    for _ in range(frames):
        commands = []
        for k, parts in list(pending):
            names = [p.character for p in parts]
            if any(n not in free or busy_until.get(n, 0) > world.frame for n in names):
                continue
            if any(n in {p.character for _, q in pending[: pending.index((k, parts))] for p in q} for n in names):
                continue  # an earlier event of the same character goes first
            view = WorldView(characters=tuple(
                CharacterState(name=n, position=(float(c.xy[0]), float(c.xy[1])))
                for n, c in world.characters.items()))
            api = SpatialAPI(scene, world=view)
            for p in parts:
                h = api.get_character(p.character)
                h.set_position(getattr(api, p.area[0])(p.area[1]))
                h.set_target_action(p.action)
                if p.look is not None:
                    h.set_orientation(p.look)
            plans = api.resolve(seed + k)
            cmd = AssignEvent.from_plans(f"e{k}", plans, scene)
            if not keep_focus:
                cmd = cmd.model_copy(update={"assignments": tuple(
                    a.model_copy(update={"focus": None}) for a in cmd.assignments)})
            commands.append(cmd)
            planned[f"e{k}"] = (parts, {pl.character: pl.position for pl in plans})
            pending.remove((k, parts))
            for n in names:
                free.discard(n)
        _, out = step(world, commands, world.dt)
        free = set(out.available)
        for eid in out.looping_events:
            for p in planned[eid][0]:
                busy_until[p.character] = world.frame + round(LOOP_S * fps)
    return _world_interactions(world, scene, planned)


def _world_interactions(world: object, scene: Scene,
                        planned: dict[str, tuple[tuple[Part, ...], dict[str, tuple[float, float]]]]) -> list[Interaction]:
    from storyteller.sim.world.step import World

    assert isinstance(world, World)
    tracks = world.tracks()
    event_ids = world.event_ids()
    yaw = {n: root_yaw(t.local_rotations[:, 0]) for n, t in tracks.items()}
    xy = {n: t.root_positions[:, :2] for n, t in tracks.items()}
    out: list[Interaction] = []
    for eid, (parts, positions) in planned.items():
        for p in parts:
            ids = event_ids[p.character]
            frames = [f for f, e in enumerate(ids) if e == eid]
            labels = tracks[p.character].action_labels
            if not frames or labels is None:
                continue
            run = first_run(labels, database_key(p.action), frames[0], frames[-1] + 1)
            if run is None:
                continue
            others = [q.character for q in parts if q.character != p.character]
            pxy = np.stack([xy[n] for n in others]) if others and action_spec(p.action).family == "partner" else None
            obj = None if pxy is not None else used_object(scene, p.action, positions[p.character], " ".join(p.area))
            item = measure_interaction(p.character, p.action, yaw[p.character], xy[p.character], run, obj, pxy)
            if item is not None:
                out.append(item)
    return out


# ----- report -----------------------------------------------------------------------------------
def format_summary_table(rows: Sequence[tuple[str, FacingSummary]]) -> str:
    """One line per source: counts, start and during facing errors (degrees), distances (metres)."""
    head = (f"{'source':34s}{'n':>4s}{'start med':>10s}{'p95':>7s}{'max':>7s}{'during med':>11s}{'p95':>7s}"
            f"{'<=25deg':>8s}{'dist med':>9s}{'max':>6s}  targets")
    lines = [head]
    for name, s in rows:
        ok = "met" if s.meets_targets else "NOT met"
        lines.append(f"{name[:34]:34s}{s.count:4d}{s.start_median:10.1f}{s.start_p95:7.1f}{s.start_max:7.1f}"
                     f"{s.during_median:11.1f}{s.during_p95:7.1f}{s.within_25:8.2f}{s.distance_median:9.2f}"
                     f"{s.distance_max:6.2f}  {ok}")
    return "\n".join(lines)


def format_worst(items: Sequence[Interaction], n: int = 5) -> str:
    """The ``n`` interactions with the largest start error, one per line."""
    worst = sorted(items, key=lambda i: -i.start_error)[:n]
    return "\n".join(
        f"  {i.character:6s}{i.action:24s}{i.toward:18s} frame {i.start_frame:5d}: {i.start_error:6.1f} deg"
        + ("" if i.start_distance is None else f", {i.start_distance:.2f} m")
        for i in worst)


def report(motion_factory: Callable[[], MotionLayer], runs: Sequence[Path] = (), seconds: float = 150.0) -> str:
    """The facing table: the scripted story as the world runs it and without objects (before),
    then every run folder of ``runs``; the worst starts of the world's run below it."""
    t0 = time.perf_counter()
    world = scripted_story(motion_factory(), seconds=seconds)
    before = scripted_story(motion_factory(), keep_focus=False, seconds=seconds)
    rows = [("scripted home story (world)", summarize(world)),
            ("same, planner facing only (before)", summarize(before))]
    for folder in runs:
        rows.append((f"run {folder.name}", summarize(run_folder_interactions(folder))))
    return (f"facing at interaction start (standing; targets: median <= {START_MEDIAN_TARGET:g}, p95 <= "
            f"{START_P95_TARGET:g} deg; {time.perf_counter() - t0:.1f} s)\n"
            + format_summary_table(rows) + "\nworst starts (world):\n" + format_worst(world)
            + "\nworst starts (before):\n" + format_worst(before))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", type=Path, help="run folders to measure too")
    parser.add_argument("--seconds", type=float, default=150.0, help="simulated seconds of the scripted story")
    args = parser.parse_args(argv)
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    dbs = load_databases(cache_dir=motion_cache_dir())
    print(report(lambda: MotionMatcher(dbs), args.runs, args.seconds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
