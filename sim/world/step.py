"""The world step: characters, events, cooperative walking and motion, one frame at a time.

``step(world, commands, dt) -> (world, StepOutput)`` applies the planner's commands
(``storyteller.sim.world.events``), advances every character by one frame (``dt`` = 1 / fps, 30 fps),
appends a pose per character to the world's track buffers and reports completed / looping /
failed events and the characters available to the narrator. The world is advanced in place
and returned; ``World.snapshot()`` / ``World.restore(snapshot)`` copy its state (plain data:
dataclasses, dicts and numpy arrays) for replays and tests. ``World.stream_tracks(store)``
makes the track buffers stream to chunk files (``storyteller.sim.world.track_chunks``): memory then holds
one window of frames, a snapshot holds only the frames not yet in the store (and how many are),
and restoring it cuts the store back to that count.

The step is four parts: event bookkeeping (``storyteller.sim.world.event_book``: assigning and releasing,
the start queue and group starts, completion and failure, who is free), the phases of this
module (``World.advance``), the walkers' arrivals and stalls (``storyteller.sim.world.arrivals``), and
motion assembly (``storyteller.sim.world.frame_assembly``: motion queries in, poses and track rows out).

Who moves a character's root (pelvis ground point, metres):

- walkers (``approaching``; ``idle`` standing characters, including those waiting at their
  target for the event's other members, who step aside for passers-by and walk back) are on
  the ``CrowdNavigator``'s position exactly, so its clearance rule (centres >= 2 body radii
  apart, bodies off every blocking footprint) holds for the synthesized pelvis;
- everyone else is a stationary obstacle for the navigator: characters transitioning in or
  out, acting, seated, or standing still after an action until the next planning step. A
  seated body registers discs along its sit-down path (approach point to seat point, at least
  three, <= 0.4 m apart: ``event_book.seat_discs``) while it sits down, sits and stands up; they keep
  walkers 2 body radii from both ends and at least ~0.45 m from the segment between them.

Walkers join the navigator only at planning-step boundaries (every ``step_frames`` frames,
9 at 0.3 m cells and 1 m/s): a character that finished standing up waits in place until then.

Events: every member walks to the EXACT point the planner gave (``StandTarget``): its target
when standing, the seat's approach point (``NavGrid.approach_point``, cached) when sitting. It
walks the grid to the point's entry cell, then straight onto the point, and counts as arrived
once it stands there. A point a body cannot stand on or walk straight to falls back to the
nearest cell centre; ``CharacterState.target.fallback`` keeps the typed reason
(``TargetFallback``). Whoever arrives first waits; when all stand on their points at a
planning-step boundary, all start their transition in on the same frame: each turns in place
(root about the pelvis) to its partners, the object it uses or the planner's facing
(``storyteller.sim.world.facing``) before it acts. A walker that a stall rule would stop out of reach of
the object its action works on walks to a free point within reach instead (``out_of_reach``,
at most ``WorldConfig.max_replans`` times), or keeps waiting for room (and fails as stuck if
none comes): it never acts out of reach or facing away.
An event completes when every member has finished its action (or, acting a looping action,
was interrupted or released); it becomes *looping* when every member is done or acting a
looping action. Characters of looping events are available, and a new assignment interrupts
them via their transition out. Unreachable targets and walkers that make no progress for
``stuck_after_s`` seconds fail the event with a typed ``EventFailure``.

Deterministic: the only randomness is the navigator's seeded priority order; no clock.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from storyteller.sim.body.foot_ik import FootSolver, FootState
from storyteller.sim.paths.cooperative_astar import Cell, PathPlanner
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.arm_room import ArmBoxes
from storyteller.sim.world.arrivals import walker_checks
from storyteller.sim.world.character_track import CharacterTrack
from storyteller.sim.world.errors import WorldError
from storyteller.sim.world.event_book import (
    EventState,
    StepReport,
    assign,
    final_of,
    free_characters,
    member_done,
    release,
    start_groups,
    take,
    unstarted,
)
from storyteller.sim.world.events import AssignEvent, ReleaseCharacters, StepOutput
from storyteller.sim.world.frame_assembly import write_frame
from storyteller.sim.world.motion_layer import FUTURE_FRAMES, MotionLayer
from storyteller.sim.world.navigation import OFF_GRID_EPS, StandTargets, WorldNavigator
from storyteller.sim.world.phases import (
    INFINITE,
    CharacterState,
    interaction_frames,
)
from storyteller.sim.world.track_chunks import ChunkStore
from storyteller.sim.world.tracks import TrackBuffers

STREAM_WINDOW = 300
"""Frames (10 s at 30 fps) a streaming world keeps in memory per character at most."""


@dataclass(frozen=True)
class WorldConfig:
    """fps: frames per second; seed: navigator priority seed; walk_turn_rate: rad/s a walker's
    heading may turn (faster turns swing the planted feet around the root: sliding);
    heading_lookahead: frames ahead on the plan that a walker turns to face (looking past the
    grid's zigzags); stuck_after_s: seconds without getting closer before a walker fails;
    max_target_offset: metres between a target and the nearest reachable cell centre beyond
    which the target counts as unreachable; exact_patience_s: seconds a walker on its goal cell
    waits for room to step onto its exact target before it settles for the cell centre
    (``target_occupied``); near_enough_m, near_patience_s: a standing walker that got no closer
    for ``near_patience_s`` within ``near_enough_m`` of its target acts where it stands
    (``stopped_near``); max_replans: points within reach a stalled walker may be sent to for one
    assignment (``out_of_reach``); initial_capacity: frames pre-allocated per track; foot_ik: run the
    leg IK (``sim.body.foot_ik.FootSolver``) on every frame's poses: feet kept out of floor-standing
    furniture and pinned while in contact (characters sitting, sitting down or standing up are
    left as animated), then the legs of different characters kept apart
    (``sim.body.leg_separation``)."""

    fps: int = 30
    seed: int = 0
    walk_turn_rate: float = 2.0
    heading_lookahead: int = 20
    stuck_after_s: float = 20.0
    near_enough_m: float = 1.0
    near_patience_s: float = 6.0
    max_target_offset: float = 0.75
    exact_patience_s: float = 3.0
    max_replans: int = 3
    initial_capacity: int = 512
    foot_ik: bool = True


@dataclass
class WorldSnapshot:
    """A deep copy of a world's mutable state (restore with ``World.restore``)."""

    frame: int
    characters: dict[str, CharacterState]
    events: dict[str, EventState]
    motion_states: dict[str, Any]
    navigator: WorldNavigator
    buffers: TrackBuffers
    feet: FootState | None = None


class World:
    """All characters of one scene. Build with ``World(scene, characters, motion)``.

    ``characters``: name -> ((x, y) metres, heading radians); each starts standing idle on the
    centre of the free navigation cell nearest to its position. ``motion``: the motion layer
    (e.g. ``sim.motion.matching.MotionMatcher``). ``grid`` / ``planner`` default to
    ``build_nav_grid(scene)`` and ``PathPlanner(grid, seed=config.seed)``.
    """

    def __init__(
        self,
        scene: Scene,
        characters: Mapping[str, tuple[tuple[float, float], float]],
        motion: MotionLayer,
        *,
        grid: NavGrid | None = None,
        planner: PathPlanner | None = None,
        config: WorldConfig | None = None,
    ) -> None:
        self.config = config or WorldConfig()
        if self.config.fps < 1:
            raise WorldError(f"fps must be >= 1, got {self.config.fps}")
        if not characters:
            raise WorldError("a world needs at least one character")
        self.scene = scene
        self.grid = grid if grid is not None else build_nav_grid(scene)
        self.planner = planner if planner is not None else PathPlanner(self.grid, seed=self.config.seed)
        self.motion = motion
        self.dt = 1.0 / self.config.fps
        self.names: tuple[str, ...] = tuple(characters)
        self.frame = 0
        self.navigator = WorldNavigator(self.grid, self.planner, self.config.fps, self.config.seed)
        self.characters: dict[str, CharacterState] = {}
        self.events: dict[str, EventState] = {}
        self.start_queue: dict[str, None] = {}  # ongoing, not yet started events, in ``events`` order
        self.targets = StandTargets(self.grid)
        self.motion_states: dict[str, Any] = {}
        taken: dict[Cell, str] = {}
        for name, (xy, heading) in characters.items():
            if not isinstance(name, str) or not name:  # type: ignore[redundant-expr]  # callers pass untyped data
                raise WorldError(f"character names must be non-empty strings, got {name!r}")
            p = np.asarray(xy, dtype=float)
            if p.shape != (2,) or not np.all(np.isfinite(p)) or not math.isfinite(heading):
                raise WorldError(f"character {name!r}: position must be finite (x, y) and heading a finite angle")
            cell = self.grid.nearest_free_cell(p)
            if cell in taken:
                raise WorldError(f"characters {taken[cell]!r} and {name!r} start on the same cell {cell}")
            taken[cell] = name
            centre = self.grid.center_of(*cell)
            self.characters[name] = CharacterState(name=name, xy=centre, heading=float(heading), anchor_xy=centre,
                                                   anchor_cell=cell)
            self.navigator.add_walker(name, cell)
            self.motion_states[name] = motion.initial_state("idle", centre, float(heading))
        self.buffers = TrackBuffers(self.names, max(1, self.config.initial_capacity))
        self.foot_solver = FootSolver.from_scene(scene) if self.config.foot_ik else None
        self.feet: FootState | None = FootSolver.initial_state(len(self.names)) if self.foot_solver else None
        self.arm_boxes = ArmBoxes.from_scene(scene)

    # ----- snapshots ---------------------------------------------------------------------------
    def shared_objects(self) -> dict[str, Any]:
        """The read-only objects a snapshot refers to instead of copying (scene, grids, path
        planners, motion layer), by a stable name: a serialized snapshot stores these names and
        is loaded against the same objects of a world built from the same inputs."""
        nav = self.navigator.nav
        return {"scene": self.scene, "grid": self.grid, "planner": self.planner, "motion": self.motion,
                "nav.grid": nav.grid, "nav.planner": nav.planner}

    def _shared_memo(self) -> dict[int, Any]:
        return {id(obj): obj for obj in self.shared_objects().values()}

    def snapshot(self) -> WorldSnapshot:
        """A copy of the mutable state; the world can go on stepping afterwards."""
        memo = self._shared_memo()
        return WorldSnapshot(
            frame=self.frame,
            characters=copy.deepcopy(self.characters, memo),
            events=copy.deepcopy(self.events, memo),
            motion_states=copy.deepcopy(self.motion_states, memo),
            navigator=copy.deepcopy(self.navigator, memo),
            buffers=self.buffers.trimmed(),
            feet=copy.deepcopy(self.feet),
        )

    def stream_tracks(self, store: ChunkStore, window: int = STREAM_WINDOW) -> None:
        """Keep at most ``window`` frames per character in memory from now on, the older ones in
        ``store`` (which must hold exactly the frames this world's buffers have passed on)."""
        self.buffers.stream_to(store, window)

    def restore(self, snap: WorldSnapshot, *, store: ChunkStore | None = None) -> World:
        """A new world in the state of ``snap`` (sharing scene, grid, planner and motion layer).

        A streaming world keeps streaming to its store (or to ``store``, e.g. the chunk files of
        an earlier process), cut back to the snapshot's frames in the store (``WorldError`` when
        the store holds fewer, or there is no store and the snapshot's first frames are in one)."""
        window = self.buffers.window or STREAM_WINDOW
        if store is None:
            store = self.buffers.store
        base = snap.buffers.base
        if store is None and base > 0:
            raise WorldError(f"the snapshot's first {base} frames are in chunk files; stream_tracks() to them first")
        if store is not None:
            if store.frames < base:
                raise WorldError(f"the chunk files hold {store.frames} frames, the snapshot needs {base}")
            store.cut(base)
        out = copy.copy(self)
        memo = self._shared_memo()
        out.frame = snap.frame
        out.characters = copy.deepcopy(snap.characters, memo)
        out.events = copy.deepcopy(snap.events, memo)
        out.start_queue = unstarted(out.events)
        out.motion_states = copy.deepcopy(snap.motion_states, memo)
        out.navigator = copy.deepcopy(snap.navigator, memo)
        out.buffers = snap.buffers.trimmed()
        if store is not None:
            out.buffers.stream_to(store, window)
        out.feet = copy.deepcopy(snap.feet)
        return out

    # ----- read-outs ------------------------------------------------------------------------------
    def available(self) -> tuple[str, ...]:
        """Characters the narrator may give a new event (``storyteller.sim.world.event_book.free_characters``)."""
        return free_characters(self)

    def tracks(self) -> dict[str, CharacterTrack]:
        """One ``CharacterTrack`` per character with every frame produced so far."""
        if self.buffers.length == 0:
            raise WorldError("no frame has been produced yet")
        return {name: self.track(name) for name in self.names}

    def track(self, name: str) -> CharacterTrack:
        """The ``CharacterTrack`` of one character (read from the chunk store when streaming)."""
        if self.buffers.length == 0:
            raise WorldError("no frame has been produced yet")
        f = self.buffers.frames(self.names.index(name))
        return CharacterTrack(
            name=name,
            root_positions=f.pelvis,
            local_rotations=f.rotations,  # float32; the track keeps a float64 copy
            fps=float(self.config.fps),
            action_labels=f.labels,
        )

    def foot_contacts(self) -> dict[str, np.ndarray]:
        """Per character, the motion layer's left/right foot contact flags (frames, 2)."""
        return {name: self.buffers.frames(k).contacts for k, name in enumerate(self.names)}

    def event_ids(self) -> dict[str, tuple[str, ...]]:
        """Per character, the event it belonged to at every frame ("" when none)."""
        return {name: self.buffers.frames(k).events for k, name in enumerate(self.names)}

    def positions(self) -> np.ndarray:
        """Current root xy (N, 2) in ``names`` order."""
        return np.array([self.characters[n].xy for n in self.names])

    # ----- the frame ------------------------------------------------------------------------------
    def advance(self, out: StepReport) -> None:
        """One frame after the commands: phases that end, walkers that join the navigator and
        its tick, arrivals and group starts (at step boundaries), then the motion of every
        character (``storyteller.sim.world.frame_assembly.write_frame``). Events found completed, looping,
        started or failed go to ``out``."""
        nav = self.navigator
        boundary = nav.at_boundary()
        self._phase_ends(out)
        if boundary:
            self._join_walkers()
        horizon = (0, *FUTURE_FRAMES, self.config.heading_lookahead)
        nav.tick(horizon)  # walkers' positions this frame and their planned futures (read below)
        if boundary:
            walker_checks(self, out)
            start_groups(self, out)
        write_frame(self, horizon)

    # ----- phases ---------------------------------------------------------------------------------
    def _phase_ends(self, out: StepReport) -> None:
        fps = self.config.fps
        for c in self.characters.values():
            if not c.phase_over:
                continue
            a = c.assignment
            if c.phase == "transition_in":
                assert a is not None
                c.seated = a.seat is not None
                if c.seated:
                    assert c.seat_xy is not None
                    c.xy = c.seat_xy.copy()
                c.heading = c.act_heading
                c.enter("interacting", interaction_frames(a, fps))
                if c.loops:
                    member_done(self, c, out)
            elif c.phase == "interacting":
                c.enter("idle")
                member_done(self, c, out)
            elif c.phase == "transition_out":
                if c.seated:
                    c.seated = False
                    c.xy = c.anchor_xy.copy()
                    self.navigator.make_stationary(c.name, [c.anchor_xy])
                c.enter("idle")
                if c.pending is None:
                    c.assignment = None

    def _join_walkers(self) -> None:
        """At a step boundary: standing, stationary characters with nothing to wait for walk again."""
        for c in self.characters.values():
            if c.walker or c.seated or c.waiting or c.phase not in ("idle", "approaching"):
                continue
            if c.phase == "idle" and c.pending is not None:
                eid, a, target = c.pending
                c.pending = None
                ev = self.events.get(eid)
                if ev is not None and ev.status == "ongoing" and c.event_id == eid:
                    take(c, a, target)
                    c.enter("approaching")
            cell = c.anchor_cell
            off = float(np.linalg.norm(c.anchor_xy - self.grid.center_of(*cell))) > OFF_GRID_EPS
            approaching = c.phase == "approaching"
            self.navigator.add_walker(
                c.name, cell, c.goal_cell if approaching else None,
                start_xy=c.anchor_xy if off else None,
                final_xy=final_of(c.target) if approaching else None,
            )
            c.walker = True


def step(world: World, commands: Iterable[AssignEvent | ReleaseCharacters], dt: float) -> tuple[World, StepOutput]:
    """Apply ``commands`` and advance ``world`` by one frame of ``dt`` seconds (must be 1 / fps).

    Returns the same (mutated) world and what happened in the frame. Raises ``WorldError`` for
    a wrong ``dt`` or an event id that is already running; everything else the planner can get
    wrong (unknown names, busy characters, unreachable targets) comes back as failures.
    """
    if not math.isfinite(dt) or abs(dt - world.dt) > 1e-9:
        raise WorldError(f"dt must be 1/{world.config.fps} s = {world.dt:.6f} s, got {dt!r}")
    out = StepReport()
    for cmd in commands:
        if isinstance(cmd, AssignEvent):
            assign(world, cmd, out)
        elif isinstance(cmd, ReleaseCharacters):
            release(world, cmd, out)
        else:
            raise WorldError(f"unknown command {type(cmd).__name__}; expected AssignEvent or ReleaseCharacters")
    world.advance(out)
    frame = world.frame
    world.frame += 1
    return world, StepOutput(
        frame=frame,
        completed_events=tuple(out.completed),
        looping_events=tuple(out.looping),
        started_events=tuple(out.started),
        failures=tuple(out.failures),
        available=world.available(),
    )


def run(world: World, frames: int, commands_at: Mapping[int, Sequence[AssignEvent | ReleaseCharacters]] | None = None) -> list[StepOutput]:
    """Step ``frames`` frames, applying ``commands_at[frame]`` before each; returns the outputs."""
    outs = []
    schedule = commands_at or {}
    for _ in range(frames):
        _, o = step(world, schedule.get(world.frame, ()), world.dt)
        outs.append(o)
    return outs


__all__ = ["INFINITE", "STREAM_WINDOW", "EventState", "World", "WorldConfig", "WorldError", "WorldSnapshot", "run", "step"]
