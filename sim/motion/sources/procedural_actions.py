"""Procedural clips for idle, sitting, in-place and partner actions.

Each clip keeps both feet planted (toe joints fixed, zero foot velocity) and moves the
pelvis, spine, head and wrists along keyframed or periodic targets; wrists are reached with
two-bone IK. Hand targets are written in the character frame (x forward, y left, z up from
the floor) and converted to offsets from an estimate of the shoulder. Looping clips are
periodic (the last frame flows into the first); completing clips start and end in the rest
pose of their posture (standing or seated).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.action_labels import ActionSpec, action_spec, database_key
from storyteller.sim.motion.clips import FPS, MotionClip
from storyteller.sim.motion.sources.procedural_locomotion import TOE_AHEAD, smoothstep
from storyteller.sim.motion.sources.procedural_rig import (
    SHOULDER_ABOVE_PELVIS,
    SHOULDER_HALF_WIDTH,
    STANDING_PELVIS_HEIGHT,
    TOE_HEIGHT,
    BodyTargets,
    pelvis_height_limit,
    solve_body,
)

STAND_Z = STANDING_PELVIS_HEIGHT - 0.01
SEAT_PELVIS_ABOVE_SEAT = 0.09  # pelvis joint above the seat surface, metres
SIT_BACK = 0.33  # how far the pelvis moves back from the standing spot to the seat, metres
FEET_X_SEATED = 0.46  # toes ahead of the seated pelvis, metres
SEAT_HEIGHTS = (0.40, 0.46, 0.52)
PARTNER_DISTANCE = {"handshake": 0.95, "hug": 0.5, "dance": 0.9}
DEFAULT_PARTNER_DISTANCE = 1.1
OBJECT_DISTANCE = 0.55


def _keys(t: NDArray[np.float64], times: list[float], values: Sequence[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Smoothstep interpolation between keyframes; holds the ends. Returns (F, D)."""
    v = np.asarray(values, dtype=np.float64)
    out = np.empty((len(t), v.shape[1]))
    for d in range(v.shape[1]):
        out[:, d] = v[0, d]
        for k in range(len(times) - 1):
            a = smoothstep((t - times[k]) / max(times[k + 1] - times[k], 1e-6))
            seg = (t >= times[k]) & (t <= times[k + 1])
            out[seg, d] = v[k, d] + (v[k + 1, d] - v[k, d]) * a[seg]
        out[t > times[-1], d] = v[-1, d]
    return out


