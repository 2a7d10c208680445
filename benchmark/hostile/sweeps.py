"""Attacks on a bench sweep folder and the case files it names, read by ``bench score``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Spec,
    deep_json,
    registrar,
    score,
    victim_intact,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


def _sweep_trace(sweep: Path) -> Path:
    return next((sweep / "traces" / "runs").glob("*.jsonl"))


@attack("bench", "results.jsonl -> file outside")
def _bench_results_link(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(sweep / "results.jsonl", box.victim())
    return Spec(**{**score(box, sweep).__dict__, "check": victim_intact(box)})


@attack("bench", "report.md and plots/ -> outside")
def _bench_report_link(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(sweep / "report.md", box.victim())
    box.link(sweep / "plots", box.outside / "dir")
    return Spec(**{**score(box, sweep, "bad").__dict__, "check": victim_intact(box)})


@attack("bench", "results.csv hard-linked outside")
def _bench_csv_hardlink(box: Box) -> Spec:
    sweep = box.copy_sweep()
    (sweep / "results.csv").unlink()
    os.link(box.victim(), sweep / "results.csv")
    return Spec(**{**score(box, sweep, "either").__dict__, "check": victim_intact(box)})


@attack("bench", "run trace -> /dev/zero")
def _bench_trace_zero(box: Box) -> Spec:
    sweep = box.copy_sweep()
    box.link(_sweep_trace(sweep), "/dev/zero")
    return score(box, sweep)


@attack("bench", "run trace nested 100,000 deep")
def _bench_trace_deep(box: Box) -> Spec:
    sweep = box.copy_sweep()
    _sweep_trace(sweep).write_text(deep_json(100_000) + "\n", encoding="utf-8")
    return score(box, sweep)


@attack("bench", "a case named testcase_one.json and one not UTF-8")
def _bench_cases(box: Box) -> Spec:
    sweep = box.copy_sweep()
    cases = box.root / "cases" / "0_OA"
    cases.mkdir(parents=True)
    (cases / "testcase_one.json").write_text("{}", encoding="utf-8")
    (cases / "testcase_100.json").write_bytes(b'{"scene_name": "\xff\xfe"}')
    box.edit_json(sweep / "sweep.json", lambda v: {**v, "case_sets": [{**v["case_sets"][0], "path": str(cases.parent)}]})
    return score(box, sweep)


@attack("bench", "sweep.json: a 5,000-digit case id and duplicate keys")
def _bench_spec_digits(box: Box) -> Spec:
    sweep = box.copy_sweep()
    text = (sweep / "sweep.json").read_text(encoding="utf-8")
    text = text.replace('"case_ids": [', '"case_ids": [' + "9" * 5000 + ", ", 1)
    (sweep / "sweep.json").write_text(text, encoding="utf-8")
    return score(box, sweep)


@attack("bench", "description FIFO and results.jsonl line of escapes")
def _bench_fifo(box: Box) -> Spec:
    sweep = box.copy_sweep()
    for desc in (sweep / "descriptions").glob("*.json"):
        box.fifo(desc)
    with open(sweep / "results.jsonl", "a", encoding="utf-8") as f:
        f.write(json.dumps({"run_id": BIDI * 3}) + "\n")
    return score(box, sweep)
