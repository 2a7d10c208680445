"""``run.json``: what a run folder was made with, so it can be resumed or replayed.

``storyteller run`` writes it before the first frame (thread id, scene, config, seed and
every argument, with file paths made absolute); ``storyteller resume RUN_DIR`` and
``storyteller replay RUN_DIR`` read it back and rebuild the same run, so neither needs the
original command line.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from storyteller.orchestrator.planning.kinds import DescriptionKind, PlannerKind
from storyteller.orchestrator.session.instruction_script import ScriptLine
from storyteller.orchestrator.session.pace import MAX_RUN_SPEED, MIN_SPEED, Pace
from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes
from storyteller.sim.no_follow_writes import write_file
from storyteller.sim.run_folder_names import RUN_JSON
from storyteller.sim.validation_text import user_error

MANIFEST_FILE = RUN_JSON
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]{0,31}$")
MAX_MANIFEST_BYTES = 16 << 20
"""Bytes of the largest ``run.json`` read back (it holds the arguments and the instruction script)."""
_MAX_DEPTH = 8  # JSON nesting of run.json at most (it has 3: a script line in ``arguments.instructions``)


MAX_CHARACTERS = 24
"""Characters of one run at most (``--characters``, ``--names``, ``run.json``, ``story.json``)."""
MAX_SEED = 2**64
"""Seeds are 64-bit unsigned integers (numpy's generators refuse a negative one)."""
MAX_DURATION_S = 9_000.0
"""Simulated seconds of a run at most (2.5 h): one character's chunk file, about 826 bytes a frame
at 30 fps, then stays under what a reader takes (``storyteller.sim.world.track_chunks.MAX_CHUNK_FILE_BYTES``,
256 MiB: 223 MB), so ``resume`` and ``view`` never refuse the motion a run wrote."""
MAX_CHARACTER_SECONDS = 36_000.0
"""Simulated seconds times characters at most (10 character-hours): the run's chunk files together
stay under ``storyteller.sim.world.track_chunks.MAX_RUN_CHUNK_BYTES`` (1 GiB: 0.89 GB)."""


class ManifestError(Exception):
    """A run folder without a readable ``run.json`` (the message names the file and the field)."""


class RunArguments(BaseModel):
    """The arguments of ``storyteller run`` that decide the story (paths absolute; numbers finite)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    scene: str = Field(description="Bundled scene name or absolute path to a scene file.")
    names: tuple[str, ...] = Field(min_length=1, max_length=MAX_CHARACTERS, description="Character names, in order.")
    instruction: str = ""
    instructions: tuple[ScriptLine, ...] = Field(
        default=(), description="The timed script of ``--instructions FILE``, as read when the run started."
    )
    duration: float = Field(gt=0, description="Simulated seconds.")
    pace: Pace = "lockstep"
    speed: float = Field(default=1.0, ge=MIN_SPEED, le=MAX_RUN_SPEED,
                         description="Simulated seconds per wall second (realtime).")
    planners: int = Field(default=1, ge=1, le=8, description="Planning steps in flight at most (1: one at a time).")
    offline_latency: float | None = Field(
        default=None, ge=0, description="offline pace: simulated seconds per LLM call (None: each call's own latency)."
    )
    max_events: int | None = Field(default=None, ge=1)
    config: str | None = None
    motion_config: str | None = None
    seed: int = Field(default=0, ge=0, lt=MAX_SEED)
    max_retries: int = Field(default=3, ge=0, le=10)
    program_grammar: bool = True
    foot_ik: bool = True
    planner: PlannerKind = "event"
    description: DescriptionKind = "describer"
    video: bool = False
    gif: bool = False

    @model_validator(mode="after")
    def _motion_fits_the_readers(self) -> RunArguments:
        """A run never writes more motion than ``resume`` and ``view`` read back (see the caps)."""
        if self.duration > MAX_DURATION_S:
            raise ValueError(f"duration {self.duration:g} s is longer than the {MAX_DURATION_S:g} s a run may last")
        if self.duration * len(self.names) > MAX_CHARACTER_SECONDS:
            raise ValueError(f"{len(self.names)} characters for {self.duration:g} s is more than the "
                             f"{MAX_CHARACTER_SECONDS:g} character-seconds a run may hold")
        if self.offline_latency is not None and self.offline_latency > MAX_DURATION_S:
            raise ValueError(f"offline latency {self.offline_latency:g} s is longer than a run may last")
        return self


class RunManifest(BaseModel):
    """``run.json``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    version: Literal[1] = 1
    thread_id: str = Field(description="Planning thread in runs.sqlite (checkpoints and story log).")
    scene_name: str
    seed: int = Field(ge=0, lt=MAX_SEED)
    config: str | None
    arguments: RunArguments


def parse_names(text: str) -> tuple[str, ...]:
    """``--names A,B,..``: distinct names of a letter then letters, digits, ``_`` or ``-``."""
    names = tuple(n.strip() for n in text.split(","))
    bad = [n for n in names if not _NAME.match(n)]
    if bad:
        raise ValueError(
            f"--names: {bad[0]!r} is not a name (expected a letter, then up to 31 letters, digits, _ or -)"
        )
    if len({n.lower() for n in names}) != len(names):  # they name files: Zoe.bvh and zoe.bvh are one on some disks
        raise ValueError("--names: every name must be different (letter case aside: each names the character's files)")
    return names


def absolute(path: Path | None) -> str | None:
    return None if path is None else str(path.expanduser().resolve())


def write_manifest(out: Path, manifest: RunManifest) -> Path:
    """``out/run.json``, written to a fresh temporary name and renamed over it (a symbolic link
    planted there is replaced, never written through: ``storyteller.sim.no_follow_writes``)."""
    return write_file(out / MANIFEST_FILE, (manifest.model_dump_json(indent=2) + "\n").encode("utf-8"))


def read_manifest(run_dir: Path) -> RunManifest:
    """``run_dir/run.json``, read within :data:`MAX_MANIFEST_BYTES` and validated;
    :class:`ManifestError` (one line naming the file and the field) otherwise."""
    path = run_dir / MANIFEST_FILE
    if not path.exists() and not path.is_symlink():  # a link to /dev/zero is read (and refused), not "missing"
        raise ManifestError(f"{path}: no run.json (is {run_dir} a folder written by `storyteller run`?)")
    try:
        data = read_bounded_bytes(path, MAX_MANIFEST_BYTES, str(path))
    except BoundedFileError as exc:
        raise ManifestError(str(exc)) from None
    return parse_manifest(data, str(path))


def parse_manifest(data: bytes, where: str) -> RunManifest:
    """The manifest in the bytes of a ``run.json`` (``where`` names it in errors)."""
    try:
        raw = load_bounded_json(data, _MAX_DEPTH, where)
    except BoundedFileError as exc:
        raise ManifestError(str(exc)) from None
    try:
        return RunManifest.model_validate(raw)
    except ValidationError as exc:
        raise ManifestError(user_error(where, exc)) from None


def manifest_bytes(manifest: RunManifest, path: Path) -> bytes:
    """The bytes of ``run.json`` for ``manifest``, once they read back (:func:`parse_manifest`)
    as the same manifest: a run never writes a ``run.json`` that ``resume`` or ``replay`` would
    refuse (too large, a number or a text JSON cannot hold); :class:`ManifestError` otherwise."""
    try:
        data = (manifest.model_dump_json(indent=2) + "\n").encode("utf-8")
    except (ValueError, UnicodeError) as exc:  # a lone surrogate in a text
        raise ManifestError(f"{path}: the run's arguments cannot be stored ({str(exc)[:200]})") from None
    if len(data) > MAX_MANIFEST_BYTES:
        raise ManifestError(
            f"{path}: the run's arguments take {len(data)} bytes, more than the {MAX_MANIFEST_BYTES} a run.json "
            "may hold (a shorter instruction or script)"
        )
    try:
        back = parse_manifest(data, str(path))
    except ManifestError as exc:
        raise ManifestError(f"the run's arguments would not read back from run.json: {exc}") from None
    if back != manifest:
        raise ManifestError(f"{path}: the run's arguments would not read back the same from run.json")
    return data


def resume_command(run_dir: Path) -> str:
    return f"storyteller resume {shlex.quote(str(run_dir))}"