class _Body:
    """Mutable per-frame target arrays for one clip (character frame, root at the origin)."""

    def __init__(self, t: NDArray[np.float64], seated: bool, seat_height: float) -> None:
        n = len(t)
        self.t = t
        self.seated = seated
        self.root_xy = np.zeros((n, 2))
        self.heading = np.zeros(n)
        self.pelvis = np.zeros((n, 3))
        self.pelvis[:, 2] = seat_height + SEAT_PELVIS_ABOVE_SEAT if seated else STAND_Z
        self.tilt = np.zeros((n, 3))
        self.spine = np.zeros((n, 3))
        self.head = np.zeros((n, 3))
        self.toes = np.zeros((n, 2, 3))
        feet_x = FEET_X_SEATED if seated else TOE_AHEAD
        self.toes[:, 0] = [feet_x, 0.11, TOE_HEIGHT]
        self.toes[:, 1] = [feet_x, -0.11, TOE_HEIGHT]
        self.foot_yaw = np.zeros((n, 2))
        self.foot_yaw[:, 0], self.foot_yaw[:, 1] = 0.08, -0.08
        self.heel = np.zeros((n, 2))
        self.hands = np.zeros((n, 2, 3))
        for side in (0, 1):
            self.hands[:, side] = self.rest_hand(side)
        self.pole = np.zeros((n, 2, 3))
        self.pole[:, 0] = [-0.6, 0.35, -1.0]
        self.pole[:, 1] = [-0.6, -0.35, -1.0]

    def rest_hand(self, side: int) -> NDArray[np.float64]:
        """Wrist rest position (character frame): hanging by the side, or on the thigh."""
        s = 1.0 if side == 0 else -1.0
        if self.seated:
            return np.array([0.24, s * 0.13, float(self.pelvis[0, 2]) + 0.06])
        return np.array([0.02, s * 0.22, STAND_Z - 0.03])

    def anchor(self, name: str, side: int, height: float = 1.0) -> NDArray[np.float64]:
        """Named wrist positions (character frame) relative to the current posture."""
        s = 1.0 if side == 0 else -1.0
        p = float(self.pelvis[0, 2])
        table = height if not self.seated else p + 0.25
        return {
            "mouth": np.array([0.16, s * 0.04, p + 0.47]),
            "chest": np.array([0.30, s * 0.08, p + 0.22]),
            "type": np.array([0.40, s * 0.14, table + 0.04]),
            "reach": np.array([0.50, s * 0.15, height + 0.03]),
            "wave": np.array([0.12, s * 0.40, p + 0.74]),
            "talk": np.array([0.28, s * 0.16, p + 0.12]),
            "clasp": np.array([0.20, s * 0.03, p - 0.02]),
            "shake": np.array([0.46, -0.04, p + 0.06]),
            "hug": np.array([0.30, -s * 0.16, p + 0.38]),
            "tray": np.array([0.34, s * 0.16, p + 0.10]),
        }[name]

    def shoulders(self) -> NDArray[np.float64]:
        """Estimated shoulder positions (F,2,3) in the character frame."""
        pitch = self.tilt[:, 0] + self.spine[:, 0]
        sh = np.zeros((len(self.t), 2, 3))
        for side, s in ((0, 1.0), (1, -1.0)):
            sh[:, side, 0] = self.pelvis[:, 0] + SHOULDER_ABOVE_PELVIS * np.sin(pitch)
            sh[:, side, 1] = self.pelvis[:, 1] + s * SHOULDER_HALF_WIDTH
            sh[:, side, 2] = self.pelvis[:, 2] + SHOULDER_ABOVE_PELVIS * np.cos(pitch)
        return sh

    def targets(self) -> BodyTargets:
        toes_world = self.toes.copy()
        return BodyTargets(self.root_xy, self.heading, self.pelvis, self.tilt, self.spine, self.head,
                           toes_world, self.foot_yaw, self.heel, self.hands - self.shoulders(), self.pole)

    def solve(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t = self.targets()
        limit = pelvis_height_limit(t)
        self.pelvis[:, 2] = np.minimum(self.pelvis[:, 2], limit)
        return solve_body(self.targets())


def _breathing(body: _Body, period: float) -> None:
    w = 2 * np.pi * body.t / period
    body.spine[:, 0] += 0.015 * np.sin(w)
    body.head[:, 0] -= 0.01 * np.sin(w)
    if not body.seated:
        body.pelvis[:, 1] += 0.018 * np.sin(w / 2)
        body.tilt[:, 2] += 0.02 * np.sin(w / 2)


def _loop_period(duration: float, cycles: int) -> float:
    return duration / cycles


def _to_mouth(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """``to_mouth``: the right hand to the mouth and back; ``to_mouth_both``: both hands held
    at the chest, each in turn to the mouth."""
    t, g, hands = body.t, spec.gesture, body.hands
    sides = (1,) if g == "to_mouth" else (1, 0)
    span = duration / len(sides)
    if g == "to_mouth_both":
        for side in (0, 1):
            hands[:, side] = body.anchor("chest", side) * [1, 0.5, 1]
    for i, side in enumerate(sides):
        t0 = i * span
        hold = body.anchor("chest", side) * [1, 0.5, 1] if g == "to_mouth_both" else rest[side]
        k = _keys(t, [t0, t0 + 0.25 * span, t0 + 0.45 * span, t0 + 0.65 * span, t0 + span],
                  [hold, body.anchor("mouth", side), body.anchor("mouth", side), hold, hold])
        active = (t >= t0) & (t <= t0 + span)
        hands[active, side] = k[active]
        body.head[active, 0] += -0.15 * np.sin(np.pi * (t[active] - t0) / span)
    if g == "to_mouth_both":
        hands[:, :, 2] = np.maximum(hands[:, :, 2], body.anchor("chest", 0)[2] - 0.1)


def _hold_chest(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """Both hands at the chest, the right one moving a little (scrolling, turning pages); head
    and spine bent."""
    t, hands = body.t, body.hands
    for side in (0, 1):
        hands[:, side] = body.anchor("chest", side) + np.array([0, 0, 0.02]) * np.sin(2 * np.pi * t / duration)[:, None]
    hands[:, 1, 0] += 0.015 * np.sin(8 * np.pi * t / duration)  # thumb scrolling / page turning
    body.head[:, 0] += 0.45
    body.spine[:, 0] += 0.05


def _typing(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """Both hands at the keyboard anchor at the spec's reach height, tapping and shifting."""
    t, hands = body.t, body.hands
    for side in (0, 1):
        hands[:, side] = body.anchor("type", side, spec.reach_height)
        hands[:, side, 2] += 0.012 * np.abs(np.sin(2 * np.pi * 6 * t / duration + side * 1.3))
        hands[:, side, 1] += 0.02 * np.sin(2 * np.pi * 2 * t / duration + side)
    body.head[:, 0] += 0.25
    body.spine[:, 0] += 0.12


def _reach(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """The right hand from rest (``carry``: both hands from the tray) to the reach anchor at the
    spec's reach height, held, and back; ``wipe``, ``write`` and ``reach`` add their strokes
    while held, ``reach_low`` lowers the pelvis."""
    t, g, hands = body.t, spec.gesture, body.hands
    h = spec.reach_height
    side = 1
    if g == "reach_low":
        body.pelvis[:, 2] -= 0.12 * np.sin(np.pi * t / duration) ** 2
        body.spine[:, 0] += 0.6 * np.sin(np.pi * t / duration) ** 2
    target = body.anchor("tray" if g == "carry" else "reach", side, h)
    start = body.anchor("tray", side) if g == "carry" else rest[side]
    k = _keys(t, [0, 0.3 * duration, 0.7 * duration, duration], [start, target, target, rest[side]])
    hands[:, side] = k
    if g == "carry":
        for s2 in (0, 1):
            hands[:, s2] = _keys(t, [0, 0.35 * duration, 0.6 * duration, duration],
                                 [body.anchor("tray", s2), body.anchor("reach", s2, h),
                                  body.anchor("reach", s2, h), rest[s2]])
    mid = (t > 0.3 * duration) & (t < 0.7 * duration)
    u = (t[mid] - 0.3 * duration) / (0.4 * duration)
    if g == "wipe":
        hands[mid, side, 0] += 0.08 * np.sin(6 * np.pi * u)
        hands[mid, side, 1] += 0.12 * np.sin(3 * np.pi * u)
    elif g == "write":
        hands[mid, side, 1] += (0.15 * u - 0.07) * np.sin(np.pi * u)
        hands[mid, side, 2] += 0.03 * np.sin(10 * np.pi * u)
    elif g == "reach":
        hands[mid, side, 0] += 0.03 * np.sin(4 * np.pi * u)
    body.head[:, 0] += 0.25 * np.sin(np.pi * t / duration) * (1.0 if h < 1.2 else -0.5)
    body.spine[:, 0] += (0.25 if h < 0.95 else 0.05) * np.sin(np.pi * t / duration) ** 2


def _held_hand(body: _Body, duration: float, rest: list[NDArray[np.float64]], anchor: str, side: int,
               until: tuple[float, float], *, axis: int, amplitude: float, hz: float) -> NDArray[np.float64]:
    """One hand (``side``) raised to ``anchor`` by 0.3 of ``duration``, held there until
    ``until[0]`` of it (``until[1]``: that end less 0.3, so the hold's span is written as it
    always was) with an oscillation of ``amplitude`` metres at ``hz`` along ``axis`` (faded in
    and out over the hold), and back to rest; set in ``body.hands`` and returned."""
    t = body.t
    k = _keys(t, [0, 0.3 * duration, until[0] * duration, duration],
              [rest[side], body.anchor(anchor, side), body.anchor(anchor, side), rest[side]])
    mid = (t > 0.3 * duration) & (t < until[0] * duration)
    env = np.sin(np.pi * (t[mid] - 0.3 * duration) / (until[1] * duration))
    k[mid, axis] += amplitude * env * np.sin(2 * np.pi * hz * (t[mid] - 0.3 * duration))
    body.hands[:, side] = k
    return k


def _wave(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """The right hand raised to the wave anchor and waved; the elbow pole follows as it rises."""
    side = 1
    k = _held_hand(body, duration, rest, "wave", side, (0.7, 0.4), axis=1, amplitude=0.09, hz=1.8)
    raised = np.clip((k[:, 2] - rest[side][2]) / 0.5, 0, 1)[:, None]
    body.pole[:, side] = (1 - raised) * body.pole[:, side] + raised * np.array([0.0, -1.0, -0.6])


def _talk_or_listen(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """``talk``: both hands gesturing in two loops, the head nodding and turning; ``listen``:
    hands clasped when standing, small nods."""
    t, g, hands = body.t, spec.gesture, body.hands
    p = _loop_period(duration, 2)
    if g == "talk":
        for side in (0, 1):
            base = _keys(t % p, [0, 0.3 * p, 0.7 * p, p],
                         [rest[side], body.anchor("talk", side), body.anchor("talk", side), rest[side]])
            base[:, 0] += 0.05 * np.sin(2 * np.pi * 3 * t / p + side * 2)
            base[:, 2] += 0.04 * np.sin(2 * np.pi * 2 * t / p + side)
            weight = 0.5 + 0.5 * np.sin(2 * np.pi * t / duration + side * np.pi)
            hands[:, side] = rest[side] + (base - rest[side]) * weight[:, None]
        body.head[:, 0] += 0.06 * np.sin(2 * np.pi * 3 * t / duration)
        body.head[:, 1] += 0.12 * np.sin(2 * np.pi * t / duration)
    else:
        if not body.seated:
            for side in (0, 1):
                hands[:, side] = body.anchor("clasp", side)
        body.head[:, 0] += 0.05 + 0.06 * np.maximum(np.sin(2 * np.pi * 2 * t / duration), 0) ** 4


def _handshake(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """The right hand to the shake anchor, pumped, and back."""
    _held_hand(body, duration, rest, "shake", 1, (0.75, 0.45), axis=2, amplitude=0.04, hz=2.5)
    body.spine[:, 0] += 0.08 * np.sin(np.pi * body.t / duration)


def _hug(body: _Body, spec: ActionSpec, duration: float, rest: list[NDArray[np.float64]]) -> None:
    """Both hands to the hug anchors and back, elbows out; the head turned."""
    t, hands = body.t, body.hands
    for side in (0, 1):
        hands[:, side] = _keys(t, [0, 0.3 * duration, 0.75 * duration, duration],
                               [rest[side], body.anchor("hug", side), body.anchor("hug", side), rest[side]])
        body.pole[:, side] = [-0.2, 1.0 if side == 0 else -1.0, -0.3]
    body.spine[:, 0] += 0.12 * np.sin(np.pi * t / duration)
    body.head[:, 1] += 0.35 * np.sin(np.pi * t / duration)


_GESTURES: dict[str, Callable[[_Body, ActionSpec, float, list[NDArray[np.float64]]], None]] = {
    "to_mouth": _to_mouth,
    "to_mouth_both": _to_mouth,
    "hold_chest": _hold_chest,
    "type": _typing,
    "reach": _reach,
    "reach_low": _reach,
    "wipe": _reach,
    "write": _reach,
    "carry": _reach,
    "wave": _wave,
    "talk": _talk_or_listen,
    "listen": _talk_or_listen,
    "handshake": _handshake,
    "hug": _hug,
}
"""The hand / head motion of each gesture (``ActionSpec.gesture``; ``none``: head turns only)."""


def _gesture(body: _Body, spec: ActionSpec, duration: float) -> None:
    """Write the spec's hand / head motion into ``body`` (time t in [0, duration))."""
    g = spec.gesture
    rest = [body.rest_hand(0), body.rest_hand(1)]
    if g == "none":
        w = 2 * np.pi * body.t / duration
        body.head[:, 1] += 0.25 * np.sin(w)
        return
    write = _GESTURES.get(g)
    if write is None:
        raise ValueError(f"no procedural gesture {g!r}")
    write(body, spec, duration, rest)


def action_clip(label: str, *, seated: bool = False, seat_height: float = 0.46,
                cycles: int = 1, name: str | None = None) -> MotionClip:
    """A clip for an idle / in-place / partner label, standing or seated.

    The target (clip world) is the seat for seated clips, the partner for partner actions
    (facing back at the character) and the object in front for in-place actions.
    """
    spec = action_spec(label)
    key = database_key(label, seated)
    duration = spec.duration_s * (cycles if spec.loops else 1)
    n = round(duration * FPS)
    t = np.arange(n) / FPS
    body = _Body(t, seated, seat_height)
    _breathing(body, duration / max(1, round(duration / 4.0)))
    _gesture(body, spec, duration)
    local, pelvis = body.solve()
    if seated:
        target = np.array([0.0, 0.0, 0.0, seat_height])
    elif spec.family == "partner":
        target = np.array([PARTNER_DISTANCE.get(label, DEFAULT_PARTNER_DISTANCE), 0.0, np.pi, 0.0])
    else:
        target = np.array([OBJECT_DISTANCE, 0.0, np.pi, spec.reach_height])
    contacts = np.ones((n, 2), dtype=bool)
    return MotionClip(name or f"{key}_proc", key, local, pelvis, body.root_xy, body.heading, contacts,
                      spec.loops, target)


def _sit_progress(body: _Body, u: NDArray[np.float64], seat_height: float) -> None:
    """Pose along the sit-down path, u in [0, 1] (0 standing, 1 seated); root at the pelvis."""
    back = smoothstep(u / 0.85)
    drop = smoothstep((u - 0.1) / 0.9)
    body.pelvis[:, 0] = 0.0
    body.root_xy[:, 0] = -SIT_BACK * back
    body.pelvis[:, 2] = STAND_Z + (seat_height + SEAT_PELVIS_ABOVE_SEAT - STAND_Z) * drop
    lean = 0.55 * np.sin(np.pi * np.clip(u, 0, 1)) ** 1.5
    body.tilt[:, 0] = 0.6 * lean
    body.spine[:, 0] = 0.4 * lean
    body.head[:, 0] = -0.5 * lean
    # feet stay where they were when standing (toes just ahead of the standing pelvis);
    # the rig takes toe targets in the world, which is this clip's frame
    body.toes[:, 0, 0] = body.toes[:, 1, 0] = TOE_AHEAD + 0.04
    for side in (0, 1):
        s = 1.0 if side == 0 else -1.0
        stand = np.array([0.02, s * 0.22, STAND_Z - 0.03])
        seat = np.array([0.24, s * 0.13, seat_height + SEAT_PELVIS_ABOVE_SEAT + 0.06])
        mid = np.array([0.30, s * 0.2, STAND_Z - 0.15])
        w_mid = np.sin(np.pi * np.clip(u, 0, 1)) ** 2
        base = stand + (seat - stand) * drop[:, None]
        body.hands[:, side] = base + (mid - (stand + seat) / 2) * w_mid[:, None] * 0.6


def sitting_clip(kind: str, seat_height: float) -> MotionClip:
    """``sit_down`` or ``stand_up`` clip for a seat of ``seat_height`` metres.

    The clip's world has the seated pelvis ground point at (-SIT_BACK, 0) facing +x; the
    standing spot in front of the seat is the origin. Target = the seat.
    """
    if kind not in ("sit_down", "stand_up"):
        raise ValueError(f"unknown sitting clip kind {kind!r}")
    duration = action_spec(kind).duration_s
    hold = 0.3
    n = round((duration + 2 * hold) * FPS)
    t = np.arange(n) / FPS
    u = np.clip((t - hold) / duration, 0.0, 1.0)
    if kind == "stand_up":
        u = 1.0 - u
    body = _Body(t, False, seat_height)
    _sit_progress(body, u, seat_height)
    local, pelvis = body.solve()
    target = np.array([-SIT_BACK, 0.0, 0.0, seat_height])
    contacts = np.ones((n, 2), dtype=bool)
    return MotionClip(f"{kind}_h{seat_height:.2f}", kind, local, pelvis, body.root_xy.copy(),
                      body.heading, contacts, False, target)


def sit_idle_clip(seat_height: float) -> MotionClip:
    """Seated idle (breathing, looking around); target = the seat under the pelvis."""
    clip = action_clip("idle", seated=True, seat_height=seat_height, name=f"sit_idle_h{seat_height:.2f}")
    return MotionClip(clip.name, "sit_idle", clip.local_rotations, clip.pelvis, clip.root_xy,
                      clip.heading, clip.contacts, True, clip.target)
