"""``results.csv``, ``report.md`` and the plots of a sweep, from its result lines only.

``report.md`` follows the paper's layout: per case set, one row per model and method, cells
``success (execution)`` for Total (the cases without the PI tag), OA, RC and SS (the cases
carrying the tag), and PI per method; then the same cells by distraction level and by number
of characters, prompt and completion tokens per call by scene-description type, latency per
call by role, and the classes of the runs that did not pass. Success = passed runs / runs;
execution = runs that produced a plan or a wait with every role's first reply accepted / runs
(first attempt, whatever the feedback budget; with feedback the rate after retries is shown
too). Nothing in it depends on the wall clock, so a replay writes the same bytes.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Sequence
from pathlib import Path

from storyteller.benchmark.sweep.grid import METHOD_TITLES, SweepSpec
from storyteller.benchmark.sweep.results import RunResult, results_csv, write_atomic
from storyteller.orchestrator.reference_data import PROJECT_ROOT, REFERENCE_ENV, locate_reference

PLOTS = ("success_by_characters.png", "tokens_by_description.png")



def where(path: str) -> str:
    """A case folder as a reader can find it on their machine: under the reference data
    (``$STORYTELLER_REFERENCE/...``), under the project, else as given. The report then reads
    the same wherever the sweep ran."""
    folder = Path(path).resolve()
    reference = locate_reference()
    for root, name in ((reference.path if reference.found else None, f"${REFERENCE_ENV}"), (PROJECT_ROOT, ".")):
        if root is not None and folder.is_relative_to(root):
            rel = folder.relative_to(root).as_posix()
            return name if rel == "." else f"{name}/{rel}"
    return path


def _has_tag(tag: str) -> Callable[[RunResult], bool]:
    return lambda r: tag in _tags(r)


def _at_level(level: int) -> Callable[[RunResult], bool]:
    return lambda r: r.level == level


def _with_characters(n: int) -> Callable[[RunResult], bool]:
    return lambda r: r.characters == n

def cell(results: Sequence[RunResult]) -> str:
    """``success (execution)`` with two decimals, or ``-`` without runs."""
    if not results:
        return "-"
    n = len(results)
    return f"{sum(r.verdict == 'pass' for r in results) / n:.2f} ({sum(r.executed_first for r in results) / n:.2f})"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return [*out, ""]


def _rows_by(results: Sequence[RunResult], columns: Sequence[tuple[str, Callable[[RunResult], bool]]]) -> list[list[str]]:
    """One row per (model, method) in first-seen order, one cell per column filter."""
    pairs = list(dict.fromkeys((r.model, r.method) for r in results))
    rows = []
    for model, method in pairs:
        mine = [r for r in results if r.model == model and r.method == method]
        rows.append([model, METHOD_TITLES.get(method, method), *(cell([r for r in mine if f(r)]) for _, f in columns)])
    return rows


def _tags(r: RunResult) -> set[str]:
    return set(r.group.split("+"))


def case_set_section(name: str, results: Sequence[RunResult], feedback: int) -> list[str]:
    lines = [f"## Case set `{name}`", ""]
    cases = len({r.case for r in results})
    lines += [f"{len(results)} runs over {cases} cases; {sum(r.verdict == 'pass' for r in results)} passed.", ""]
    plain = [r for r in results if "PI" not in _tags(r)]
    if plain:
        lines += ["### Success (execution) by tag", ""]
        cols: list[tuple[str, Callable[[RunResult], bool]]] = [("Total", lambda r: True)]
        cols += [(t, _has_tag(t)) for t in ("OA", "RC", "SS")]
        lines += _table(["Model", "Method", *(c for c, _ in cols)], _rows_by(plain, cols))
    pi = [r for r in results if "PI" in _tags(r)]
    if pi:
        lines += ["### Position inference (PI)", ""]
        lines += _table(["Model", "Method", "PI"], _rows_by(pi, [("PI", lambda r: True)]))
    if feedback:
        lines += [f"### Execution after up to {feedback} feedback retries", ""]
        rows = [[m, METHOD_TITLES.get(k, k), f"{sum(r.executed for r in rs) / len(rs):.2f}"]
                for (m, k) in dict.fromkeys((r.model, r.method) for r in results)
                if (rs := [r for r in results if r.model == m and r.method == k])]
        lines += _table(["Model", "Method", "Execution"], rows)
    levels = sorted({r.level for r in results})
    lines += ["### By distraction level", ""]
    lines += _table(["Model", "Method", *(f"level {lv}" for lv in levels)],
                    _rows_by(results, [(str(lv), _at_level(lv)) for lv in levels]))
    counts = sorted({r.characters for r in results})
    lines += ["### By number of characters", ""]
    lines += _table(["Model", "Method", *(f"{n} char." for n in counts)],
                    _rows_by(results, [(str(n), _with_characters(n)) for n in counts]))
    return lines


def token_section(results: Sequence[RunResult]) -> list[str]:
    lines = ["## Tokens per call by scene-description type", ""]
    rows = []
    for desc in dict.fromkeys(r.description for r in results):
        for node in dict.fromkeys(c.node for r in results if r.description == desc for c in r.calls):
            calls = [c for r in results if r.description == desc for c in r.calls if c.node == node]
            rows.append([desc, node, str(len(calls)), f"{statistics.fmean(c.prompt_tokens for c in calls):.0f}",
                         f"{statistics.fmean(c.completion_tokens for c in calls):.0f}"])
    return lines + _table(["Description", "Role", "Calls", "Prompt tokens / call", "Completion tokens / call"], rows)


def latency_section(results: Sequence[RunResult]) -> list[str]:
    lines = ["## Latency per call", ""]
    rows = []
    for model in dict.fromkeys(r.model for r in results):
        for node in dict.fromkeys(c.node for r in results if r.model == model for c in r.calls):
            lat = [c.latency_s for r in results if r.model == model for c in r.calls if c.node == node]
            rows.append([model, node, str(len(lat)), f"{statistics.fmean(lat):.2f}", f"{statistics.median(lat):.2f}",
                         f"{max(lat):.2f}"])
    return lines + _table(["Model", "Role", "Calls", "Mean s", "Median s", "Max s"], rows)


def error_section(results: Sequence[RunResult]) -> list[str]:
    failed = [r for r in results if r.error_class is not None]
    if not failed:
        return []
    counts: dict[tuple[str, str, str], int] = {}
    for r in failed:
        k = (r.model, METHOD_TITLES.get(r.method, r.method), r.error_class or "")
        counts[k] = counts.get(k, 0) + 1
    return ["## Why runs did not pass", "", *_table(["Model", "Method", "Class", "Runs"], [[*k, str(n)] for k, n in sorted(counts.items())])]


def report_markdown(spec: SweepSpec, results: Sequence[RunResult]) -> str:
    feedback = (f"on (up to {spec.feedback} retries per role; execution is still counted on the first attempt)"
                if spec.feedback else "off, as in the paper")
    lines = [
        "# Planning benchmark sweep", "",
        f"- case sets: {', '.join(f'`{c.name}` ({where(c.path)})' for c in spec.case_sets)}",
        f"- distraction levels: {', '.join(map(str, spec.levels))}; repeats: {spec.repeats}; seed: {spec.seed}",
        f"- methods: {', '.join(METHOD_TITLES[m] for m in spec.methods)}; self-feedback: {feedback}",
        f"- program grammar for local models: {'on' if spec.program_grammar else 'off'}",
    ]
    for m in spec.models:
        lines.append(f"- model `{m.label}`: " + ", ".join(f"{role} = {name}" for role, name in m.roles.items()))
    lines += ["", "Cells are `success (execution)`: success = passed runs / runs; execution = runs that "
              "produced a plan or a wait with every role's first reply accepted / runs. Total = the cases "
              "without the PI tag; OA, RC, SS = the cases carrying that tag.", ""]
    if not results:
        return "\n".join([*lines, "No finished run yet.", ""])
    for cs in spec.case_sets:
        mine = [r for r in results if r.case_set == cs.name]
        if mine:
            lines += case_set_section(cs.name, mine, spec.feedback)
    lines += token_section(results) + latency_section(results) + error_section(results)
    lines += ["## Plots", "", "![success by number of characters](plots/success_by_characters.png)", "",
              "![tokens per call by description type](plots/tokens_by_description.png)", ""]
    return "\n".join(lines)


def write_reports(out: Path, spec: SweepSpec, results: Sequence[RunResult]) -> None:
    """Write ``results.csv``, ``report.md`` and ``plots/`` (atomically, file by file)."""
    from storyteller.benchmark.sweep.plots import write_plots

    write_atomic(out / "results.csv", results_csv(results))
    write_atomic(out / "report.md", report_markdown(spec, results).encode("utf-8"))
    write_plots(out / "plots", results)
