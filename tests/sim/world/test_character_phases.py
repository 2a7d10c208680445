"""Phase timing and the motion label of every phase (storyteller.sim.world.phases)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.motion.action_labels import database_key
from storyteller.sim.world.events import Assignment
from storyteller.sim.world.phases import (
    INFINITE,
    CharacterState,
    Phase,
    available,
    interaction_frames,
    phase_motion,
    smoothstep,
    transition_in_frames,
    transition_out_frames,
    turn_frames,
    wrap_angle,
)


def _assign(action: str = "drink", seat: str | None = None, facing: tuple[float, float] = (1.0, 0.0)) -> Assignment:
    return Assignment(character="a", action=action, target_xy=(1.0, 1.0), facing_xy=facing, seat=seat)


def _state(
    *, phase: Phase = "idle", assignment: Assignment | None = None, seated: bool = False, turn_frames: int = 0,
    phase_frame: int = 0,
) -> CharacterState:
    return CharacterState(name="a", xy=np.zeros(2), heading=0.0, phase=phase, assignment=assignment, seated=seated,
                          turn_frames=turn_frames, phase_frame=phase_frame)


@settings(max_examples=60, deadline=None)
@given(st.floats(-50.0, 50.0, allow_nan=False))
def test_wrap_angle_lands_in_half_open_range_and_keeps_direction(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_turning_takes_at_least_the_minimum_and_half_a_second_per_quarter_turn() -> None:
    assert turn_frames(0.0, 0.0) == 9  # 0.3 s blend even without turning
    assert turn_frames(0.0, math.pi / 2) == 15  # pi rad/s
    assert turn_frames(0.0, math.pi) == 30
    assert turn_frames(3.0, -3.0) == turn_frames(0.0, 2 * math.pi - 6.0)  # shortest way round


def test_transition_in_adds_sitting_down_when_seated() -> None:
    turn, total = transition_in_frames(_assign(), heading=0.0)
    assert (turn, total) == (9, 9)
    turn, total = transition_in_frames(_assign(seat="chair_1", facing=(-1.0, 0.0)), heading=0.0)
    assert turn == 30 and total == 30 + 60  # 180 degrees, then sit_down's 2.0 s


def test_completing_actions_last_their_duration_and_looping_ones_forever() -> None:
    assert interaction_frames(_assign("drink")) == 120
    assert interaction_frames(_assign("use_coffee_maker")) == 180
    assert interaction_frames(_assign("chat")) == INFINITE
    assert transition_out_frames(seated=True) == 54 and transition_out_frames(seated=False) == 9


def test_phase_over_counts_frames_and_never_ends_open_phases() -> None:
    s = _state()
    s.enter("interacting", 3)
    assert not s.phase_over
    s.phase_frame = 3
    assert s.phase_over
    s.enter("interacting", INFINITE)
    s.phase_frame = 10_000
    assert not s.phase_over


def test_every_phase_maps_to_an_existing_motion_database() -> None:
    seated = _assign("drink", seat="chair_1")
    cases = [
        (_state(phase="approaching"), True, ("walk", False)),
        (_state(phase="approaching"), False, ("idle", False)),
        (_state(phase="idle"), True, ("walk", False)),
        (_state(phase="idle", seated=True), False, ("idle", True)),
        (_state(phase="transition_in", assignment=seated, turn_frames=5, phase_frame=2), False, ("idle", False)),
        (_state(phase="transition_in", assignment=seated, turn_frames=5, phase_frame=5), False, ("sit_down", False)),
        (_state(phase="interacting", assignment=seated), False, ("drink", True)),
        (_state(phase="interacting", assignment=_assign("chat")), False, ("chat", False)),
        (_state(phase="transition_out", seated=True), False, ("stand_up", False)),
        (_state(phase="transition_out"), False, ("idle", False)),
    ]
    for state, moving, expected in cases:
        assert phase_motion(state, moving) == expected, state.phase
        database_key(*expected)  # raises for unknown keys
    assert database_key("idle", True) == "sit_idle"


def test_available_only_outside_events_or_while_looping() -> None:
    assert available(_state(), event_active=False)
    assert not available(_state(phase="approaching"), event_active=True)
    assert not available(_state(phase="interacting", assignment=_assign("drink")), event_active=True)
    assert available(_state(phase="interacting", assignment=_assign("chat")), event_active=True)


def test_smoothstep_is_monotone_and_clamped() -> None:
    u = np.linspace(-0.5, 1.5, 41)
    v = np.array([smoothstep(float(x)) for x in u])
    assert v[0] == 0.0 and v[-1] == 1.0
    assert np.all(np.diff(v) >= 0.0)
