"""Per-character phases and their timing: idle, approaching, transition_in, interacting, transition_out.

A character's life in the world (``storyteller.sim.world.step``) is a loop through five phases:

- ``idle``: nothing to do, or waiting (``waiting=True``) at its target for the other members
  of its event to arrive; a seated character can be idle on its seat;
- ``approaching``: walking along the cooperative plan to its target cell;
- ``transition_in``: turning on the spot (the root turns about the pelvis, which stays put)
  to the facing it acts with (``act_heading``: its partners, the object it uses or the
  planner's facing, chosen where it stands: ``storyteller.sim.world.facing``), then (when sitting)
  sitting down, the pelvis moving from the approach cell to the seat point;
- ``interacting``: acting; a completing action lasts its ``ActionSpec.duration_s``, a looping
  action lasts until interrupted;
- ``transition_out``: leaving the action: standing up when seated (the pelvis back to the
  approach cell), else a short blend back to standing.

This module is pure bookkeeping on plain data: ``CharacterState`` (a dataclass that copies
with ``copy.deepcopy``) and functions giving phase lengths in frames and the motion database
key each phase animates with. Angles are radians (world yaw from +x toward +y); times are
frames at ``FPS``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from storyteller.sim.motion.action_labels import action_spec
from storyteller.sim.world.events import Assignment

FPS = 30
Phase = Literal["idle", "approaching", "transition_in", "interacting", "transition_out"]
TargetFallback = Literal["target_blocked", "no_straight_approach", "no_approach_point", "goal_cell_taken",
                         "target_occupied", "stopped_near", "out_of_reach"]
"""Why a character stands on a cell centre instead of the exact point it was sent to:
``target_blocked``: a body at the target would overlap furniture or leave the floor;
``no_straight_approach``: no free cell nearby has a straight, furniture-free walk to the target;
``no_approach_point``: no exact standing point by the seat is reachable (the seat's approach
cell is used); ``goal_cell_taken``: someone else held the goal cell, the walker stopped on the
neighbouring cell the planner chose; ``target_occupied``: another body stayed too close to the
straight walk onto the point for ``WorldConfig.exact_patience_s``, the walker stopped on its
goal cell's centre; ``stopped_near``: a standing walker within ``WorldConfig.near_enough_m`` of its
target got no closer for ``WorldConfig.near_patience_s`` (bodies standing still in the way), and
does its action where it stands rather than failing the event as stuck; ``out_of_reach``: the
point (or where a stall rule would have stopped the walker) is out of reach of the object the
action uses (``storyteller.sim.world.facing.REACH_M``): the walker goes to a free point within reach
instead."""
PHASES: tuple[Phase, ...] = ("idle", "approaching", "transition_in", "interacting", "transition_out")

TURN_SPEED = math.pi  # rad/s when turning on the spot before acting
MIN_TURN_S = 0.3  # a transition in always takes at least this long (blend into the action)
STAND_OUT_S = 0.3  # leaving a standing action
INFINITE = -1  # phase length of looping actions and of open-ended idling


@dataclass(frozen=True)
class StandTarget:
    """Where an assignment's walker ends (see ``sim.world.navigation.stand_target``).

    ``cell``: the grid goal; ``xy``: the exact pelvis ground point (metres) it stands on when
    the transition in starts: the assignment's target (standing), the seat's approach point
    (seated), or ``cell``'s centre (``fallback`` says why; ``message`` is one sentence).
    ``off_grid``: ``xy`` is not ``cell``'s centre (the walker takes a straight leg to it).
    """

    cell: tuple[int, int]
    xy: tuple[float, float]
    off_grid: bool = False
    fallback: TargetFallback | None = None
    message: str = ""


@dataclass
class CharacterState:
    """Everything the world knows about one character (plain data).

    ``xy``: pelvis ground point (metres) at the last produced frame; ``heading``: facing yaw;
    ``anchor_xy``: the exact point the character stands on when not walking (an assignment's
    target, a seat's approach point, or a nav-cell centre); ``anchor_cell``: the free cell a
    walker leaving ``anchor_xy`` walks to first (the cell it stands on when on a centre);
    ``target``: where the current assignment's walk ends (``StandTarget``);
    ``phase_frame``: frames spent in the current phase;
    ``phase_length``: frames the phase lasts (``INFINITE``: until something happens);
    ``turn_frames``: the part of a transition in spent turning; ``action_done``: the action of
    the current event is finished (or, looping, under way); ``pending``: the assignment to
    start (event id, assignment, stand target) once the current transition out ends;
    ``best_distance`` / ``stalled_frames``: the walker's closest approach to its goal and the
    frames since (the stuck check), measured around stationary bodies while ``rerouted`` (the
    navigator's detour; entering it starts the count afresh); ``act_yaw``: the yaw it acts
    facing, chosen when the transition in starts (None: the assignment's ``facing_xy``);
    ``replans``: standing points within reach chosen again for the current assignment after a
    stall (``out_of_reach``).
    """

    name: str
    xy: np.ndarray
    heading: float
    phase: Phase = "idle"
    phase_frame: int = 0
    phase_length: int = INFINITE
    turn_frames: int = 0
    turn_from: float = 0.0
    event_id: str | None = None
    assignment: Assignment | None = None
    pending: tuple[str, Assignment, StandTarget] | None = None
    waiting: bool = False
    seated: bool = False
    seat_xy: np.ndarray | None = None
    anchor_xy: np.ndarray = field(default_factory=lambda: np.zeros(2))
    anchor_cell: tuple[int, int] = (0, 0)
    goal_cell: tuple[int, int] | None = None
    target: StandTarget | None = None
    walker: bool = True
    action_done: bool = False
    best_distance: float = math.inf
    stalled_frames: int = 0
    rerouted: bool = False
    motion_key: str = "idle"
    act_yaw: float | None = None
    replans: int = 0
    seat_via: np.ndarray | None = None
    """The corner of the way onto the seat and back (``storyteller.sim.world.legroom.sit_via``; None: straight)."""

    def enter(self, phase: Phase, length: int = INFINITE) -> None:
        """Switch to ``phase`` for ``length`` frames (``INFINITE``: open-ended)."""
        self.phase = phase
        self.phase_frame = 0
        self.phase_length = length

    @property
    def phase_over(self) -> bool:
        return self.phase_length != INFINITE and self.phase_frame >= self.phase_length

    @property
    def act_heading(self) -> float:
        """Yaw the character acts with: ``act_yaw``, else its assignment's facing (0 without one)."""
        if self.act_yaw is not None:
            return self.act_yaw
        return self.assignment.facing_angle if self.assignment is not None else 0.0

    @property
    def loops(self) -> bool:
        """Whether the current assignment's action is a looping one."""
        return self.assignment is not None and action_spec(self.assignment.action).loops


def seconds_to_frames(seconds: float, fps: int = FPS) -> int:
    return max(1, round(seconds * fps))


def wrap_angle(a: float) -> float:
    """Angle wrapped to [-pi, pi) (works on numpy arrays too)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def turn_frames(from_heading: float, to_heading: float, fps: int = FPS) -> int:
    """Frames to turn on the spot (at ``TURN_SPEED``, at least ``MIN_TURN_S``)."""
    angle = abs(float(wrap_angle(to_heading - from_heading)))
    return seconds_to_frames(max(MIN_TURN_S, angle / TURN_SPEED), fps)


def sit_heading(assignment: Assignment) -> float:
    """Heading while sitting: the assignment's facing (the seat's front)."""
    return assignment.facing_angle


def turn_heading(c: CharacterState) -> float:
    """The heading ``c`` turns to on the spot before it acts: ``act_heading``, but the planner's
    facing for a seat (a body sitting turned on a seat with no back, ``storyteller.sim.world.legroom``,
    swivels the rest of the way while it sits down, so the transition takes as long as planned)."""
    a = c.assignment
    if a is not None and a.seat is not None:
        return a.facing_angle
    return c.act_heading


def transition_in_frames(assignment: Assignment, heading: float, fps: int = FPS,
                         act_heading: float | None = None) -> tuple[int, int]:
    """(turn frames, total frames) of the transition into ``assignment``'s action, turning from
    ``heading`` to ``act_heading`` (default: the assignment's facing)."""
    turn = turn_frames(heading, assignment.facing_angle if act_heading is None else act_heading, fps)
    total = turn + (seconds_to_frames(action_spec("sit_down").duration_s, fps) if assignment.seat else 0)
    return turn, total


def interaction_frames(assignment: Assignment, fps: int = FPS) -> int:
    """Frames the action lasts (``INFINITE`` for looping actions)."""
    spec = action_spec(assignment.action)
    return INFINITE if spec.loops else seconds_to_frames(spec.duration_s, fps)


def transition_out_frames(seated: bool, fps: int = FPS) -> int:
    return seconds_to_frames(action_spec("stand_up").duration_s if seated else STAND_OUT_S, fps)


def smoothstep(u: float) -> float:
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


def phase_motion(state: CharacterState, moving: bool) -> tuple[str, bool]:
    """(action label, seated) that animates ``state`` this frame.

    ``moving``: the character's root moved this frame along its walking plan (idle walkers
    stepping aside walk too; a walker waiting for others to pass stands). ``database_key(*phase_motion(...))`` names the motion database.
    """
    a = state.assignment
    if state.phase in ("approaching", "idle") and moving:
        return "walk", False
    if state.phase in ("approaching", "idle"):
        return "idle", state.seated
    if state.phase == "transition_in":
        if a is not None and a.seat is not None and state.phase_frame >= state.turn_frames:
            return "sit_down", False
        return "idle", False
    if state.phase == "interacting":
        assert a is not None
        return a.action, a.seat is not None
    return ("stand_up", False) if state.seated else ("idle", False)


def available(state: CharacterState, event_active: bool) -> bool:
    """Whether the narrator may give the character a new event.

    Free when it belongs to no active event, or when it is acting a looping action (which a
    new assignment interrupts).
    """
    if not event_active:
        return True
    return state.phase == "interacting" and state.loops
