"""The files of a run folder a person reads: ``story.md`` and ``metrics.json``.

:func:`story_markdown` renders ``story.json`` (:func:`storyteller.orchestrator.session.run_outputs.story_json`)
as a short story in order: one paragraph per applied event with its simulated time, saying what
the applied plan has the characters do (the event's ``text``, ``storyteller.agents.story_text``), the
narrator's own words only where they were checked to agree with the plan (``narration``), and
how the event ended; a line for each run of waits and each failed planning step; then the
failure messages under "What went wrong". Every string (plan sentences carry character names
from the user; narration, failures and feedback come from a model or the simulation) goes
through :func:`md_text`: control characters are dropped, line breaks become spaces and every
markdown-special character is backslash-escaped, so no text can inject markup or break a line.

:func:`run_metrics` counts from the trace (every attempt of every LLM call, also those of an
earlier, killed process of the same run) and the session's result: events by state, calls,
retries and tokens per role, latency p50/p95 per role, simulation speed and the wall-clock
interval between frames (p50/p99).
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from storyteller.agents.story_text import step_text

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


def story_markdown(story: dict[str, Any], *, text: Callable[[str], str] = md_text) -> str:
    """``story.md`` from the ``story.json`` payload: the story in order, one paragraph per
    applied event (its simulated time, its plan sentence, the narrator's words where they agree
    with the plan, how it ended), a line for each run of waits and each failed planning step, then
    what went wrong in detail. ``text`` escapes every string from the story (the viewer's story
    panel passes ``storyteller.orchestrator.safe_text.markdown``)."""
    fps = int(story["fps"])
    lines = [
        f"# Story in {text(str(story['scene']))}",
        "",
        f"Characters: {', '.join(text(n) for n in story['characters'])}  ",
        f"Instruction: {text(story['instruction']) or '(none)'}  ",
        f"Length: {clock(int(story['frames']), fps)} ({story['frames']} frames at {fps} fps)",
        "",
    ]
    plans_of = {s["index"]: s.get("plans", []) for s in story["steps"] if s["kind"] == "event"}
    happenings: list[tuple[int, int, str, dict[str, Any]]] = [
        (int(e["applied_frame"]), int(e["index"]), "event", e) for e in story["events"]
    ]
    happenings += [(int(s["applied_frame"]), int(s["index"]), s["kind"], s) for s in story["steps"]
                   if s["kind"] in ("wait", "failed")]  # fmt: skip
    happenings.sort(key=lambda h: (h[0], h[1]))
    if not story["events"]:
        lines += ["No event was applied.", ""]
    event_frames = {int(e["applied_frame"]) for e in story["events"]}
    previous = ""
    for frame, _, kind, item in happenings:
        if kind == "wait" and (previous == "wait" or frame in event_frames):
            continue  # a run of waits is one line; beside an event that starts then, none
        previous = kind
        if kind == "event":
            lines += [_event_paragraph(item, plans_of.get(item["index"], []), fps, text), ""]
        else:
            said = item.get("text") or (step_text(None) if kind == "wait" else _FAILED_STEP)
            lines += [f"{clock(frame, fps)} — {text(said)}", ""]
    wrong = [f"- {text(e['event_id'])} failed at {clock(int(e['finished_frame'] or 0), fps)}: "
             f"{text(e.get('failure') or 'no reason given')}"
             for e in story["events"] if e["state"] == "failed"]  # fmt: skip
    wrong += [f"- step {s['index']} at {clock(int(s['applied_frame']), fps)} in {text(s['node'])}: {text(s['feedback'])}"
              for s in story["steps"] if s["kind"] == "failed"]  # fmt: skip
    if wrong:
        lines += ["## What went wrong", "", *wrong, ""]
    return "\n".join(lines).rstrip("\n") + "\n"


_FAILED_STEP = "No new event could be planned."


def _event_paragraph(e: dict[str, Any], plans: list[Any], fps: int, text: Callable[[str], str]) -> str:
    """One event: time, what happens (the plan sentence), the narrator's words if they agree,
    the instruction's part, how it ended and its id."""
    sentence = e.get("text") or _plan_sentence(e, plans)
    parts = [f"{clock(int(e['applied_frame']), fps)} \u2014 {text(sentence)}"]
    if e.get("narration"):
        parts.append(f"In the narrator's words: \u201c{text(str(e['narration']).rstrip('. '))}\u201d.")
    if e.get("part"):
        parts.append(f"This carries out the instruction's part \u201c{text(str(e['part']).rstrip('. '))}\u201d.")
    if e["state"] == "failed":
        at = f" at {clock(int(e['finished_frame']), fps)}" if e["finished_frame"] is not None else ""
        parts.append(f"It fails{at} \\(see below\\).")
    elif e["finished_frame"] is not None:
        parts.append(f"Done at {clock(int(e['finished_frame']), fps)}.")
    else:
        parts.append("Still going when the story ends.")
    parts.append(f"*{text('(' + str(e['event_id']) + ')')}*")
    return " ".join(parts)


