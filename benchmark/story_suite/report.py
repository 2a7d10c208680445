"""The story suite's table: expectations met / total and share, per scenario and in total."""

from __future__ import annotations

from typing import TypedDict

from storyteller.benchmark.story_suite.evaluate import ScenarioScore


class Totals(TypedDict):
    """Expectations met over the whole suite."""

    met: int
    total: int
    share: float


def totals(scores: list[ScenarioScore]) -> Totals:
    met, total = sum(s.met for s in scores), sum(s.total for s in scores)
    return {"met": met, "total": total, "share": round(met / total, 4) if total else 0.0}


def table(scores: list[ScenarioScore]) -> str:
    width = max([len(s.scenario) for s in scores] + [len("total")])
    lines = [f"{'scenario':{width}s}  met/total  share", f"{'-' * width}  ---------  -----"]
    for s in scores:
        lines.append(f"{s.scenario:{width}s}  {s.met:>4d}/{s.total:<4d}  {s.share:5.2f}")
    t = totals(scores)
    lines.append(f"{'total':{width}s}  {t['met']:>4d}/{t['total']:<4d}  {t['share']:5.2f}")
    return "\n".join(lines)


def markdown_report(scores: list[ScenarioScore], meta: dict[str, object]) -> str:
    t = totals(scores)
    out = ["# Story suite", ""]
    out += [f"- {k}: {v}" for k, v in meta.items()]
    out += [f"- expectations met: {t['met']} / {t['total']} ({t['share']:.0%})", "",
            "| scenario | met / total | share |", "|---|---|---|"]  # fmt: skip
    out += [f"| {s.scenario} | {s.met} / {s.total} | {s.share:.2f} |" for s in scores]
    out += ["", "## Verdicts", ""]
    for s in scores:
        out.append(f"### {s.scenario} ({s.met} / {s.total})")
        out += [f"- {'met' if v.met else 'NOT met'} `{v.id}` ({v.kind}): {v.reason}" for v in s.verdicts]
        out.append("")
    return "\n".join(out)
