"""Procedural locomotion: walks at several speeds, curved walks, sharp turns, turns on the
spot, starts and stops, and stepping in place (dance), all with planted feet.

A clip is generated from a root trajectory (speed and turn rate over time). A gait phase
advances with the step rate the speed asks for; step ``k`` swings one foot during phase
``[k - 0.8, k]`` and lands where the root will be half a step later, beside the path. Feet
on the ground keep their toe joint fixed (the heel lifts about it before toe-off), so the
toe speed during contact is exactly zero. A swinging foot rises before it travels and comes
down onto its landing point from above, so a foot near the floor never moves fast along it.
The pelvis rides a share of the rise and fall of the highest the legs can reach (smoothed from
below: lowest just after a landing, highest at mid-stance) and dips further at each double
support (bob), shifting over the stance foot (sway); arms swing against the legs, the chest
twists against the hips, and the body leans into turns. How much of each, as a function of
speed, and the step length at each speed, is ``storyteller.sim.motion.sources.gait_params.FITTED_GAIT``
(fitted to real walks).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import overload

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.clips import FPS, MotionClip
from storyteller.sim.motion.sources.gait_params import FITTED_GAIT, GaitParams
from storyteller.sim.motion.sources.procedural_rig import (
    SHOULDER_HALF_WIDTH,
    STANDING_PELVIS_HEIGHT,
    TOE_HEIGHT,
    BodyTargets,
    pelvis_height_limit,
    solve_body,
)

SWING = 0.8  # swing length in step-phase units (40 % of a gait cycle)
LIFT_S = 0.07  # share of the swing a foot rises before it travels
LAND_S = 0.07  # share of the swing it comes down onto its landing point
GRAVITY = 9.81  # m/s^2
BOB_LEVEL_RADIUS = 9  # frames: about half a step, so the level is the lowest height of each step
STANCE_HALF_WIDTH = 0.10  # lateral distance of a toe from the path, metres
TOE_AHEAD = 0.08  # toe joint ahead of the pelvis when standing, metres
DIP_PHASE = 0.1  # step phase after a landing at which the pelvis is lowest (mid double support)
Profile = Callable[[NDArray[np.float64]], NDArray[np.float64]]


@overload
def step_length(speed: float, params: GaitParams = ...) -> float: ...
@overload
def step_length(speed: NDArray[np.float64], params: GaitParams = ...) -> NDArray[np.float64]: ...
def step_length(speed: float | NDArray[np.float64], params: GaitParams = FITTED_GAIT) -> float | NDArray[np.float64]:
    """Step length (m) for a walking speed (m/s): ``params``' power law of speed, held above
    its shortest step."""
    v = np.maximum(np.asarray(speed, dtype=np.float64), 0.0)
    length = np.maximum(params.step_length_1ms * v**params.step_length_exponent, params.step_length_min)
    return float(length) if np.ndim(speed) == 0 else np.asarray(length)


def smoothstep(x: NDArray[np.float64]) -> NDArray[np.float64]:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def integrate_root(speed: NDArray[np.float64], turn_rate: NDArray[np.float64], dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Root ground points (N,2) and headings (N,) from speed (m/s) and turn rate (rad/s)."""
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (turn_rate[1:] + turn_rate[:-1]) * dt)])
    vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt)])
    return np.stack([x, y], axis=-1), heading


