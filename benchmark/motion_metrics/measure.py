"""Every measure of the package over one source (a run, the crowd, the real clips), poolable.

:func:`measure_run` keeps what the summaries need per frame or per event (penetration depths,
lowest-foot heights, walking windows, reaches, seat errors, transition times, facing), so that
several runs pool by concatenation (:func:`pooled`) before medians and percentiles are taken.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from storyteller.benchmark.motion_facing import Interaction, run_folder_interactions
from storyteller.benchmark.motion_metrics.bodies import (
    CONTACT_ACTIONS,
    crowd_overlaps,
    furniture_penetration,
    sphere_body,
)
from storyteller.benchmark.motion_metrics.feet import Skating, foot_skating, lowest_foot_height
from storyteller.benchmark.motion_metrics.gait import GaitWindow, track_windows
from storyteller.benchmark.motion_metrics.interactions import (
    Reach,
    is_seated_label,
    mouth_reaches,
    reaches,
    seat_errors,
    transition_times,
)
from storyteller.benchmark.motion_metrics.sources import RunMotion
from storyteller.sim.motion.action_labels import family_of
from storyteller.sim.world.facing import needs_reach

FURNITURE_TARGET_M = 0.02  # p99 of frames


@dataclass
class Measured:
    """What one source (or several pooled) measured; see the module docstring."""

    name: str
    characters: int = 0
    frames: int = 0
    fps: float = 30.0
    skating: Skating = field(default_factory=lambda: Skating(0, 0))
    foot_heights: list[NDArray[np.float64]] = field(default_factory=list)
    furniture: list[NDArray[np.float64]] = field(default_factory=list)  # per character-frame, m
    overlap_frames: int = 0
    overlap_checked: int = 0  # frames in which pairs were checked (frames of runs with 2+ characters)
    overlap_max: float = 0.0
    overlap_pairs: int = 0
    gait: list[GaitWindow] = field(default_factory=list)
    reaches: list[Reach] = field(default_factory=list)
    mouths: list[Reach] = field(default_factory=list)  # drink / eat: wrist to mouth
    seat_errors: list[float] = field(default_factory=list)
    transitions: dict[str, list[float]] = field(default_factory=lambda: {"sit_down": [], "stand_up": []})
    facing: list[Interaction] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _base_label(label: str) -> str:
    return label.split("@", 1)[0]


def _flags(labels: Sequence[str]) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """(seated, hands working on an object, in a contact action) per frame."""
    seated, hands, contact = [], [], []
    for lab in labels:
        base = _base_label(lab)
        known = bool(base)
        try:
            fam = family_of(base) if known else "idle"
            reach = needs_reach(base) if known else False
        except ValueError:
            fam, reach = "idle", False
        seated.append(is_seated_label(lab) or fam == "sitting")
        hands.append(reach)
        contact.append(base in CONTACT_ACTIONS)
    return np.array(seated, dtype=bool), np.array(hands, dtype=bool), np.array(contact, dtype=bool)


def measure_run(run: RunMotion, *, bodies: bool = True, facing: bool = True) -> Measured:
    """Every measure of ``run`` (``bodies=False``: no furniture and overlap; ``facing=False``:
    no facing, which needs the run folder's plans)."""
    out = Measured(run.name, characters=len(run.characters), frames=run.frames, fps=run.fps)
    floor = run.scene.floor_z if run.scene is not None else 0.0
    body = sphere_body()
    centres, contacts = [], []
    for c in run.characters:
        out.skating = out.skating + foot_skating(c.joints, run.fps, floor)
        out.foot_heights.append(lowest_foot_height(c.joints, floor))
        out.gait.extend(track_windows(c.joints, c.labels, run.fps))
        for k, v in transition_times(c.labels, run.fps).items():
            out.transitions[k].extend(v)
        if run.scene is None:
            continue
        out.reaches.extend(reaches(c.joints, c.labels, run.scene, run.fps))
        out.mouths.extend(mouth_reaches(c.joints, c.labels, run.fps))
        out.seat_errors.extend(seat_errors(c.joints, c.labels, run.scene))
        if bodies:
            seated, hands, contact = _flags(c.labels)
            sph = body.centres(c.joints)
            out.furniture.append(furniture_penetration(sph, body, run.scene.objects, seated, hands))
            centres.append(sph)
            contacts.append(contact)
    if bodies and len(centres) > 1:
        n = min(len(s) for s in centres)
        depth, pairs = crowd_overlaps([s[:n] for s in centres], body, [f[:n] for f in contacts])
        out.overlap_frames, out.overlap_checked = int((depth > 0).sum()), n
        out.overlap_max, out.overlap_pairs = float(depth.max(initial=0.0)), pairs
    if facing and run.folder is not None:
        try:
            out.facing = run_folder_interactions(run.folder)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            out.notes.append(f"facing not measured: {type(exc).__name__}: {str(exc)[:160]}")
    return out


def pooled(name: str, items: Sequence[Measured]) -> Measured:
    """Several sources as one (frames, windows and events concatenated; overlap frames added)."""
    out = Measured(name)
    for m in items:
        out.characters += m.characters
        out.frames += m.frames
        out.fps = m.fps
        out.skating = out.skating + m.skating
        out.foot_heights += m.foot_heights
        out.furniture += m.furniture
        out.overlap_frames += m.overlap_frames
        out.overlap_checked += m.overlap_checked
        out.overlap_max = max(out.overlap_max, m.overlap_max)
        out.overlap_pairs += m.overlap_pairs
        out.gait += m.gait
        out.reaches += m.reaches
        out.mouths += m.mouths
        out.seat_errors += m.seat_errors
        for k in out.transitions:
            out.transitions[k] += m.transitions.get(k, [])
        out.facing += m.facing
        out.notes += [f"{m.name}: {n}" for n in m.notes]
    return out


def furniture_summary(m: Measured) -> tuple[float, float, float]:
    """(p99 cm, max cm, share of character-frames deeper than 2 cm); nan without a scene."""
    if not m.furniture:
        return math.nan, math.nan, math.nan
    d = np.concatenate(m.furniture)
    if d.size == 0:
        return math.nan, math.nan, math.nan
    return float(np.percentile(d, 99) * 100), float(d.max() * 100), float(np.mean(d > FURNITURE_TARGET_M))
