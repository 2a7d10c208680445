"""The files of a run folder a person reads: ``story.md`` and ``metrics.json``.

:func:`story_markdown` renders ``story.json`` (:func:`orchestrator.session.run_job.story_json`)
as text: per applied event its simulated time, characters, activity and each character's
action and place, then when it finished. Every string that came from an LLM (activities,
areas, failure feedback) or from the user (instruction) goes through :func:`md_text`: control
characters are dropped, line breaks become spaces and every markdown-special character is
backslash-escaped, so a model's answer can neither inject markup nor break a line.

:func:`run_metrics` counts from the trace (every attempt of every LLM call, also those of an
earlier, killed process of the same run) and the session's result: events by state, calls,
retries and tokens per role, latency p50/p95 per role, simulation speed and the wall-clock
interval between frames (p50/p99).
"""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2066-\u2069]")
_BREAKS = re.compile(r"[\t\r\n]+")
_SPECIAL = re.compile(r"([\\`*_{}\[\]()<>#+\-.!|~])")


def md_text(text: str) -> str:
    """``text`` safe inside one markdown line: no control characters, no line breaks, every
    markdown-special character escaped."""
    flat = _BREAKS.sub(" ", text)
    return _SPECIAL.sub(r"\\\1", _CONTROL.sub("", flat)).strip()


def clock(frame: int, fps: int) -> str:
    """Simulated time of ``frame`` as ``mm:ss.s`` (``h:mm:ss.s`` past an hour)."""
    total = frame / fps
    hours, rest = divmod(total, 3600.0)
    minutes, seconds = divmod(rest, 60.0)
    if hours >= 1:
        return f"{int(hours)}:{int(minutes):02d}:{seconds:04.1f}"
    return f"{int(minutes):02d}:{seconds:04.1f}"


def story_markdown(story: dict[str, Any]) -> str:
    """``story.md`` from the ``story.json`` payload."""
    fps = int(story["fps"])
    plans_of = {s["index"]: s.get("plans", []) for s in story["steps"] if s["kind"] == "event"}
    lines = [
        f"# Story in {md_text(str(story['scene']))}",
        "",
        f"Characters: {', '.join(md_text(n) for n in story['characters'])}  ",
        f"Instruction: {md_text(story['instruction']) or '(none)'}  ",
        f"Length: {clock(int(story['frames']), fps)} ({story['frames']} frames at {fps} fps)",
        "",
    ]
    events = story["events"]
    if not events:
        lines.append("No event was applied.")
    for e in events:
        who = ", ".join(md_text(c) for c in e["characters"])
        lines.append(f"## {clock(int(e['applied_frame']), fps)} {md_text(e['event_id'])}: {who}")
        lines.append("")
        lines.append(md_text(e["activity"]))
        if e.get("part"):
            lines.append(f"(for the instruction's part: {md_text(e['part'])})")
        lines.append("")
        for p in plans_of.get(e["index"], []):
            x, y = p["position"]
            seat = f", on {md_text(p['seat'])}" if p.get("seat") else ""
            lines.append(
                f"- {md_text(p['character'])}: {md_text(p['action'])} at {md_text(p['area'])} "
                f"\\({x:.2f}, {y:.2f}\\){seat}"
            )
        state = e["state"]
        if e["finished_frame"] is not None:
            end = f"{state} at {clock(int(e['finished_frame']), fps)}"
        else:
            end = f"{state} at the end of the story"
        if e.get("failure"):
            end += f": {md_text(e['failure'])}"
        lines += ["", f"*{end}*", ""]
    failed = [s for s in story["steps"] if s["kind"] == "failed"]
    if failed:
        lines += ["## Planning steps that failed", ""]
        for s in failed:
            lines.append(
                f"- step {s['index']} at {clock(int(s['applied_frame']), fps)} in {md_text(s['node'])}: "
                f"{md_text(s['feedback'])}"
            )
        lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def _percentiles(values: list[float], qs: tuple[float, ...]) -> dict[str, float | None]:
    if not values:
        return {f"p{q:g}": None for q in qs}
    arr = np.asarray(values, dtype=float)
    return {f"p{q:g}": round(float(np.percentile(arr, q)), 6) for q in qs}


def llm_metrics(trace_path: Path | None) -> dict[str, Any]:
    """Per role (node): calls, attempts, retries, failed calls, tokens, latency p50/p95 (s)."""
    from orchestrator.llm.traces import read_trace

    if trace_path is None or not trace_path.is_file():
        return {}
    attempts_by_node: dict[str, list[Any]] = defaultdict(list)
    for a in read_trace(trace_path).attempts():
        attempts_by_node[a.node].append(a)
    out: dict[str, Any] = {}
    for node in sorted(attempts_by_node):
        attempts = attempts_by_node[node]
        calls: dict[tuple[str, int], list[Any]] = defaultdict(list)
        for a in attempts:
            calls[(a.run_id, a.call)].append(a)
        out[node] = {
            "calls": len(calls),
            "attempts": len(attempts),
            "retries": sum(1 for a in attempts if a.attempt > 1),
            "failed_calls": sum(1 for c in calls.values() if not any(a.final and a.ok for a in c)),
            "replayed": sum(1 for a in attempts if "replayed_from_seq" in a.params),
            "prompt_tokens": sum(a.usage.prompt_tokens for a in attempts if a.usage is not None),
            "completion_tokens": sum(a.usage.completion_tokens for a in attempts if a.usage is not None),
            "latency_s": _percentiles([a.latency_s for a in attempts], (50, 95)),
        }
    return out


def run_metrics(
    story: dict[str, Any], trace_path: Path | None, *, wall_s: float, frame_intervals_s: list[float]
) -> dict[str, Any]:
    """``metrics.json``: story counts, LLM use per role, simulation speed and frame intervals."""
    fps = int(story["fps"])
    states: dict[str, int] = defaultdict(int)
    for e in story["events"]:
        states[e["state"]] += 1
    steps: dict[str, int] = defaultdict(int)
    for s in story["steps"]:
        steps[s["kind"]] += 1
    roles = llm_metrics(trace_path)
    simulated = story["frames"] / fps
    intervals_ms = [1000.0 * v for v in frame_intervals_s]
    return {
        "events": {"applied": len(story["events"]), **dict(sorted(states.items()))},
        "planning_steps": {"total": len(story["steps"]), **dict(sorted(steps.items()))},
        "llm": {
            "calls": sum(r["calls"] for r in roles.values()),
            "attempts": sum(r["attempts"] for r in roles.values()),
            "retries": sum(r["retries"] for r in roles.values()),
            "prompt_tokens": sum(r["prompt_tokens"] for r in roles.values()),
            "completion_tokens": sum(r["completion_tokens"] for r in roles.values()),
            "roles": roles,
        },
        "simulation": {
            "frames": story["frames"],
            "simulated_s": round(simulated, 3),
            "wall_s": round(wall_s, 3),
            "speed": round(simulated / wall_s, 3) if wall_s > 0 else None,
            "frame_interval_ms": _percentiles(intervals_ms, (50, 99)),
        },
    }
