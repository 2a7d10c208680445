"""A decoded checkpoint checked against the world it is bound to, and for sense.

:func:`check_fits_world`: the same characters, in the same order, everywhere the world keeps
them by name. :func:`check_sense`: values of the right types that no run could have made are
refused: a frame below 0 or after the checkpoint's own, a step index outside the steps taken,
an event id a character, a pending assignment or the world's event book names that the
checkpoint does not hold, a character or event member that is not this run's, a position or
angle that is not finite or lies more than :data:`OUTSIDE_M` outside the scene's floor, a grid
cell off the navigation grid, a seat or used object the scene has no object of.

Runs after :func:`~storyteller.orchestrator.session.snapshot_tree.check_tree` (the fields are of their
types); every refusal is a :class:`~storyteller.orchestrator.session.snapshot_errors.SnapshotError` with
one line.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from storyteller.orchestrator.session.session_types import SessionCheckpoint
from storyteller.orchestrator.session.snapshot_errors import SnapshotError
from storyteller.sim.world.event_book import EventState
from storyteller.sim.world.events import Assignment
from storyteller.sim.world.phases import CharacterState
from storyteller.sim.world.step import World

OUTSIDE_M = 1.0
"""Metres a stored position may lie outside the scene's floor rectangle (a character stands,
walks and sits on the floor; a seat's approach point is within reach of it)."""


def check_fits_world(checkpoint: SessionCheckpoint, world: World) -> None:
    """The checkpoint is of this run's characters: the world's names, in its order, as the keys
    of its per-character state, motion states and track buffers, each state named by its key."""
    names = list(world.characters)
    snap = checkpoint.world
    for what, keys in (
        ("characters", list(snap.characters)),
        ("motion states", list(snap.motion_states)),
        ("track buffers", list(snap.buffers.names)),
    ):
        if keys != names:
            raise SnapshotError(f"the checkpoint's {what} are {keys[:8]}, this run's characters are {names[:8]}")
    for name, state in snap.motion_states.items():
        if type(state) is not type(world.motion_states[name]):
            raise SnapshotError(f"the checkpoint's motion state of {name!r} is a {type(state).__name__[:40]}, this "
                                f"run's motion layer keeps a {type(world.motion_states[name]).__name__}")
    for name, state in snap.characters.items():
        if state.name != name:
            raise SnapshotError(f"the checkpoint's character {name!r} holds the state of {state.name!r}")
    for event_id, event in checkpoint.events.items():
        if event.event_id != event_id:
            raise SnapshotError(f"the checkpoint's event {event_id!r} holds event {event.event_id!r}")


def check_sense(checkpoint: SessionCheckpoint, world: World) -> None:
    """Values of the right types that no run could have made (module doc): frames, step indices,
    event ids, characters, positions, grid cells and object names."""
    snap = checkpoint.world
    frame = snap.frame
    if frame < 0:
        raise SnapshotError(f"the checkpoint's world is at frame {frame} (frames count from 0)")

    def at(what: str, value: int | None, low: int = 0) -> None:
        if value is not None and not low <= value <= frame:
            raise SnapshotError(f"{what} is frame {value}, outside the frames so far [{low}, {frame}]")

    def count(what: str, value: int) -> None:
        if value < 0:
            raise SnapshotError(f"{what} is {value} (a count is 0 or more)")

    for what, value in (("the checkpoint's step count", checkpoint.steps),
                        ("its planning failures in a row", checkpoint.failures_in_a_row),
                        ("its count of event changes", checkpoint.changes),
                        ("its next planning frame", checkpoint.next_plan_frame),
                        ("its track buffers' base frame", snap.buffers.base),
                        ("its track buffers' length", snap.buffers.length)):
        count(what, value)
    if len(checkpoint.outcomes) != len(checkpoint.applied_frames):
        raise SnapshotError(f"the checkpoint has {len(checkpoint.outcomes)} planning outcomes and "
                            f"{len(checkpoint.applied_frames)} frames they were applied at")
    for (index, _), applied in zip(checkpoint.outcomes, checkpoint.applied_frames, strict=True):
        _step_index(f"an outcome's step {index}", index, checkpoint.steps)
        at(f"the frame step {index} was applied at", applied)
    for request in (checkpoint.in_flight, *checkpoint.more_in_flight):
        if request is not None:
            _step_index(f"the step in flight {request.index}", request.index, checkpoint.steps)
            at(f"the request frame of step {request.index}", request.frame)
    names = set(world.characters)
    for event_id, event in checkpoint.events.items():
        _step_index(f"event {event_id!r}'s step {event.index}", event.index, checkpoint.steps)
        at(f"the request frame of event {event_id!r}", event.requested_frame)
        at(f"the frame event {event_id!r} was applied at", event.applied_frame, event.requested_frame)
        at(f"the frame event {event_id!r} finished at", event.finished_frame, event.applied_frame)
        _members(f"event {event_id!r}", event.characters, names)
    for event_id, state in snap.events.items():
        if event_id not in checkpoint.events or state.event.event_id != event_id:
            raise SnapshotError(f"the checkpoint's world holds event {event_id!r}, which its story does not")
        _members(f"event {event_id!r}", (*state.members, *(a.character for a in state.event.assignments)), names)
        for assignment in state.event.assignments:
            _assignment(f"event {event_id!r}", assignment, world)
    for name, character in snap.characters.items():
        _character(name, character, snap.events, world)


