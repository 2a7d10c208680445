"""The grid of a sweep and the stable id of each of its runs.

A :class:`SweepSpec` (saved as ``sweep.json`` in the sweep folder) names the case sets, the
distraction levels, the repeats, the methods, the models (a resolved run config per model
label), the feedback budget and the seed. :func:`expand` lists its runs in grid order (case
set, case, level, repeat, method, model); a run's id (:attr:`RunKey.run_id`) depends only on
those coordinates, so a restarted sweep recognises the runs it finished.

Methods are the paper's (Table 2): ``ours`` (event narrator + event parser, our describer),
``wo-event`` (one planner call, "w/o Event"), ``object-list`` and ``scene-graph`` (the full
method on a preset scene description) and ``direct`` ("Direct Inference": coordinates instead
of an event program). Each is a variant of the planning graph
(:class:`~storyteller.orchestrator.planning.ablation_graph.Ablation`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer

from storyteller.orchestrator.llm.config import StorytellerConfig
from storyteller.orchestrator.planning.ablation_graph import Ablation
from storyteller.orchestrator.reference_data import DataFolder, ReferenceDataNotFound

METHODS: dict[str, Ablation] = {
    "ours": Ablation(planner="event", description="describer"),
    "wo-event": Ablation(planner="unified", description="describer"),
    "object-list": Ablation(planner="event", description="object-list"),
    "scene-graph": Ablation(planner="event", description="scene-graph"),
    "direct": Ablation(planner="direct", description="describer"),
}
METHOD_TITLES: dict[str, str] = {
    "ours": "Ours", "wo-event": "w/o Event", "object-list": "Object List",
    "scene-graph": "Scene Graph", "direct": "Direct Inference",
}
LEVELS: tuple[int, ...] = (0, 1, 2)
MAX_RUNS = 100_000
"""Runs of one sweep at most (the paper's grid is a few thousand): a ``sweep.json`` asking for
more (a billion repeats took ``bench score`` past 11 s and 1.9 GB) is refused before it is expanded."""
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


class SweepSpecError(ValueError):
    """Arguments that do not make a sweep (unknown method, no model, a level out of range...)."""


def slug(text: str) -> str:
    """``text`` as a file-name-safe token (``local/qwen2.5-coder-0.5b`` -> ``local-qwen2.5-coder-0.5b``)."""
    return _UNSAFE.sub("-", text).strip("-") or "x"


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class CaseSetSpec(_Frozen):
    """A folder of cases in the reference format, and where its reference scenes are."""

    name: str = Field(description="Short name used in run ids and reports (reference, ours, 6_PI...).")
    path: str = Field(description="The case folder (absolute).")
    scenes_root: str | None = Field(
        default=None, description="Folder holding configs/scenes/<Scene> for the cases' non-bundled scenes "
        "(None: every case is on a bundled scene, the reference data is not needed).")
    case_ids: tuple[int, ...] | None = Field(
        default=None, description="Only these cases of the folder (ours-dev / ours-test: one side of the "
        "committed split); None: every case.")

    @model_serializer(mode="wrap")
    def _omit_all_cases(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Without ``case_ids`` when it is None: a sweep.json written before the field existed stays byte for byte."""
        data: dict[str, Any] = handler(self)
        if data.get("case_ids") is None:
            data.pop("case_ids", None)
        return data


class ModelSpec(_Frozen):
    """One point of the model axis: a label and the resolved config (a model per role)."""

    label: str
    config: StorytellerConfig

    @property
    def roles(self) -> dict[str, str]:
        return {name: node.model for name, node in sorted(self.config.nodes.items())}


class SweepSpec(_Frozen):
    """Everything that decides which runs a sweep makes and what each run sends to a model."""

    version: int = 1
    case_sets: tuple[CaseSetSpec, ...]
    case_ids: tuple[int, ...] | None = Field(default=None, description="Only these case ids (None: all).")
    levels: tuple[int, ...] = (2,)
    repeats: int = Field(default=1, ge=1, le=MAX_RUNS)
    seed: int = 0
    methods: tuple[str, ...] = ("ours",)
    models: tuple[ModelSpec, ...]
    feedback: int = Field(default=0, ge=0, description="Retries with feedback per role (max_retries); 0 as in the paper.")
    program_grammar: bool = True

    def decisive(self) -> dict[str, object]:
        """The spec without where things were found (case folders, the config file's path):
        a sweep resumed on another machine, or after the config file moved, is the same sweep."""
        data = self.model_dump(mode="json")
        data["case_sets"] = [c["name"] for c in data["case_sets"]]
        for model in data["models"]:
            model["config"].pop("source", None)
        return data

    def check(self) -> SweepSpec:
        """Raise :class:`SweepSpecError` naming the first bad argument."""
        if unknown := [m for m in self.methods if m not in METHODS]:
            raise SweepSpecError(f"--method {unknown[0]!r}: expected one of {', '.join(METHODS)}")
        if bad := [lv for lv in self.levels if lv not in LEVELS]:
            raise SweepSpecError(f"--level {bad[0]}: expected 0, 1 or 2")
        if not self.models:
            raise SweepSpecError("no model: give --model or --config")
        labels = [m.label for m in self.models]
        if len(set(labels)) != len(labels):
            raise SweepSpecError(f"two models share the label {labels[0]!r}")
        names = [c.name for c in self.case_sets]
        if len(set(names)) != len(names):
            raise SweepSpecError(f"two case sets share the name {names[0]!r}")
        return self

    def model(self, label: str) -> ModelSpec:
        return next(m for m in self.models if m.label == label)

    def case_set(self, name: str) -> CaseSetSpec:
        return next(c for c in self.case_sets if c.name == name)


class RunKey(_Frozen):
    """The coordinates of one run in the grid."""

    case_set: str
    case: int
    level: int
    repeat: int
    method: str
    model: str

    @property
    def run_id(self) -> str:
        return (f"{slug(self.case_set)}-c{self.case:03d}-L{self.level}-r{self.repeat}-"
                f"{self.method}-{slug(self.model)}")


def expand(spec: SweepSpec, case_ids: dict[str, Sequence[int]]) -> list[RunKey]:
    """Every run of ``spec`` in grid order; ``case_ids``: the ids of each case set (loaded).
    :class:`SweepSpecError` when they are more than :data:`MAX_RUNS` (counted first)."""
    count = (sum(len(case_ids[cs.name]) for cs in spec.case_sets) * len(spec.levels) * spec.repeats
             * len(spec.methods) * len(spec.models))
    if count > MAX_RUNS:
        raise SweepSpecError(f"the sweep has {count} runs, more than the {MAX_RUNS} allowed")
    return [
        RunKey(case_set=cs.name, case=cid, level=level, repeat=r, method=method, model=m.label)
        for cs in spec.case_sets
        for cid in case_ids[cs.name]
        for level in spec.levels
        for r in range(spec.repeats)
        for method in spec.methods
        for m in spec.models
    ]


OURS_SPLITS: dict[str, str] = {"ours-dev": "dev", "ours-test": "test"}
"""Case-set names for one side of our pool's committed split (``benchmark/own_cases/split.json``)."""
OURS_REF_SPLITS: dict[str, str] = {"ours-ref-dev": "dev", "ours-ref-test": "test"}
"""The same for our pool on the authors' scenes (``benchmark/cases/ours_ref``,
``benchmark/own_cases/split_ref.json``); they need the reference data."""


def case_set_for(arg: str, reference: DataFolder, ours: Path) -> CaseSetSpec:
    """The case set named on the command line: ``reference`` (the authors' 40 cases), ``ours``
    (``benchmark/cases/ours``, the whole pool), ``ours-dev`` / ``ours-test`` (one side of its
    split: levers are developed on dev only, test is measured), ``ours-ref`` / ``ours-ref-dev`` /
    ``ours-ref-test`` (our generated cases on the authors' scenes, ``ours_ref`` beside ``ours``,
    and their split; they need the reference data) or a folder in the reference format.

    ``reference`` (the lookup of :func:`~storyteller.orchestrator.reference_data.locate_reference`) is
    required only by the case sets that need it: ``reference`` itself, and a folder outside the
    reference data with a case on a scene that is not bundled (``scene_name`` without
    ``bundled:``); then its absence raises :class:`ReferenceDataNotFound` with the lookup's reason.
    A folder inside a checkout of the reference data takes its scenes from that checkout."""
    if arg == "reference":
        found = str(reference.require())
        return CaseSetSpec(name="reference", path=found, scenes_root=found)
    if arg == "ours":
        path = ours.resolve()
        return CaseSetSpec(name="ours", path=str(path), scenes_root=_scenes_root(path, reference))
    if arg in OURS_SPLITS:
        from storyteller.benchmark.own_cases.split import split_ids

        whole = case_set_for("ours", reference, ours)
        return whole.model_copy(update={"name": arg, "case_ids": split_ids(OURS_SPLITS[arg])})
    if (arg == "ours-ref" or arg in OURS_REF_SPLITS) and not reference.found:
        raise ReferenceDataNotFound(f"--cases {arg}: these cases are on the authors' scenes; {reference.reason}")
    if arg == "ours-ref":
        path = (ours.parent / "ours_ref").resolve()
        return CaseSetSpec(name="ours-ref", path=str(path), scenes_root=str(reference.path))
    if arg in OURS_REF_SPLITS:
        from storyteller.benchmark.own_cases.split import split_ids

        whole = case_set_for("ours-ref", reference, ours)
        return whole.model_copy(update={"name": arg, "case_ids": split_ids(OURS_REF_SPLITS[arg], "ours_ref")})
    path = Path(arg).expanduser().resolve()
    if not path.is_dir():
        raise SweepSpecError(f"--cases {arg}: not a folder (expected reference, ours, ours-dev, ours-test, "
                             "ours-ref, ours-ref-dev, ours-ref-test or a case folder)")
    if path == ours.resolve():
        return case_set_for("ours", reference, ours)
    root = next((p for p in (path, *path.parents) if (p / "configs" / "scenes").is_dir()), None)
    if root is None:
        return CaseSetSpec(name=slug(path.name), path=str(path), scenes_root=_scenes_root(path, reference))
    return CaseSetSpec(name="reference" if path == root else slug(path.name), path=str(path), scenes_root=str(root))


def _scenes_root(folder: Path, reference: DataFolder) -> str | None:
    """None when every case in ``folder`` is on a bundled scene; else the reference data
    (:class:`ReferenceDataNotFound` naming the first such case when it is absent)."""
    from storyteller.benchmark.reference_cases import BUNDLED_PREFIX, load_cases

    needs = next((c for c in load_cases(folder) if not c.scene_name.startswith(BUNDLED_PREFIX)), None)
    if needs is None:
        return None
    if not reference.found:
        raise ReferenceDataNotFound(f"{needs.source}: case {needs.id} is on the reference scene "
                                    f"{needs.scene_name!r}; {reference.reason}")
    return str(reference.path)


def model_specs(models: Sequence[str], configs: Sequence[Path]) -> tuple[ModelSpec, ...]:
    """One :class:`ModelSpec` per ``--model`` (every role on that model) and per ``--config``
    (its model per role, labelled by the file's stem); the default config when neither is given."""
    from storyteller.orchestrator.llm.config import load_config

    out = [ModelSpec(label=slug(Path(c).stem), config=load_config(c)) for c in configs]
    for name in models:
        base = load_config(None, env={})
        nodes = {k: v.model_copy(update={"model": name, "fallbacks": ()}) for k, v in base.nodes.items()}
        out.append(ModelSpec(label=name, config=base.model_copy(update={"nodes": nodes, "source": f"--model {name}"})))
    if not out:
        config = load_config(None)
        out.append(ModelSpec(label=config.node("narrator").model, config=config))
    return tuple(out)
