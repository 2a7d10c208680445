"""Side-view and top-view strips of one stretch of motion per action label, for a person to look at.

For each label, the longest run of it among the characters measured (at most ``STRIP_S``
seconds of it) is drawn as ``POSES`` stick figures spaced evenly in time: in the side view in
the vertical plane of each pose's own heading (seen from its side), placed along the distance
the pelvis travelled (figures that stay in place are spread ``SPACING_M`` apart), in the top view from above with the scene's object footprints near the
character. One PNG per label, ``strip_<label>.png`` (the label made file-safe).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from storyteller.benchmark.motion_metrics.gait import label_runs
from storyteller.benchmark.motion_metrics.sources import RunMotion
from storyteller.sim.body.skeleton import JOINT_INDEX, PARENTS

POSES = 8
STRIP_S = 4.0
SPACING_M = 0.7  # side view: metres between figures that stand in place


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "_", label)[:60] or "label"


def longest_runs(runs: Sequence[RunMotion]) -> dict[str, tuple[RunMotion, int, int, int]]:
    """Per label: (run, character index, first, end) of its longest run of frames."""
    best: dict[str, tuple[RunMotion, int, int, int]] = {}
    for run in runs:
        for ci, c in enumerate(run.characters):
            for label in set(c.labels):
                if not label:
                    continue
                for a, b in label_runs(c.labels, label):
                    if label not in best or b - a > best[label][3] - best[label][2]:
                        best[label] = (run, ci, a, b)
    return dict(sorted(best.items()))


def _bones(ax: object, pts: NDArray[np.float64], colour: str) -> None:
    for j, p in enumerate(PARENTS):
        if p >= 0:
            ax.plot([pts[p, 0], pts[j, 0]], [pts[p, 1], pts[j, 1]], color=colour, lw=1.4)  # type: ignore[attr-defined]  # matplotlib's Axes stub lacks the 3-d plot overload used here


def draw_strip(run: RunMotion, character: int, first: int, end: int, label: str, path: Path) -> Path:
    """Write the strip of ``run``'s character over frames [first, end) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = run.characters[character]
    end = min(end, first + round(STRIP_S * run.fps))
    frames = np.unique(np.linspace(first, end - 1, POSES).round().astype(int))
    j = c.joints
    path_len = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(j[first:end, 0, :2], axis=0), axis=-1))])
    moved = float(path_len[-1])
    fig, (side_ax, top_ax) = plt.subplots(2, 1, figsize=(11, 6.5), gridspec_kw={"height_ratios": [1.2, 1]})
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, len(frames)))
    for k, (f, col) in enumerate(zip(frames, colours, strict=True)):
        hips = j[f, JOINT_INDEX["right_hip"], :2] - j[f, JOINT_INDEX["left_hip"], :2]
        fwd = np.array([hips[1], -hips[0]]) / max(float(np.linalg.norm(hips)), 1e-9)  # the body's own forward
        offset = path_len[f - first] if moved > 1.0 else k * SPACING_M
        along = (j[f, :, :2] - j[f, 0, :2]) @ fwd + offset
        _bones(side_ax, np.stack([along, j[f, :, 2]], axis=-1), col)
        _bones(top_ax, j[f, :, :2], col)
        side_ax.text(float(along[0]), -0.12, f"{(f - first) / run.fps:.1f}s", fontsize=7, ha="center")
    side_ax.axhline(run.scene.floor_z if run.scene is not None else 0.0, color="0.4", lw=0.8)
    side_ax.set_aspect("equal")
    side_ax.set_ylim(-0.2, 2.0)
    side_ax.set_title(f"{label}: {c.name} in {run.name}, frames {first}-{end - 1} (side view: each pose from its side, along the path)",
                      fontsize=9)
    if run.scene is not None:
        centre = j[frames, 0, :2].mean(axis=0)
        for o in run.scene.objects:
            if np.linalg.norm(o.center_xy - centre) < 3.0:
                fp = o.footprint()
                top_ax.fill(fp[:, 0], fp[:, 1], color="0.85", ec="0.5", lw=0.6)
                top_ax.text(o.center[0], o.center[1], o.name, fontsize=6, ha="center", color="0.3", clip_on=True)
    top_ax.set_aspect("equal")
    top_ax.set_title("top view (world x, y; metres)", fontsize=9)
    lo, hi = j[frames, :, :2].min(axis=(0, 1)) - 0.8, j[frames, :, :2].max(axis=(0, 1)) + 0.8
    top_ax.set_xlim(lo[0], hi[0])
    top_ax.set_ylim(lo[1], hi[1])
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def draw_strips(runs: Sequence[RunMotion], folder: Path) -> list[Path]:
    """One strip per action label found in ``runs``, written into ``folder``."""
    return [draw_strip(run, ci, a, b, label, folder / f"strip_{_safe(label)}.png")
            for label, (run, ci, a, b) in longest_runs(runs).items()]
