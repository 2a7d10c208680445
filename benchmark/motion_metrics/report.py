"""Tables of :class:`~storyteller.benchmark.motion_metrics.measure.Measured` sources, as text and Markdown,
the gait-against-speed figure and ``metrics.json``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from storyteller.benchmark.motion_facing import summarize
from storyteller.benchmark.motion_metrics.feet import floor_contact
from storyteller.benchmark.motion_metrics.gait import (
    GAIT_METRICS,
    UNITS,
    GaitWindow,
    cadence_by_speed,
    compare_gait,
    fit_speed,
)
from storyteller.benchmark.motion_metrics.interactions import HAND_TARGET_M, SEAT_TARGET_M, Reach, is_use_action
from storyteller.benchmark.motion_metrics.measure import Measured, furniture_summary

Table = tuple[list[str], list[list[str]]]


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}" if math.isfinite(x) else "-"


def _ratio(a: float, b: float) -> str:
    ok = math.isfinite(a) and math.isfinite(b) and abs(b) > 1e-12
    return f"{a / b:.2f}x" if ok else "-"


def contact_table(items: Sequence[Measured], real: Measured | None) -> Table:
    head = ["source", "chars", "frames", "skate (GMD)", "floor pen mean/max mm", "float med/p95 mm",
            "float /real", "furniture p99/max cm", ">2cm", "overlap frames", "overlap max cm"]
    real_float = floor_contact(np.concatenate(real.foot_heights)).float_median if real and real.foot_heights else math.nan
    rows = []
    for m in ([real] if real is not None and real.characters else []) + list(items):
        fc = floor_contact(np.concatenate(m.foot_heights) if m.foot_heights else np.zeros(0))
        p99, mx, deep = furniture_summary(m)
        overlap = f"{m.overlap_frames}/{m.overlap_checked}" if m.overlap_checked else "-"
        rows.append([m.name, str(m.characters), str(m.frames), _f(m.skating.ratio, 3),
                     f"{_f(fc.penetration_mean, 1)}/{_f(fc.penetration_max, 1)}",
                     f"{_f(fc.float_median, 1)}/{_f(fc.float_p95, 1)}",
                     "1.00x" if m is real else _ratio(fc.float_median, real_float),
                     f"{_f(p99, 1)}/{_f(mx, 1)}", _f(deep, 3), overlap,
                     _f(m.overlap_max * 100, 1) if m.overlap_checked else "-"])
    return head, rows


def gait_table(items: Sequence[Measured], real: Measured) -> Table:
    head = ["source", "windows", *[f"{m} ({UNITS[m]})" for m in GAIT_METRICS]]
    rows = []
    for m in items:
        cmp = compare_gait(m.gait, real.gait)
        rows.append([m.name, str(cmp.windows), *[_f(cmp.generated[g], 3) for g in GAIT_METRICS]])
        rows.append(["  real at those speeds", str(len(real.gait)), *[_f(cmp.real[g], 3) for g in GAIT_METRICS]])
        rows.append(["  generated / real", "", *[_f(cmp.ratio[g]) + "x" if math.isfinite(cmp.ratio[g]) else "-"
                                                  for g in GAIT_METRICS]])
    return head, rows


def cadence_table(items: Sequence[Measured], real: Measured) -> Table:
    head = ["speed m/s", *[f"{m.name} n / cadence / step m" for m in [real, *items]]]
    cols = [cadence_by_speed(m.gait) for m in [real, *items]]
    rows = []
    for k in range(len(cols[0])):
        rows.append([cols[0][k][0], *[f"{c[k][1]} / {_f(c[k][2], 0)} / {_f(c[k][3])}" for c in cols]])
    return head, rows


def interaction_table(items: Sequence[Measured]) -> Table:
    head = ["source", "facing n", "start med/p95 deg", "during med/p95 deg", "use_* reaches", "hand med cm",
            f"<= {HAND_TARGET_M * 100:g} cm", f"all reaches n / med cm / <= {HAND_TARGET_M * 100:g} cm",
            f"to mouth n / med cm / <= {HAND_TARGET_M * 100:g} cm",
            "sittings", "seat err med/max cm", f"<= {SEAT_TARGET_M * 100:g} cm",
            "sit down n / med s", "stand up n / med s"]
    rows = []
    for m in items:
        fs = summarize(m.facing)
        hands = np.array([r.distance for r in m.reaches if is_use_action(r.action)])
        every = np.array([r.distance for r in m.reaches])
        seats = np.array(m.seat_errors)
        sd, su = m.transitions["sit_down"], m.transitions["stand_up"]
        rows.append([
            m.name, str(fs.count), f"{_f(fs.start_median, 1)}/{_f(fs.start_p95, 1)}",
            f"{_f(fs.during_median, 1)}/{_f(fs.during_p95, 1)}", str(len(hands)),
            _f(float(np.median(hands)) * 100, 1) if len(hands) else "-",
            _f(float(np.mean(hands <= HAND_TARGET_M)), 2) if len(hands) else "-",
            f"{len(every)} / {_f(float(np.median(every)) * 100, 1)} / {_f(float(np.mean(every <= HAND_TARGET_M)), 2)}"
            if len(every) else "0 / - / -", _reach_cell(m.mouths), str(len(seats)),
            f"{_f(float(np.median(seats)) * 100, 1)}/{_f(float(seats.max()) * 100, 1)}" if len(seats) else "-",
            _f(float(np.mean(seats <= SEAT_TARGET_M)), 2) if len(seats) else "-",
            f"{len(sd)} / {_f(float(np.median(sd)), 2) if sd else '-'}",
            f"{len(su)} / {_f(float(np.median(su)), 2) if su else '-'}",
        ])
    return head, rows


def _reach_cell(items: Sequence[Reach]) -> str:
    """'n / median cm / share within the hand target' of reaches."""
    d = np.array([r.distance for r in items])
    if not len(d):
        return "0 / - / -"
    return f"{len(d)} / {_f(float(np.median(d)) * 100, 1)} / {_f(float(np.mean(d <= HAND_TARGET_M)), 2)}"


def as_text(table: Table) -> str:
    head, rows = table
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    lines = ["  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(head, widths, strict=True)))]
    for r in rows:
        lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True))))
    return "\n".join(lines)


def as_markdown(table: Table) -> str:
    head, rows = table
    esc = [[c.replace("|", "\\|") for c in r] for r in [head, *rows]]
    out = ["| " + " | ".join(esc[0]) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r) + " |" for r in esc[1:]]
    return "\n".join(out)


def gait_figure(items: Sequence[Measured], real: Measured, path: Path) -> Path:
    """Cadence, step length, bob and arm swing against speed: every window, the real fit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ("cadence", "step_length", "bob", "sway", "arm_swing", "jerk")
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5))
    for ax, metric in zip(axes.ravel(), shown, strict=True):
        def scatter(ws: Sequence[GaitWindow], ax: Any = ax, metric: str = metric, **kw: Any) -> None:
            ax.scatter([w.speed for w in ws], [w.value(metric) for w in ws], s=12, **kw)

        scatter(real.gait, color="black", marker="x", label="real")
        for k, m in enumerate(items):
            scatter(m.gait, color=plt.get_cmap("tab10")(k), alpha=0.6, label=m.name[:30])
        fit = fit_speed([w.speed for w in real.gait], [w.value(metric) for w in real.gait])
        if math.isfinite(fit.intercept):
            s = np.linspace(fit.lo, fit.hi, 10)
            ax.plot(s, [fit.value(x) for x in s], color="black", lw=1)
        ax.set_xlabel("speed (m/s)")
        ax.set_ylabel(f"{metric} ({UNITS[metric]})")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("walking windows against speed (black: real walks and their line)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def figures_json(items: Sequence[Measured], real: Measured | None) -> dict[str, Any]:
    """The main figures of every source, for ``metrics.json``."""
    out: dict[str, Any] = {}
    for m in ([real] if real is not None else []) + list(items):
        fc = floor_contact(np.concatenate(m.foot_heights) if m.foot_heights else np.zeros(0))
        p99, mx, deep = furniture_summary(m)
        fs = summarize(m.facing)
        row: dict[str, Any] = {
            "characters": m.characters, "frames": m.frames, "skating_ratio": m.skating.ratio,
            "floor_penetration_mean_mm": fc.penetration_mean, "floor_penetration_max_mm": fc.penetration_max,
            "float_median_mm": fc.float_median, "float_p95_mm": fc.float_p95,
            "furniture_p99_cm": p99, "furniture_max_cm": mx, "furniture_over_2cm_share": deep,
            "overlap_frames": m.overlap_frames, "overlap_checked_frames": m.overlap_checked,
            "overlap_max_cm": m.overlap_max * 100, "walking_windows": len(m.gait),
            "facing_count": fs.count, "facing_start_median_deg": fs.start_median, "facing_start_p95_deg": fs.start_p95,
            "facing_during_median_deg": fs.during_median, "facing_during_p95_deg": fs.during_p95,
            "reaches": [[r.action, r.obj, r.frame, r.distance] for r in m.reaches],
            "mouths": [[r.action, r.obj, r.frame, r.distance] for r in m.mouths],
            "seat_errors_m": m.seat_errors, "transitions_s": m.transitions, "notes": m.notes,
        }
        if real is not None and m is not real:
            cmp = compare_gait(m.gait, real.gait)
            row["gait"] = {"generated": cmp.generated, "real_at_speed": cmp.real, "ratio": cmp.ratio}
        out[m.name] = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}
    return out
