"""TOML config mapping real mocap clips (BVH or AMASS npz) to action labels.

Example::

    root = "../shared/mocap"          # optional; relative to this file
    replace_procedural = true         # imported clips replace generated ones of their label

    [[clips]]
    file = "cmu/daz/05_01.bvh"        # relative to root
    label = "walk"
    start = 1                         # first source frame (skip a T-pose), default 0
    end = 500                         # exclusive, default: to the end
    fps = 120                         # override the file's frame rate
    seated = false                    # file it under the seated variant of the label
    loops = false
    mapping = { spine3 = "chest" }    # BVH joint-name overrides (our name = file name)

The file is read within ``MAX_MOTION_CONFIG_BYTES`` (a regular file); TOML nested too deeply for
the reader, integers too long to convert and non-finite or out-of-range numbers are a
``MotionConfigError`` naming the file.

Labels the config does not cover keep their procedural clips. Imported clips are cached on
disk (in the folder the caller passes, if any) keyed by the file's SHA-256 and the clip
parameters.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any

from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from storyteller.sim.bounded_files import BoundedFileError, load_bounded_toml, read_bounded_bytes
from storyteller.sim.motion.action_labels import UnknownActionLabelError, database_key
from storyteller.sim.motion.cache import cached_arrays, file_sha256
from storyteller.sim.motion.clips import MotionClip
from storyteller.sim.motion.database import MotionDatabase, load_databases
from storyteller.sim.motion.features import FeatureConfig
from storyteller.sim.motion.sources.amass_import import import_amass
from storyteller.sim.motion.sources.bvh_import import MAX_MOCAP_FILE_BYTES, import_bvh
from storyteller.sim.validation_text import problem_field, problem_message

IMPORTER_VERSION = "mocap-import-2"
MAX_MOTION_CONFIG_BYTES = 1024 * 1024
"""Bytes of a motion config file."""
MAX_SOURCE_FRAME = 10**9
"""Largest frame number a clip entry may name."""


class MotionConfigError(ValueError):
    """A bad motion config: names the file, the field and what was expected."""

    def __init__(self, path: str | Path, message: str, field: str | None = None) -> None:
        where = f" ({field})" if field else ""
        super().__init__(f"{path}{where}: {message}")
        self.path, self.field = str(path), field


class ClipEntry(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    file: str = Field(description="BVH or AMASS .npz path, relative to the config's root")
    label: str = Field(description="action label the clip animates")
    start: int = Field(0, ge=0, le=MAX_SOURCE_FRAME, description="first source frame")
    end: int | None = Field(None, ge=2, le=MAX_SOURCE_FRAME, description="end source frame (exclusive)")
    fps: float | None = Field(None, gt=0, le=10_000, description="source frame rate override (frames/s)")
    seated: bool = False
    loops: bool = False
    mapping: dict[str, str] = Field(default_factory=dict, description="our joint name -> file joint name")

    @field_validator("label")
    @classmethod
    def _known_label(cls, v: str) -> str:
        database_key(v)  # raises for unknown labels
        return v

    @property
    def key(self) -> str:
        return database_key(self.label, self.seated)


class MotionConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    root: str = "."
    replace_procedural: bool = True
    clips: tuple[ClipEntry, ...] = ()
    weights: dict[str, Annotated[float, Field(ge=-1e6, le=1e6)]] = Field(
        default_factory=dict, description="feature group weights (finite)"
    )
    base_dir: str = Field(".", description="directory of the config file (set by the loader)")

    def resolve(self, entry: ClipEntry) -> Path:
        root = Path(self.root)
        if not root.is_absolute():
            root = Path(self.base_dir) / root
        p = Path(entry.file)
        return p if p.is_absolute() else root / p


def load_motion_config(path: str | Path) -> MotionConfig:
    """Read and validate a motion config TOML file; raises MotionConfigError."""
    path = Path(path)
    try:
        raw = load_bounded_toml(read_bounded_bytes(path, MAX_MOTION_CONFIG_BYTES, str(path)), str(path))
    except BoundedFileError as exc:
        raise MotionConfigError(path, f"cannot read ({exc.problem})") from None
    try:
        return MotionConfig.model_validate({**raw, "base_dir": str(path.resolve().parent)})
    except ValidationError as exc:
        err = exc.errors()[0]
        raise MotionConfigError(path, problem_message(err), problem_field(err)) from None
    except UnknownActionLabelError as exc:  # pragma: no cover - pydantic wraps validator errors
        raise MotionConfigError(path, str(exc), "clips.label") from None


def import_entry(config: MotionConfig, entry: ClipEntry, cache_dir: Path | None = None) -> MotionClip:
    """Import one configured clip (BVH or npz by extension), cached by file content in the folder
    ``cache_dir`` (None: no disk cache)."""
    path = config.resolve(entry)
    if not path.is_file():
        raise MotionConfigError(path, "clip file not found", "clips.file")
    if path.stat().st_size > MAX_MOCAP_FILE_BYTES:  # before it is hashed for the cache, let alone read
        raise MotionConfigError(path, f"more than the {MAX_MOCAP_FILE_BYTES} bytes a clip file may have", "clips.file")

    def build() -> MotionClip:
        if path.suffix.lower() == ".bvh":
            return import_bvh(path, entry.key, start=entry.start, end=entry.end, fps=entry.fps,
                              mapping=entry.mapping, loops=entry.loops)
        if path.suffix.lower() == ".npz":
            return import_amass(path, entry.key, start=entry.start, end=entry.end, fps=entry.fps, loops=entry.loops)
        raise MotionConfigError(path, "expected a .bvh or .npz file", "clips.file")

    if cache_dir is None:
        return build()
    payload = {"importer": IMPORTER_VERSION, "sha256": file_sha256(path), "entry": entry.model_dump()}
    holder: list[MotionClip] = []

    def arrays() -> dict[str, NDArray[Any]]:
        clip = build()
        holder.append(clip)
        return {"local_rotations": clip.local_rotations, "pelvis": clip.pelvis, "root_xy": clip.root_xy,
                "heading": clip.heading, "contacts": clip.contacts, "target": clip.target}

    a = cached_arrays(payload, arrays, cache_dir)
    if holder:
        return holder[0]
    return MotionClip(f"{path.stem}[{entry.start}:{entry.end}]", entry.key, a["local_rotations"], a["pelvis"],
                      a["root_xy"], a["heading"], a["contacts"].astype(bool), entry.loops, a["target"],
                      source=str(path))


def build_databases_from_config(
    config: MotionConfig | None, keys: Iterable[str] | None = None, cache_dir: Path | None = None
) -> dict[str, MotionDatabase]:
    """Databases for ``keys`` with the config's clips; procedural clips fill the rest. Imports and
    procedural databases are cached in the folder ``cache_dir`` (None: no disk cache)."""
    extra: dict[str, list[MotionClip]] = {}
    weights = FeatureConfig()
    if config is not None:
        key_set = None if keys is None else set(keys)
        for entry in config.clips:
            if key_set is None or entry.key in key_set:
                extra.setdefault(entry.key, []).append(import_entry(config, entry, cache_dir))
        if config.weights:
            weights = FeatureConfig({**weights.weights, **config.weights})
    return load_databases(keys, config=weights, extra_clips=extra,
                          replace_procedural=config.replace_procedural if config else True, cache_dir=cache_dir)