def _plan_sentence(e: dict[str, Any], plans: list[Any]) -> str:
    """The plan sentence of an event of an older ``story.json`` (no ``text``), from its step's
    plans and the object ids alone (no scene: no disambiguation)."""
    from pydantic import ValidationError

    from storyteller.agents.messages import PlannedCharacter
    from storyteller.agents.story_text import plan_text

    try:
        planned = [PlannedCharacter.model_validate(p) for p in plans]
    except ValidationError:
        planned = []
    return plan_text([str(c) for c in e["characters"]], planned, None)


def _percentiles(values: list[float], qs: tuple[float, ...]) -> dict[str, float | None]:
    if not values:
        return {f"p{q:g}": None for q in qs}
    arr = np.asarray(values, dtype=float)
    return {f"p{q:g}": round(float(np.percentile(arr, q)), 6) for q in qs}


def llm_metrics(trace_path: Path | None) -> dict[str, Any]:
    """Per role (node): calls, attempts, retries, failed calls, tokens, latency p50/p95 (s)."""
    from storyteller.orchestrator.llm.traces import read_trace

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


def local_threads_metrics(trace_path: Path | None) -> dict[str, Any] | None:
    """The embedded model's thread choices over the run's attempts (None when no local call
    ran here): attempts per thread count at their start, attempts whose threads changed while
    they ran, the usable cores, the range of the cores other processes kept busy before the
    calls and where that figure came from (``storyteller.orchestrator.llm.cpu_threads``). Replayed attempts
    are left out: they ran no model."""
    from storyteller.orchestrator.llm.traces import read_trace

    if trace_path is None or not trace_path.is_file():
        return None
    choices = [a.params["local_threads"] for a in read_trace(trace_path).attempts()
               if isinstance(a.params.get("local_threads"), dict) and "replayed_from_seq" not in a.params]
    if not choices:
        return None
    by_threads: dict[int, int] = defaultdict(int)
    for c in choices:
        by_threads[int(c["threads"])] += 1
    busy = [float(c["busy_cores"]) for c in choices if c.get("busy_cores") is not None]
    return {
        "attempts_by_threads": {str(t): n for t, n in sorted(by_threads.items())},
        "rethreaded_attempts": sum(1 for c in choices if c.get("rechosen")),
        "usable_cores": max(int(c["usable_cores"]) for c in choices),
        "busy_cores": {"min": min(busy), "max": max(busy)} if busy else None,
        "sources": sorted({str(c["source"]) for c in choices}),
    }


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
            "local_threads": local_threads_metrics(trace_path),
        },
        "simulation": {
            "frames": story["frames"],
            "simulated_s": round(simulated, 3),
            "wall_s": round(wall_s, 3),
            "speed": round(simulated / wall_s, 3) if wall_s > 0 else None,
            "frame_interval_ms": _percentiles(intervals_ms, (50, 99)),
        },
    }
