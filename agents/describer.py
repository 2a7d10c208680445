"""The describer: scene graph + clusters -> a description organised by functional areas.

The model answers JSON ``{"areas": [{"name", "purpose", "objects": [...]}]}`` whose object
names are restricted to the scene's (an enum in the schema); :func:`parse_areas` then checks
that every object is named exactly once (missing or repeated names are fed back for another
try). If the last try still misses objects, :func:`repair_areas` completes it from the
clusters (each missing object joins the area holding most of its cluster, else an "other
objects" area) and the result is flagged ``repaired``. The text the other agents read is
rendered by :func:`render_description`, one line per area, with supports (``on counter_1``).

In regions mode (small local models) the model instead answers one entry per region (cluster)
``{"regions": [{"region": 1, "area", "purpose"}, ...]}``; the schema pins the entries' region
numbers (1..n, in order), so under grammar decoding every region appears exactly once and the
answer needs no rejected attempt; regions named alike form one area. Each entry's area name and
purpose are chosen from the ones the room table (``storyteller.agents.area_fit.region_choices``) gives its
region, so a grammar-decoded answer names a couch and a TV a living room, never a dining area.

Both modes: an answer whose area names or purposes do not fit their objects by the room table
(``storyteller.agents.area_fit``) is rejected with feedback naming the kinds that would fit; if the last
try still disagrees, the misfits are renamed from the table (:func:`best_effort`).

Descriptions are cached on disk per (scene content, model, prompt files) hash.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, JsonValue

from storyteller.agents.area_fit import area_problems_by_table, fitting_kinds, region_choices, rule_areas
from storyteller.agents.llm_port import ChatMessage, LLMPort, LLMRequest
from storyteller.agents.llm_schemas import Refine, reply_schema
from storyteller.agents.messages import SceneDescription
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.retry_feedback import (
    AnswerRejectedError,
    RetriesExhaustedError,
    Turn,
    feedback_from_error,
    retry_temperature,
    with_turns,
)
from storyteller.agents.room_table import ROOMS_FILE, room_table
from storyteller.sim.bounded_files import load_bounded_json, read_bounded_bytes
from storyteller.sim.scene.model import Scene
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph
from storyteller.tools.scene_text import clusters_text, scene_graph_json

DESCRIBER_FILES = (
    "describer/system.md",
    "describer/request.md",
    "describer/system_regions.md",
    "describer/request_regions.md",
    "describer/region_choices.md",
    ROOMS_FILE,
)
MAX_AREAS = 8
"""Areas a reply may have (the schema's bound; the parser accepts twice as many, so an
over-long answer from a provider without schema decoding still gets precise feedback and can
be repaired)."""
MAX_REGIONS = 64
"""Regions a regions-mode reply may name (the schema pins the scene's own count)."""
MAX_AREA_NAME_CHARS = 40
MAX_PURPOSE_CHARS = 80
DEFAULT_MAX_TOKENS = 420


class Area(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(max_length=MAX_AREA_NAME_CHARS, description="Short area name, e.g. 'kitchen'.")
    purpose: str = Field(default="", max_length=MAX_PURPOSE_CHARS, description="What people do there.")
    objects: tuple[str, ...] = Field(description="Names of the objects in this area.")


class AreaList(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    areas: tuple[Area, ...] = Field(max_length=MAX_AREAS * 2)


class RegionName(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    region: int = Field(description="The region's number.")
    area: str = Field(
        min_length=1, max_length=MAX_AREA_NAME_CHARS,
        description="Short name of the area the region belongs to; regions of one area share it.",
    )
    purpose: str = Field(default="", max_length=MAX_PURPOSE_CHARS, description="What people do there.")


class RegionNaming(BaseModel):
    """A regions-mode reply: one entry per region, in region order (the schema pins each
    entry's number, so a grammar-decoded answer always covers every region exactly once)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    regions: tuple[RegionName, ...] = Field(max_length=MAX_REGIONS)


@dataclass(frozen=True)
class DescriberInput:
    """Scene data the describer reads (texts from ``tools.scene_text``)."""

    scene_name: str
    object_names: tuple[str, ...]
    scene_graph_json: str
    clusters: tuple[tuple[str, ...], ...]
    supports: Mapping[str, str]
    """object name -> name of the object it stands on or is inside (absent: on the floor)."""
    mode: Literal["objects", "regions"] = "objects"
    """objects: the model lists every object; regions: the model names the area of each
    cluster (numbered region), one entry per region in order, and the objects follow from
    them, so a small model writes ~5x fewer tokens and cannot leave a region out."""
    labels: Mapping[str, str] = field(default_factory=dict)
    """object name -> its label (absent: the name without its ``_<idx>`` suffix)."""

    def label_of(self, name: str) -> str:
        if name in self.labels:
            return self.labels[name]
        base, _, idx = name.rpartition("_")
        return base if base and idx.isdigit() else name

    @property
    def all_labels(self) -> dict[str, str]:
        """object name -> label, for every object of the scene."""
        return {n: self.label_of(n) for n in self.object_names}


COMPACT_RELATIONS = ("on", "inside", "adjacent to")


def compact_scene_graph_json(graph: SceneGraph) -> str:
    """The scene graph reduced to what grouping needs: object -> its support and adjacency
    relations (no coordinates). About a quarter of the full JSON's size, which matters for a
    0.5B model reading ~100 tokens/s."""
    out: dict[str, list[str]] = {}
    for obj in graph.scene.objects:
        out[obj.name] = [f"{r} {a}" for r, a in graph.relations_of(obj.name) if r in COMPACT_RELATIONS]
    return json.dumps(out, separators=(",", ":"))


def describer_input_from_scene(
    scene: Scene,
    graph: SceneGraph | None = None,
    *,
    full_graph: bool = False,
    mode: Literal["objects", "regions"] = "objects",
) -> DescriberInput:
    """Build the describer's input with the scene-graph and cluster tools.

    ``full_graph=True`` gives the model the whole scene graph JSON (positions, sizes, every
    relation); the default compact form suits small local models."""
    graph = graph or build_scene_graph(scene)
    supports = {n: s for n in scene.object_names if (s := graph.supporter(n)) is not None}
    clusters = tuple(tuple(c) for c in cluster_objects(scene))
    return DescriberInput(
        scene_name=scene.name,
        object_names=tuple(scene.object_names),
        scene_graph_json=scene_graph_json(graph) if full_graph else compact_scene_graph_json(graph),
        clusters=clusters,
        supports=supports,
        mode=mode,
        labels={o.name: o.label for o in scene.objects},
    )


def describer_schema(names: Sequence[str]) -> dict[str, Any]:
    """Schema of an objects-mode reply: at most MAX_AREAS areas, each naming scene objects."""
    return reply_schema(
        AreaList,
        {
            "areas": Refine(min_items=1, max_items=MAX_AREAS),
            "areas.objects": Refine(enum=names, min_items=1, max_items=len(names)),
        },
    )


RegionChoices = tuple[tuple[str, ...], tuple[str, ...]]
"""A region's area names and purposes (best first), from :func:`storyteller.agents.area_fit.region_choices`."""


def describer_regions_schema(
    n_regions: int, choices: Sequence[RegionChoices] | None = None, prompts: PromptLibrary | None = None
) -> dict[str, Any]:
    """Schema of a regions-mode reply: exactly one entry per region 1..n_regions, in order,
    each entry's region number fixed. Entry ``i``'s area name is one of ``choices[i]``'s names
    and its purpose one of its purposes (without ``choices``: any kind of the room table, a
    free purpose)."""
    kinds = tuple(room_table(prompts).kinds)
    schema = reply_schema(RegionNaming, {
        "regions.area": Refine(enum=kinds),
        "regions": Refine(pin=("region", range(1, n_regions + 1))),
    })
    for entry, (names, purposes) in zip(schema["properties"]["regions"]["prefixItems"], choices or (), strict=False):
        props = entry["properties"]  # one region's own choices: each entry a copy (see _pin)
        props["area"] = {**props["area"], "enum": list(names or kinds)}
        if purposes:
            props["purpose"] = {**props["purpose"], "enum": list(purposes)}
    return schema


def regions_choices(inp: DescriberInput, prompts: PromptLibrary | None = None) -> list[RegionChoices]:
    """Every region's area names and purposes by the room table; a region whose objects say
    nothing about the room (a lone plant) may take the names the other regions fit."""
    table = room_table(prompts)
    labels = [[inp.label_of(n) for n in c] for c in inp.clusters]
    scene_kinds = tuple(dict.fromkeys(k for labs in labels for k in fitting_kinds(labs, table)))
    return [region_choices(labs, scene_kinds, table) for labs in labels]


def regions_max_tokens(n_regions: int) -> int:
    """Token budget of a regions-mode reply: about 50 tokens per entry at the string limits."""
    return max(DEFAULT_MAX_TOKENS, 40 + 50 * n_regions)


def describer_request(
    prompts: PromptLibrary, inp: DescriberInput, turns: tuple[Turn, ...] = (), *, max_tokens: int = DEFAULT_MAX_TOKENS
) -> LLMRequest:
    regions = clusters_text([list(c) for c in inp.clusters]) or prompts.render_text("describer/no_regions.md")
    if inp.mode == "regions":
        choices = regions_choices(inp, prompts)
        lines = [
            prompts.render_text(
                "describer/region_choices.md", number=k, objects=", ".join(c), kinds=", ".join(names),
                purposes=" / ".join(purposes),
            )
            for k, (c, (names, purposes)) in enumerate(zip(inp.clusters, choices, strict=True), start=1)
        ]
        system = prompts.render("describer/system_regions.md")
        user = prompts.render(
            "describer/request_regions.md",
            scene_graph=inp.scene_graph_json.strip(),
            regions="\n".join(lines) or prompts.render_text("describer/no_regions.md"),
            count=len(inp.clusters),
        )
        schema = describer_regions_schema(len(inp.clusters), choices, prompts)
        max_tokens = max(max_tokens, regions_max_tokens(len(inp.clusters)))
    else:
        system = prompts.render("describer/system.md")
        user = prompts.render(
            "describer/request.md",
            scene_graph=inp.scene_graph_json.strip(),
            clusters=regions,
            count=len(inp.object_names),
            names=", ".join(inp.object_names),
        )
        schema = describer_schema(inp.object_names)
    base = (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))
    return LLMRequest(
        node="describer",
        messages=with_turns(base, turns),
        json_schema=schema,
        max_tokens=max_tokens,
        seed=0,
        temperature=retry_temperature(turns),
    )


def region_problems(naming: RegionNaming, n_regions: int, prompts: PromptLibrary | None = None) -> list[str]:
    """Entries that are not regions 1..n_regions in order (only possible without a grammar)."""
    lib = prompts or package_prompts()
    got = [r.region for r in naming.regions]
    if got == list(range(1, n_regions + 1)):
        return []
    listed = ", ".join(map(str, got)) or lib.render_text("feedback/none.md")
    return [lib.render_text("feedback/describer/region_order.md", count=n_regions, got=listed)]


def _area_key(name: str) -> str:
    return " ".join(name.lower().split())


def regions_to_areas(naming: RegionNaming, inp: DescriberInput) -> AreaList:
    """Regions named alike become one area (in order of first mention; the first non-empty
    purpose); its objects are its regions' objects in region order. Unknown or repeated
    region numbers are skipped."""
    grouped: dict[str, tuple[str, str, list[str]]] = {}
    seen: set[int] = set()
    for r in naming.regions:
        if not 1 <= r.region <= len(inp.clusters) or r.region in seen:
            continue
        seen.add(r.region)
        name, purpose, objects = grouped.setdefault(_area_key(r.area), (r.area.strip(), "", []))
        grouped[_area_key(r.area)] = (name, purpose or r.purpose.strip(), [*objects, *inp.clusters[r.region - 1]])
    return AreaList(areas=tuple(Area(name=n, purpose=p, objects=tuple(o)) for n, p, o in grouped.values()))


def _json_blob(text: str) -> JsonValue:
    start, end = text.find("{"), text.rfind("}")
    value: JsonValue = json.loads(text[start : end + 1] if 0 <= start < end else text)
    return value


def load_areas(text: str, inp: DescriberInput | None = None) -> AreaList:
    """Parse a reply of either mode into objects per area (no completeness check)."""
    if inp is not None and inp.mode == "regions":
        return regions_to_areas(RegionNaming.model_validate(_json_blob(text)), inp)
    return AreaList.model_validate(_json_blob(text))


def area_problems(areas: AreaList, names: Sequence[str], prompts: PromptLibrary | None = None) -> list[str]:
    """Missing, repeated and unknown object names (empty when the answer is complete); the
    sentences are ``prompts/feedback/describer/*.md``."""
    lib = prompts or package_prompts()
    counts = Counter(n for a in areas.areas for n in a.objects)
    known = set(names)
    problems = []
    unknown = sorted(n for n in counts if n not in known)
    repeated = sorted(n for n, k in counts.items() if k > 1 and n in known)
    missing = [n for n in names if n not in counts]
    if unknown:
        problems.append(lib.render_text("feedback/describer/unknown_objects.md", names=", ".join(unknown)))
    if repeated:
        problems.append(lib.render_text("feedback/describer/repeated_objects.md", names=", ".join(repeated)))
    if missing:
        problems.append(lib.render_text("feedback/describer/missing_objects.md", names=", ".join(missing)))
    if len(areas.areas) > MAX_AREAS:
        problems.append(lib.render_text("feedback/describer/too_many_areas.md", limit=MAX_AREAS))
    return problems


def parse_areas(text: str, names: Sequence[str]) -> AreaList:
    """Check a reply; raises JSONDecodeError, ValidationError or AnswerRejectedError."""
    areas = load_areas(text)
    problems = area_problems(areas, names)
    if problems:
        raise AnswerRejectedError(problems)
    return areas


def repair_areas(areas: AreaList, inp: DescriberInput, prompts: PromptLibrary | None = None) -> AreaList:
    """Complete an answer: unknown names dropped, repeats kept at their first area,
    missing objects added to the area holding most of their cluster (else an area named by
    ``prompts/describer/other_area.md``)."""
    known = set(inp.object_names)
    seen: set[str] = set()
    kept: list[tuple[str, str, list[str]]] = []
    for a in areas.areas[:MAX_AREAS]:
        objs = []
        for n in a.objects:
            if n in known and n not in seen:
                seen.add(n)
                objs.append(n)
        kept.append((a.name, a.purpose, objs))
    area_of = {n: i for i, (_, _, objs) in enumerate(kept) for n in objs}
    cluster_of = {n: c for c in inp.clusters for n in c}
    other: list[str] = []
    for name in inp.object_names:
        if name in seen:
            continue
        votes = Counter(area_of[m] for m in cluster_of.get(name, ()) if m in area_of)
        if votes:
            idx = min(votes, key=lambda i: (-votes[i], i))
            kept[idx][2].append(name)
            area_of[name] = idx
        else:
            other.append(name)
        seen.add(name)
    result = [Area(name=n, purpose=p, objects=tuple(o)) for n, p, o in kept if o]
    if other:
        name = (prompts or package_prompts()).render_text("describer/other_area.md")
        result.append(Area(name=name, purpose="", objects=tuple(other)))
    return AreaList(areas=tuple(result))


def render_description(areas: AreaList, supports: Mapping[str, str], prompts: PromptLibrary | None = None) -> str:
    """One line per area, each object named exactly once; objects standing on another object
    of the same area are listed with it: ``- kitchen (make coffee): fridge_1, cabinet_1 (with
    coffee_maker_1, toaster_1 on it)`` (``prompts/describer/area_line*.md``, ``carrier.md``)."""
    lib = prompts or package_prompts()
    lines = []
    for a in areas.areas:
        members = set(a.objects)
        carried: dict[str, list[str]] = {}
        for n in a.objects:
            base = supports.get(n)
            if base is not None and base in members and base != n:
                carried.setdefault(base, []).append(n)
        # one level of nesting only: an object that carries others stays at the top level
        carried = {b: kept for b, g in carried.items() if (kept := [n for n in g if n not in carried])}
        nested = {n for group in carried.values() for n in group}
        parts = []
        for n in a.objects:
            if n in nested:
                continue
            if n in carried:
                parts.append(lib.render_text("describer/carrier.md", name=n, carried=", ".join(carried[n])))
            else:
                parts.append(n)
        name, purpose, objects = a.name.strip(), a.purpose.strip(), ", ".join(parts)
        if purpose:
            lines.append(lib.render_text("describer/area_line_with_purpose.md", name=name, purpose=purpose, objects=objects))
        else:
            lines.append(lib.render_text("describer/area_line.md", name=name, objects=objects))
    return "\n".join(lines)


def cache_key(scene: Scene, model: str, prompts: PromptLibrary) -> str:
    digest = hashlib.sha256()
    digest.update(scene.model_dump_json().encode())
    digest.update(b"\0" + model.encode() + b"\0")
    digest.update(prompts.fingerprint(DESCRIBER_FILES).encode())
    return digest.hexdigest()[:24]


def cache_path(cache_dir: Path, scene: Scene, model: str, prompts: PromptLibrary) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in scene.name)
    return Path(cache_dir) / f"description-{safe}-{cache_key(scene, model, prompts)}.json"


def description_cache_file(
    cache_dir: Path, scene: Scene, model: str, mode: Literal["objects", "regions"], prompts: PromptLibrary
) -> Path:
    """Where the description of ``scene`` by ``model`` in ``mode`` is cached."""
    return cache_path(cache_dir, scene, f"{model}|{mode}", prompts)


MAX_CACHE_BYTES = 1 << 20
"""A cached description larger than this (bytes) is not read: it is a miss, described again
(a 500-object scene's description is about 20 KB)."""


def read_cached(path: Path) -> SceneDescription | None:
    """The description cached at ``path``, or None: no file, not a regular file, larger than
    :data:`MAX_CACHE_BYTES`, or not a description."""
    try:
        data = read_bounded_bytes(path, MAX_CACHE_BYTES, str(path))
        return SceneDescription.model_validate(load_bounded_json(data, 8, str(path)))
    except (OSError, ValueError):  # BoundedFileError and ValidationError are ValueErrors
        return None


def write_cached(path: Path, description: SceneDescription) -> None:
    """Atomic write (temp file + rename), so a crash never leaves a torn cache file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(description.model_dump_json(), encoding="utf-8")
    os.replace(tmp, path)


@dataclass(frozen=True)
class DescriberAttempt:
    """The outcome of one describer call: accepted areas, or feedback for the next call."""

    areas: AreaList | None
    turn: Turn | None
    error: Exception | None = None
    """The typed error that rejected the reply (JSONDecodeError, ValidationError, AnswerRejectedError)."""


def fit_problems(areas: AreaList, inp: DescriberInput, prompts: PromptLibrary | None = None) -> list[str]:
    """Areas whose name or purpose does not fit their objects by the room table (``storyteller.agents.area_fit``)."""
    return area_problems_by_table([(a.name, a.purpose, a.objects) for a in areas.areas], inp.all_labels, prompts=prompts)


def fit_by_rule(areas: AreaList, inp: DescriberInput, prompts: PromptLibrary | None = None) -> AreaList:
    """``areas`` with every misfit renamed from the room table (best fitting kind, the labels' functions)."""
    renamed = rule_areas([(a.name, a.purpose, a.objects) for a in areas.areas], inp.all_labels, room_table(prompts))
    merged: dict[str, tuple[str, str, tuple[str, ...]]] = {}  # areas renamed alike become one
    for n, p, o in renamed:
        name, purpose, objects = merged.get(_area_key(n), (n, p, ()))
        merged[_area_key(n)] = (name, purpose or p, (*objects, *o))
    return AreaList(areas=tuple(Area(name=n, purpose=p, objects=o) for n, p, o in merged.values()))


def parse_reply(reply: str, inp: DescriberInput, prompts: PromptLibrary | None = None) -> AreaList:
    """Check a reply of ``inp.mode``: complete, then fitting its objects (:func:`fit_problems`);
    raises JSONDecodeError, ValidationError or AnswerRejectedError."""
    if inp.mode == "regions":
        naming = RegionNaming.model_validate(_json_blob(reply))
        problems = region_problems(naming, len(inp.clusters), prompts)
        if problems:
            raise AnswerRejectedError(problems)
        areas = regions_to_areas(naming, inp)
    else:
        areas = parse_areas(reply, inp.object_names)
    problems = fit_problems(areas, inp, prompts)
    if problems:
        raise AnswerRejectedError(problems)
    return areas


def judge_reply(reply: str, inp: DescriberInput, prompts: PromptLibrary | None = None) -> DescriberAttempt:
    try:
        return DescriberAttempt(areas=parse_reply(reply, inp, prompts), turn=None)
    except (ValueError, AnswerRejectedError) as exc:  # JSONDecodeError and ValidationError are ValueErrors
        feedback = feedback_from_error(exc, prompts=prompts)
        return DescriberAttempt(areas=None, turn=Turn(reply=reply, feedback=feedback), error=exc)


def finish(inp: DescriberInput, areas: AreaList, *, repaired: bool, attempts: int) -> SceneDescription:
    return SceneDescription(
        scene=inp.scene_name,
        text=render_description(areas, inp.supports),
        source="describer",
        repaired=repaired,
        attempts=attempts,
    )


def best_effort_areas(inp: DescriberInput, turns: Sequence[Turn]) -> AreaList:
    """After the last rejected try: the last parseable answer completed from the clusters (or
    the clusters named by the room table when none parses), its misfits renamed by the table."""
    for turn in reversed(turns):
        try:
            areas = load_areas(turn.reply, inp)
        except ValueError:
            continue
        return fit_by_rule(repair_areas(areas, inp), inp)
    return fit_by_rule(repair_areas(rule_made_areas(inp), inp), inp)


def best_effort(inp: DescriberInput, turns: Sequence[Turn]) -> SceneDescription:
    """The description of :func:`best_effort_areas` (flagged ``repaired``)."""
    return finish(inp, best_effort_areas(inp, turns), repaired=True, attempts=len(turns))


def rule_made_areas(inp: DescriberInput, prompts: PromptLibrary | None = None) -> AreaList:
    """Areas from the clusters alone: each region takes its best area name and purpose by the
    room table; regions named alike form one area (no answer of the model was usable)."""
    naming = RegionNaming(regions=tuple(
        RegionName(region=k, area=names[0] if names else "other", purpose=purposes[0] if purposes else "")
        for k, (names, purposes) in enumerate(regions_choices(inp, prompts), start=1)
    ))
    return regions_to_areas(naming, inp)


async def describe_scene(
    port: LLMPort,
    prompts: PromptLibrary,
    inp: DescriberInput,
    *,
    max_retries: int = 3,
    max_tokens: int = DEFAULT_MAX_TOKENS,
    repair: bool = True,
) -> SceneDescription:
    """Describe a scene: a first try plus at most ``max_retries`` retries, then repair.

    With ``repair=False`` an answer that stays incomplete raises RetriesExhaustedError.
    """
    turns: tuple[Turn, ...] = ()
    for attempt in range(1, max_retries + 2):
        response = await port.complete(describer_request(prompts, inp, turns, max_tokens=max_tokens))
        judged = judge_reply(response.text, inp, prompts)
        if judged.areas is not None:
            return finish(inp, judged.areas, repaired=False, attempts=attempt)
        assert judged.turn is not None
        turns = (*turns, judged.turn)
    if not repair:
        raise RetriesExhaustedError("describer", len(turns), turns[-1].feedback)
    return best_effort(inp, turns)


async def describe_scene_cached(
    port: LLMPort,
    prompts: PromptLibrary,
    scene: Scene,
    *,
    model: str,
    cache_dir: Path | None,
    inp: DescriberInput | None = None,
    mode: Literal["objects", "regions"] = "objects",
    max_retries: int = 3,
) -> SceneDescription:
    """:func:`describe_scene` with an on-disk cache (``cache_dir=None``: no cache)."""
    path = description_cache_file(cache_dir, scene, model, mode, prompts) if cache_dir is not None else None
    if path is not None and (hit := read_cached(path)) is not None:
        return hit
    inp = inp or describer_input_from_scene(scene, mode=mode)
    description = await describe_scene(port, prompts, inp, max_retries=max_retries)
    if path is not None:
        write_cached(path, description)
    return description
