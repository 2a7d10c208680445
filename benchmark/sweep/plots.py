"""The sweep's PNG plots (matplotlib, Agg backend, no metadata: same results, same bytes).

- ``success_by_characters.png``: success rate against the number of characters in the case,
  one line per model and method;
- ``tokens_by_description.png``: mean prompt and completion tokens per call, per
  scene-description type and role (stacked bars).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from storyteller.benchmark.sweep.grid import METHOD_TITLES
from storyteller.benchmark.sweep.results import RunResult, write_atomic
from storyteller.benchmark.sweep.sweep_files import sweep_folder

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_META = {"Software": None}  # no matplotlib version in the file


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata=_META)
    return buf.getvalue()


def success_plot(results: Sequence[RunResult]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for model, method in dict.fromkeys((r.model, r.method) for r in results):
        mine = [r for r in results if r.model == model and r.method == method]
        xs = sorted({r.characters for r in mine})
        ys = [sum(r.verdict == "pass" for r in mine if r.characters == x) / sum(1 for r in mine if r.characters == x)
              for x in xs]
        ax.plot(xs, ys, marker="o", label=f"{model} / {METHOD_TITLES.get(method, method)}")
    ax.set_xlabel("characters in the case")
    ax.set_ylabel("success rate")
    ax.set_ylim(-0.05, 1.05)
    if results:
        ax.legend(fontsize=7)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def tokens_plot(results: Sequence[RunResult]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels, prompt, completion = [], [], []
    for desc in dict.fromkeys(r.description for r in results):
        for node in dict.fromkeys(c.node for r in results if r.description == desc for c in r.calls):
            calls = [c for r in results if r.description == desc for c in r.calls if c.node == node]
            labels.append(f"{desc}\n{node}")
            prompt.append(sum(c.prompt_tokens for c in calls) / len(calls))
            completion.append(sum(c.completion_tokens for c in calls) / len(calls))
    fig, ax = plt.subplots(figsize=(max(4, 1.4 * len(labels)), 4))
    xs = list(range(len(labels)))
    ax.bar(xs, prompt, label="prompt")
    ax.bar(xs, completion, bottom=prompt, label="completion")
    ax.set_xticks(xs, labels, fontsize=7)
    ax.set_ylabel("tokens per call")
    ax.legend(fontsize=7)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def write_plots(folder: Path, results: Sequence[RunResult]) -> None:
    sweep_folder(folder.parent, folder.name)
    write_atomic(folder / "success_by_characters.png", success_plot(results))
    write_atomic(folder / "tokens_by_description.png", tokens_plot(results))
