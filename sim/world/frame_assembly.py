"""Frame assembly of the world step (motion assembly): motion queries in, poses and track rows out.

``write_frame`` turns every character's state into one ``MotionQuery`` (label and seated flag
from its phase, root and heading, the planned future of a walker, the target of its action),
steps the motion layer (batched when it has ``step_batch`` (poses as arrays) or ``step_many``,
with the same result as one by one), puts each pose on its character's root (``compose_poses``: the pelvis stays where the
world put the root), runs the leg IK when the world has a foot solver (feet out of furniture and pinned, then the legs of
different characters kept apart: ``storyteller.sim.body.leg_separation``), places the working hands and swings the other
arms out of the furniture (``storyteller.sim.world.arm_room``), and appends one row per
character to the track buffers. A character's root is never moved by the motion layer:
walkers take the navigator's position, everyone else the point its phase puts it on
(``stationary_root``).

Functions of a ``MotionWorld`` (the parts of ``storyteller.sim.world.step.World`` they read and change).
Deterministic: characters are visited in ``names`` order.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from storyteller.sim.body.foot_ik import FootSolver, FootState
from storyteller.sim.body.leg_separation import TOUCHING_ACTIONS, separate_legs
from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.motion.action_labels import action_spec, database_key
from storyteller.sim.paths.tracks import walker_headings
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.arm_room import ArmBoxes, arm_rules, arms_clear
from storyteller.sim.world.contacts import (
    hand_targets,
    seat_pelvis,
    sit_progress,
    stand_progress,
)
from storyteller.sim.world.legroom import along_way
from storyteller.sim.world.motion_layer import BatchedMotionLayer, MotionLayer, MotionQuery, compose_poses
from storyteller.sim.world.navigation import WorldNavigator
from storyteller.sim.world.phases import CharacterState, phase_motion, smoothstep, turn_heading, wrap_angle
from storyteller.sim.world.tracks import TrackBuffers

OBJECT_REACH = 0.55  # metres from the standing root to the object acted on (motion target)


class MotionSettings(Protocol):
    """The settings motion assembly reads (``sim.world.step.WorldConfig`` has them)."""

    @property
    def walk_turn_rate(self) -> float: ...


class MotionWorld(Protocol):
    """The parts of a world that motion assembly reads and changes."""

    @property
    def config(self) -> MotionSettings: ...

    scene: Scene
    names: tuple[str, ...]
    dt: float
    characters: dict[str, CharacterState]
    navigator: WorldNavigator
    motion: MotionLayer
    motion_states: dict[str, Any]
    buffers: TrackBuffers
    foot_solver: FootSolver | None
    feet: FootState | None
    arm_boxes: ArmBoxes


def write_frame(w: MotionWorld, horizon: Sequence[int]) -> None:
    """One frame of every character: roots (walkers from the navigator's tick, the others from
    their phase), motion queries, the motion layer's step, composed poses, leg IK, and a row
    of the track buffers; every phase timer advances by one frame. ``horizon``: the frames
    the navigator was ticked with (now, the three future frames, the heading lookahead)."""
    nav = w.navigator
    names = w.names
    chars = [w.characters[name] for name in names]
    n = len(names)
    dt = w.dt
    max_turn = w.config.walk_turn_rate * dt
    queries: list[MotionQuery] = []
    labels: list[str] = []
    still_feet: list[bool] = []  # sitting, sitting down, standing up: feet as animated
    seat_transit: list[bool] = []  # sitting down, standing up: planted feet pinned all the same
    seated_l: list[bool] = []
    seat_h: list[float | None] = []  # the seat's height of a character with a seat target
    heading_l: list[float] = []
    root_l: list[np.ndarray] = []
    walkers = [c for c in chars if c.walker]
    walk: dict[int, int] = {}  # id(c) -> the walker's row
    if walkers:  # the walkers' arrays in one go: planned futures, distances, future headings
        # path[:, 0]: the position now (as ticked), 1-3: the planned future, 4: the point
        # the heading turns to
        path = nav.futures([c.name for c in walkers], horizon)
        steps = path[:, 1:4] - path[:, 0:3]  # the three future steps
        wrapped, fut_h, moved = walker_headings(
            np.array([c.xy for c in walkers], dtype=float).reshape(-1, 2), path,
            np.array([c.heading for c in walkers], dtype=float), np.arctan2(steps[..., 1], steps[..., 0]), max_turn)
        h_l, moving_l = wrapped.tolist(), moved.tolist()
        now, future, fut_hl = list(path[:, 0]), list(path[:, 1:4]), list(fut_h)
        walk = {id(c): i for i, c in enumerate(walkers)}
    for c in chars:  # in order: a partner's target is the partners' position so far
        i = walk.get(id(c))
        if i is not None:
            c.xy, c.heading = now[i], h_l[i]
            fut_xy, fut_heading, moving = future[i], fut_hl[i], moving_l[i]
        else:
            fut_xy = fut_heading = None
            moving = False
            stationary_root(c)
        label, seated = phase_motion(c, moving)
        key = _database_key(label, seated)
        restart = key != c.motion_key or c.phase_frame == 0
        c.motion_key = key
        tx, tf, th = motion_target(w, c)
        queries.append(_new_query(
            label=label, seated=seated, root_xy=c.xy, heading=c.heading, future_xy=fut_xy,
            future_heading=fut_heading, target_xy=tx, target_facing=tf, seat_height=th,
            force_search=restart,
        ))
        labels.append(key)
        still_feet.append(seated or label in ("sit_down", "stand_up"))
        seat_transit.append(label in ("sit_down", "stand_up"))
        seated_l.append(seated)
        seat_h.append(th)
        heading_l.append(c.heading)
        root_l.append(c.xy)
    heading = np.array(heading_l, dtype=float)
    root = np.array(root_l, dtype=float).reshape(n, 2)
    states = [w.motion_states[name] for name in names]
    new_states, rots, pz, contacts = _step_motion(w.motion, states, queries, dt)
    w.motion_states.update(zip(names, new_states, strict=True))
    pelvis, rots = compose_poses(rots, pz, root, heading)
    seats = [w.scene.by_name.get(c.assignment.seat) if h is not None and c.assignment is not None
             and c.assignment.seat is not None else None for c, h in zip(chars, seat_h, strict=True)]
    pelvis, rots = seat_pelvis(chars, labels, seated_l, seat_h, pelvis, rots, w.scene.floor_z, seats, w.scene.objects)
    if w.foot_solver is not None and w.feet is not None:
        active = ~np.array(still_feet)
        rots, w.feet = w.foot_solver.apply(pelvis, rots, contacts, w.feet, active=active,
                                           pinned=np.array(seat_transit))
        rots, _ = separate_legs(pelvis, rots, active, np.array([q.label in TOUCHING_ACTIONS for q in queries]))
    rots = hand_targets(w.scene.by_name, chars, pelvis, rots, 1.0 / dt)
    rules = [arm_rules(c) for c in chars]
    rots = arms_clear(w.arm_boxes, pelvis, rots, [r[0] for r in rules], [r[1] for r in rules])
    w.buffers.append(pelvis, rots, labels, contacts, [c.event_id or "" for c in chars])
    for c in chars:
        c.phase_frame += 1


def _step_motion(motion: MotionLayer, states: list[Any], queries: list[MotionQuery],
                 dt: float) -> tuple[list[Any], np.ndarray, np.ndarray, np.ndarray]:
    """One step of the motion layer for every character: new states, local rotations (N,22,3,3),
    animated pelvis heights (N,) and foot contacts (N,2) bool. Batched when the layer has
    ``step_batch`` (poses as arrays) or ``step_many``, with the same result as one by one."""
    n = len(queries)
    if isinstance(motion, BatchedMotionLayer):  # the poses come as arrays (same result as one by one)
        new_states, batch = motion.step_batch(states, queries, dt)
        rots = np.asarray(batch.local_rotations, dtype=float).reshape(n, NUM_JOINTS, 3, 3)
        pz = np.asarray(batch.pelvis, dtype=float).reshape(n, 3)[:, 2]
        contacts = np.asarray(batch.contacts, dtype=bool).reshape(n, 2)
        return new_states, rots, pz, contacts
    step_many = getattr(motion, "step_many", None)
    if step_many is not None:  # a layer may batch characters (same result as one by one)
        new_states, poses = step_many(states, queries, dt)
    else:
        pairs = [motion.step(s, q, dt) for s, q in zip(states, queries, strict=True)]
        new_states, poses = [p[0] for p in pairs], [p[1] for p in pairs]
    rots = np.array([p.local_rotations for p in poses], dtype=float).reshape(n, NUM_JOINTS, 3, 3)
    pz = np.array([p.pelvis[2] for p in poses], dtype=float)
    try:  # the usual case: every pose has its (2,) contact flags
        contacts = np.array([p.contacts for p in poses], dtype=bool).reshape(n, 2)
    except (AttributeError, TypeError, ValueError):
        contacts = _contacts_of(poses)
    return new_states, rots, pz, contacts


def stationary_root(c: CharacterState) -> None:
    """Root xy / heading of a character that is not walking, from its phase and timer: a
    transition in turns the root about the pelvis (xy unchanged) to ``c.act_heading``, then a
    sit-down moves it onto the seat (by ``c.seat_via`` round furniture: ``storyteller.sim.world.legroom``),
    and a stand-up back the same way."""
    a = c.assignment
    if c.phase == "transition_in" and a is not None:
        turn_to = turn_heading(c)
        if c.phase_frame < c.turn_frames:
            u = smoothstep((c.phase_frame + 1) / c.turn_frames)
            c.heading = wrap_angle(c.turn_from + u * wrap_angle(turn_to - c.turn_from))
        else:
            c.heading = c.act_heading
            if a.seat is not None and c.seat_xy is not None:
                u = smoothstep(sit_progress(c))
                c.xy = along_way(c.anchor_xy, c.seat_via, c.seat_xy, u)
                if turn_to != c.act_heading:  # swivelling onto a seat with no back as it sits down
                    c.heading = wrap_angle(turn_to + u * wrap_angle(c.act_heading - turn_to))
    elif c.phase == "transition_out" and c.seated and c.seat_xy is not None:
        u = smoothstep(stand_progress(c))
        via = c.seat_via
        c.xy = c.seat_xy + u * (c.anchor_xy - c.seat_xy) if via is None else along_way(c.anchor_xy, via, c.seat_xy, 1.0 - u)


def motion_target(w: MotionWorld, c: CharacterState) -> tuple[np.ndarray | None, float | None, float | None]:
    """(target xy, target facing, seat height) of the motion query."""
    a = c.assignment
    if a is None or c.phase == "approaching":
        return None, None, None
    if a.seat is not None and c.seat_xy is not None:
        height = a.seat_height
        if height is None:
            obj = w.scene.by_name[a.seat]
            height = obj.z_min - w.scene.floor_z + obj.sit_offset_vertical
        return c.seat_xy, c.act_heading, height
    spec = action_spec(a.action)
    if spec.family == "partner" and a.partners:
        pts = np.array([w.characters[p].xy for p in a.partners if p in w.characters])
        centre = pts.mean(axis=0)
        d = c.xy - centre
        return centre, math.atan2(d[1], d[0]), None
    f = np.asarray(a.facing_xy) if c.act_yaw is None else np.array([math.cos(c.act_yaw), math.sin(c.act_yaw)])
    return c.anchor_xy + OBJECT_REACH * f, c.act_heading + math.pi, None


def _contacts_of(poses: Sequence[Any]) -> np.ndarray:
    """Foot contact flags (N, 2) of poses; a layer without contact flags gives none (False)."""
    n = len(poses)
    flags = [getattr(p, "contacts", None) for p in poses]
    if all(f is not None for f in flags):
        return np.array(flags, dtype=bool).reshape(n, 2)
    contacts = np.zeros((n, 2), dtype=bool)
    for k, f in enumerate(flags):
        if f is not None:
            contacts[k] = f
    return contacts


_QUERY_FIELDS = ("label", "seated", "root_xy", "heading", "future_xy", "future_heading", "target_xy",
                 "target_facing", "seat_height", "force_search")


def _query_factory() -> Callable[..., MotionQuery]:
    """A constructor of ``MotionQuery`` from all its fields (keywords).

    ``MotionQuery`` is a frozen dataclass: its generated ``__init__`` sets each of the ten
    fields through ``object.__setattr__`` (about 3 us per query, 10 queries a frame). As long
    as it stays a plain frozen dataclass (a ``__dict__``, no ``__post_init__``, exactly these
    fields, all set by ``__init__``), filling the instance dict directly builds the same
    object (equal, same ``__dict__``) in a third of the time; otherwise the class itself is
    used.
    """
    if not dataclasses.is_dataclass(MotionQuery):
        return MotionQuery
    plain = (
        "__slots__" not in vars(MotionQuery)
        and not hasattr(MotionQuery, "__post_init__")
        and tuple(f.name for f in dataclasses.fields(MotionQuery)) == _QUERY_FIELDS
        and all(f.init for f in dataclasses.fields(MotionQuery))
        and MotionQuery.__new__ is object.__new__
    )
    if not plain:
        return MotionQuery
    new = object.__new__

    def make(**fields: Any) -> MotionQuery:
        q = new(MotionQuery)
        q.__dict__.update(fields)
        return q

    return make


_new_query = _query_factory()
_DATABASE_KEYS: dict[tuple[str, bool], str] = {}


def _database_key(label: str, seated: bool) -> str:
    """``database_key(label, seated)``, memoised (a pure function of its arguments)."""
    key = _DATABASE_KEYS.get((label, seated))
    if key is None:
        key = _DATABASE_KEYS[(label, seated)] = database_key(label, seated)
    return key