def _step_index(what: str, index: int, steps: int) -> None:
    if not 0 <= index < steps:
        raise SnapshotError(f"{what} is not one of the {steps} steps taken")


def _members(what: str, members: Sequence[str], names: set[str]) -> None:
    strangers = sorted(set(members) - names)
    if strangers:
        raise SnapshotError(f"{what} names {strangers[:4]}, not characters of this run ({sorted(names)[:8]})")


def _character(name: str, character: CharacterState, events: dict[str, EventState], world: World) -> None:
    """One character's state: its event and pending event held, counts, angles, positions, cells."""
    for event_id in (character.event_id, character.pending[0] if character.pending is not None else None):
        if event_id is not None and event_id not in events:
            raise SnapshotError(f"the checkpoint's character {name!r} takes part in event {event_id!r}, "
                                "which its world does not hold")
    for field_name, count in (("phase_frame", character.phase_frame), ("turn_frames", character.turn_frames),
                              ("stalled_frames", character.stalled_frames), ("replans", character.replans)):
        if count < 0:
            raise SnapshotError(f"the checkpoint's character {name!r} has {field_name} {count}")
    for field_name, angle in (("heading", character.heading), ("turn_from", character.turn_from),
                              ("act_yaw", character.act_yaw)):
        if angle is not None and not np.isfinite(angle):
            raise SnapshotError(f"the checkpoint's character {name!r} has {field_name} {angle}, not a finite angle")
    where = f"the checkpoint's character {name!r}"
    for field_name, point in (("xy", character.xy), ("anchor_xy", character.anchor_xy), ("seat_xy", character.seat_xy)):
        _point(f"{where}'s {field_name}", point, world)
    for field_name, cell in (("anchor_cell", character.anchor_cell), ("goal_cell", character.goal_cell)):
        _cell(f"{where}'s {field_name}", cell, world)
    for target in (character.target, character.pending[2] if character.pending is not None else None):
        if target is not None:
            _point(f"{where}'s stand target", target.xy, world)
            _cell(f"{where}'s stand target cell", target.cell, world)
    for assignment in (character.assignment, character.pending[1] if character.pending is not None else None):
        if assignment is not None:
            _assignment(where, assignment, world)


def _assignment(where: str, assignment: Assignment, world: World) -> None:
    _point(f"{where}: {assignment.character!r}'s target", assignment.target_xy, world)
    for field_name, obj in (("seat", assignment.seat), ("focus", assignment.focus)):
        if obj is not None and obj not in world.scene.by_name:
            raise SnapshotError(f"{where}: {assignment.character!r}'s {field_name} is {str(obj)[:60]!r}, "
                                f"which scene {world.scene.name!r} has no object of")


def _point(what: str, value: npt.ArrayLike | None, world: World) -> None:
    """``value`` (None, or an (x, y) point) is finite and within :data:`OUTSIDE_M` of the floor."""
    if value is None:
        return
    xy = np.asarray(value, dtype=float)
    low = np.asarray(world.scene.bounds_min, dtype=float) - OUTSIDE_M
    high = np.asarray(world.scene.bounds_max, dtype=float) + OUTSIDE_M
    if xy.shape != (2,) or not np.isfinite(xy).all() or (xy < low).any() or (xy > high).any():
        shown = ", ".join(f"{v:.6g}" for v in xy.ravel()[:2])
        raise SnapshotError(f"{what} is ({shown}), not a point of the scene (x {low[0]:.6g}..{high[0]:.6g}, "
                            f"y {low[1]:.6g}..{high[1]:.6g})")


def _cell(what: str, cell: tuple[int, int] | None, world: World) -> None:
    if cell is None:
        return
    rows, cols = world.grid.free.shape[:2]
    if not (0 <= cell[0] < rows and 0 <= cell[1] < cols):
        raise SnapshotError(f"{what} is {cell}, off the navigation grid ({rows} x {cols} cells)")