def gait(
    root: NDArray[np.float64], heading: NDArray[np.float64], phase: NDArray[np.float64], dt: float,
    params: GaitParams = FITTED_GAIT,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Footsteps along a root trajectory for a given gait phase (N,), non-decreasing.

    Returns toes (N,2,3) world toe positions, foot yaw (N,2), heel lift (N,2) rad and
    contacts (N,2). Step k (k = 1, 2, ...) moves the right foot for odd k, the left for even k.
    """
    n = len(phase)
    t = np.arange(n) * dt
    lateral = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)
    fwd = np.stack([np.cos(heading), np.sin(heading)], axis=-1)

    def plant(time: float, side: int) -> tuple[NDArray[np.float64], float]:
        i = float(np.clip(time / dt, 0, n - 1))
        i0 = int(np.floor(i))
        i1 = min(i0 + 1, n - 1)
        a = i - i0
        xy = (1 - a) * root[i0] + a * root[i1]
        h = (1 - a) * heading[i0] + a * heading[i1]
        lat = np.array([-np.sin(h), np.cos(h)])
        f = np.array([np.cos(h), np.sin(h)])
        sign = 1.0 if side == 0 else -1.0
        return xy + sign * STANCE_HALF_WIDTH * lat + TOE_AHEAD * f, h

    toes = np.zeros((n, 2, 3))
    yaw = np.zeros((n, 2))
    heel = np.zeros((n, 2))
    contacts = np.ones((n, 2), dtype=bool)
    for side in (0, 1):
        sign = 1.0 if side == 0 else -1.0
        toes[:, side, :2] = root[0] + sign * STANCE_HALF_WIDTH * lateral[0] + TOE_AHEAD * fwd[0]
        yaw[:, side] = heading[0]
    toes[:, :, 2] = TOE_HEIGHT
    last = int(np.floor(phase[-1] + 1e-9))
    prev = {0: (toes[0, 0, :2].copy(), heading[0]), 1: (toes[0, 1, :2].copy(), heading[0])}
    t_of_phase: Callable[[float], float] = (
        (lambda p: float(np.interp(p, phase, t))) if phase[-1] > phase[0] else (lambda p: 0.0))
    for k in range(1, last + 2):
        side = k % 2
        start, end = k - SWING, float(k)
        if start >= phase[-1]:
            break
        land_time = t_of_phase(k + 0.5) if k + 0.5 <= phase[-1] else t[-1]
        land, land_yaw = plant(land_time, side)
        p0, y0 = prev[side]
        dist = float(np.linalg.norm(land - p0))
        lift_angle = float(np.clip(0.55 * dist, 0.0, 0.4))
        swing = (phase > start) & (phase < end)
        after = phase >= end
        s = (phase[swing] - start) / SWING
        u = np.clip((s - LIFT_S) / (1.0 - LIFT_S - LAND_S), 0.0, 1.0)  # travel between lift and landing
        e = (0.5 * u + 0.5 * smoothstep(u))[:, None]  # part linear: a lower top speed than smoothstep's
        toes[swing, side, :2] = p0 + (land - p0) * e
        lift = params.foot_clearance * min(1.0, 0.4 + dist / 0.9)
        toes[swing, side, 2] = TOE_HEIGHT + lift * np.sin(np.pi * s) ** 0.4
        dyaw = (land_yaw - y0 + np.pi) % (2 * np.pi) - np.pi
        yaw[swing, side] = y0 + dyaw * e[:, 0]
        heel[swing, side] = lift_angle * (1 - smoothstep(s / 0.45))
        pre = (phase >= end - 1.3) & (phase <= start)
        heel[pre, side] = lift_angle * smoothstep((phase[pre] - (end - 1.3)) / 0.5)
        contacts[swing, side] = False
        toes[after, side, :2] = land
        yaw[after, side] = land_yaw
        prev[side] = (land, land_yaw)
    return toes, yaw, heel, contacts


def body_from_gait(
    root: NDArray[np.float64],
    heading: NDArray[np.float64],
    phase: NDArray[np.float64],
    speed: NDArray[np.float64],
    dt: float,
    *,
    arm_raise: NDArray[np.float64] | None = None,
    params: GaitParams = FITTED_GAIT,
) -> tuple[BodyTargets, NDArray[np.bool_]]:
    """Full-body targets for a gait; returns (targets, contacts)."""
    n = len(phase)
    p = params
    toes, yaw, heel, contacts = gait(root, heading, phase, dt, p)
    rate = np.gradient(phase) / dt
    moving = np.clip(rate / 1.2, 0.0, 1.0)
    v = np.minimum(speed, 1.8)
    osc = np.sin(np.pi * (phase - 0.1))  # +1 over the left stance foot, -1 over the right
    swing = np.sin(np.pi * (phase - 0.5))
    turn_rate = np.gradient(np.unwrap(heading)) / dt
    lean = -p.turn_lean_gain * np.arctan(speed * turn_rate / GRAVITY)  # roll into the turn
    pelvis = np.zeros((n, 3))
    pelvis[:, 1] = p.sway_amplitude * moving * osc
    pelvis[:, 2] = STANDING_PELVIS_HEIGHT - 0.01
    tilt = np.zeros((n, 3))
    tilt[:, 0] = 0.03 + 0.04 * v
    tilt[:, 1] = p.pelvis_yaw * moving * swing
    tilt[:, 2] = -0.03 * moving * osc + lean
    twist = np.maximum(p.trunk_twist + p.trunk_twist_speed_slope * (v - 1.0), 0.02) * moving
    spine = np.zeros((n, 3))
    spine[:, 0] = 0.02 * v
    spine[:, 1] = -twist * swing
    head = np.zeros((n, 3))
    head[:, 0] = -(tilt[:, 0] + spine[:, 0]) + 0.05
    head[:, 1] = (twist - p.pelvis_yaw * moving) * swing
    head[:, 2] = -0.5 * lean  # the head stays nearer upright than the trunk
    amp = np.maximum(p.arm_swing_1ms + p.arm_swing_speed_slope * (v - 1.0), 0.02) * moving
    hands = np.zeros((n, 2, 3))
    for side, sign in ((0, 1.0), (1, -1.0)):
        fwd = -sign * amp * swing
        hands[:, side, 0] = fwd + 0.02
        hands[:, side, 1] = sign * 0.035
        hands[:, side, 2] = -0.48 + 0.35 * fwd**2 / 0.25
    if arm_raise is not None:
        hands[:, :, 2] += arm_raise[:, None]
        hands[:, :, 0] += 0.4 * arm_raise[:, None]
    pole = np.zeros((n, 2, 3))
    pole[:, 0] = [-0.5, 0.3, -1.0]
    pole[:, 1] = [-0.5, -0.3, -1.0]
    targets = BodyTargets(root, heading, pelvis, tilt, spine, head, toes, yaw, heel, hands, pole)
    # the legs reach lowest in double support and highest at mid-stance; the pelvis follows a
    # share of that rise and fall (bob) above the level it could keep all along
    base = np.minimum(pelvis[:, 2], pelvis_height_limit(targets, reach=0.96))
    level = _smooth_below(base, radius=BOB_LEVEL_RADIUS)
    dip = np.maximum(p.bob_dip_1ms + p.bob_dip_speed_slope * (v - 1.0), 0.0) * moving
    pelvis[:, 2] = level + p.bob_follow * (_smooth_below(base, radius=4) - level) - dip * _dip_shape(phase)
    return targets, contacts


def _dip_shape(phase: NDArray[np.float64]) -> NDArray[np.float64]:
    """1 at the lowest point of each double support (``DIP_PHASE`` after a landing), falling to 0
    at mid-stance: a squared raised cosine, so the valley is narrow and the top of the arc wide
    (the pelvis vaults over the stance leg and drops onto the next one)."""
    c = 0.5 * (1.0 + np.cos(2.0 * np.pi * (phase - DIP_PHASE)))
    out: NDArray[np.float64] = c * c
    return out


def _smooth_below(z: NDArray[np.float64], radius: int) -> NDArray[np.float64]:
    """A smooth curve that never exceeds ``z``: min-filter, then box-average (same radius)."""
    pad = np.pad(z, radius, mode="edge")
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * radius + 1)
    eroded = win.min(axis=1)
    pad2 = np.pad(eroded, radius, mode="edge")
    smooth: NDArray[np.float64] = np.lib.stride_tricks.sliding_window_view(pad2, 2 * radius + 1).mean(axis=1)
    return smooth


def locomotion_clip(
    name: str,
    speed_fn: Profile,
    turn_fn: Profile,
    duration: float,
    *,
    loops: bool = False,
    loop_cycles: int = 2,
    key: str = "walk",
    pad: float = 1.5,
    arm_raise_fn: Profile | None = None,
    params: GaitParams = FITTED_GAIT,
) -> MotionClip:
    """Generate a walking clip from speed (m/s) and turn-rate (rad/s) profiles over time (s).

    Profiles are evaluated on [-pad, duration + pad] so that footsteps before the first
    frame and landings after the last one exist; the clip is the middle part. A looping clip
    uses a constant step rate giving exactly ``loop_cycles`` gait cycles over ``duration``.
    A clip that ends at rest has its phase rescaled so that the last step completes.
    """
    dt = 1.0 / FPS
    frames = round(duration * FPS)
    npad = round(pad * FPS)
    t = (np.arange(frames + 2 * npad, dtype=np.float64) - npad) * dt  # whole numbers: exact
    speed = np.asarray(speed_fn(t), dtype=np.float64)
    turn = np.asarray(turn_fn(t), dtype=np.float64)
    root, heading = integrate_root(speed, turn, dt)
    if loops:
        rate = np.full(len(t), 2.0 * loop_cycles / (frames * dt))
    else:
        activity = np.maximum(smoothstep(speed / 0.15), smoothstep(np.abs(turn) / 0.3))
        rate = np.maximum.reduce([speed / step_length(speed, params), np.abs(turn) / 0.55, 1.7 * activity])
        rate = np.where((speed < 0.01) & (np.abs(turn) < 0.02), 0.0, rate)
    phase = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)])
    if not loops and speed[-1] < 0.01 and phase[-1] > 0.3:
        phase *= max(round(phase[-1]), 1) / phase[-1]
    raise_ = None if arm_raise_fn is None else np.asarray(arm_raise_fn(t), dtype=np.float64)
    targets, contacts = body_from_gait(root, heading, phase, speed, dt, arm_raise=raise_, params=params)
    local, pelvis = solve_body(targets)
    sl = slice(npad, npad + frames)
    # Re-anchor the clip so that it starts at the origin facing +x.
    origin, h0 = root[npad].copy(), heading[npad]
    c, s = np.cos(-h0), np.sin(-h0)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    local = local[sl].copy()
    local[:, 0] = rot @ local[:, 0]
    pel = (pelvis[sl] - np.array([*origin, 0.0])) @ rot.T
    root_xy = (root[sl] - origin) @ rot[:2, :2].T
    return MotionClip(name, key, local, pel, root_xy, heading[sl] - h0, contacts[sl], loops)


def _const(value: float) -> Profile:
    return lambda t: np.full_like(t, value)


def _pulse(rate: float, centre: float, half_width: float) -> Profile:
    """``rate`` while ``|t - centre| < half_width``, else 0 (a turn in place)."""

    def profile(t: NDArray[np.float64]) -> NDArray[np.float64]:
        # a product, not np.where: a negative rate gives -0.0 outside, as before
        inside = (np.abs(t - centre) < half_width).astype(np.float64)  # 1.0 / 0.0, as True / False
        out: NDArray[np.float64] = rate * inside
        return out

    return profile


def _ramp(t0: float, t1: float, a: float, b: float) -> Profile:
    return lambda t: a + (b - a) * smoothstep((t - t0) / (t1 - t0))


def locomotion_clips(params: GaitParams = FITTED_GAIT) -> list[MotionClip]:
    """The default locomotion set (database ``walk``)."""
    clips: list[MotionClip] = []
    for v in (0.6, 1.0, 1.3, 1.7):
        period = 2 * 2 * step_length(v, params) / v
        clips.append(locomotion_clip(f"walk_{v:.1f}", _const(v), _const(0.0), period, loops=True, params=params))
    for radius in (1.0, 2.5):
        for sign, side in ((1.0, "left"), (-1.0, "right")):
            v = 1.0
            period = 2 * 2 * step_length(v, params) / v
            clips.append(locomotion_clip(f"arc_{side}_r{radius}", _const(v), _const(sign * v / radius),
                                         period, loops=True, params=params))
    for angle in (90, 180):
        for sign, side in ((1.0, "left"), (-1.0, "right")):
            a = sign * np.radians(angle)
            clips.append(locomotion_clip(
                f"turn_{side}_{angle}", _const(1.0),
                _pulse(a / 0.9, 1.7, 0.45), 3.4, params=params))
            clips.append(locomotion_clip(
                f"spin_{side}_{angle}", _const(0.0),
                _pulse(a / 1.2, 1.0, 0.6), 2.6, params=params))
    clips.append(locomotion_clip("start", _ramp(0.6, 1.6, 0.0, 1.2), _const(0.0), 3.2, params=params))
    clips.append(locomotion_clip("stop", _ramp(1.0, 2.0, 1.2, 0.0), _const(0.0), 3.0, params=params))
    clips.append(locomotion_clip("start_slow", _ramp(0.5, 1.3, 0.0, 0.7), _const(0.0), 2.8, params=params))
    clips.append(locomotion_clip("stop_slow", _ramp(0.8, 1.6, 0.7, 0.0), _const(0.0), 2.6, params=params))
    return clips


def dance_clip(name: str = "dance_steps", key: str = "dance", cycles: int = 2) -> MotionClip:
    """Side-to-side dance steps with swaying turns and raised, swinging arms (loops)."""
    period = 1.6
    duration = period * cycles

    def speed(t: NDArray[np.float64]) -> NDArray[np.float64]:
        return 0.35 * np.sin(2 * np.pi * t / period)

    def turn(t: NDArray[np.float64]) -> NDArray[np.float64]:
        return 0.9 * np.cos(2 * np.pi * t / period)

    def arms(t: NDArray[np.float64]) -> NDArray[np.float64]:
        return 0.18 + 0.08 * np.sin(4 * np.pi * t / period)

    clip = locomotion_clip(name, speed, turn, duration, loops=True, loop_cycles=2 * cycles, key=key,
                           arm_raise_fn=arms)
    return clip


__all__ = ["SHOULDER_HALF_WIDTH", "dance_clip", "locomotion_clip", "locomotion_clips", "step_length"]
