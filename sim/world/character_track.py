"""One character's animation as the world step produces it, ready for the exporters.

A :class:`CharacterTrack` holds, per frame at ``fps`` (30 by default):

- ``root_positions`` (N, 3): the pelvis position in the world (metres, z up);
- ``local_rotations`` (N, 22, 3, 3): each joint's rotation relative to its parent in the
  SMPL-X joint order of :mod:`storyteller.sim.body.skeleton`; joint 0's is the root's world rotation (body frame
  -> world, so a standing character's root is ``heading_to_root(theta)``);
- ``betas`` (10,), ``gender`` and optional per-frame ``action_labels``.

``forward_kinematics(track.local_rotations, track.root_positions)`` gives world joint positions
directly. Tracks save to and load from ``.npz``; :func:`write_npz` writes byte-identical files
for identical arrays (numpy's own ``savez`` stamps the current time into the zip).

A track file may come from someone else's run folder, so :meth:`CharacterTrack.load` reads it
bounded: a regular file (a FIFO or a device is refused, never waited on) of at most
:data:`MAX_TRACK_FILE_BYTES`, whose arrays unpack to at most :data:`MAX_TRACK_ARRAY_BYTES`
(the sizes the zip and each array's header declare are checked before any is inflated or
allocated: a zip bomb or a header claiming terabytes costs nothing), never
unpickled, each of the expected shape and kind (text for the name, numbers for the rest). Its
text is data (a name or label may hold any character: a reader shows it through a sanitiser).
Every failure is one :class:`CharacterTrackError`
naming the file and the field.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_npz
from storyteller.sim.no_follow_writes import write_file

Gender = Literal["neutral", "male", "female"]
GENDERS: tuple[Gender, ...] = ("neutral", "male", "female")
NUM_BETAS = 10
TRACK_FORMAT = "storyteller-track/1"
# Tolerance on R^T R - I and det(R) - 1 for a matrix to count as a rotation.
ROTATION_TOLERANCE = 1e-4
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
NPZ_DEFLATE_LEVEL = 1
"""zlib level of the entries :func:`write_npz` compresses. Level 1 deflates a track's float
arrays about 2.3x faster than zlib's default 6 into files about 5% larger (a 60 s two-character
run: 0.2 s instead of 0.5 s). The bytes are a function of the arrays and this level, so a replay
writes the files of its recording; a run recorded with another level replays to the same
arrays in other bytes."""
_CHECK_FRAMES = 4096  # frames whose rotations are checked at once
MIN_FPS = 1.0
MAX_FPS = 240.0
"""Frames per second of a track (and of a story's timeline, ``storyteller.orchestrator.session.story_stream``):
runs use 30; a file at 1e-300 fps stretched 90 frames over 1e301 seconds."""
MAX_TRACK_FILE_BYTES = 256 << 20
"""Bytes of the largest ``.track.npz`` read back (a compressed hour of frames is about 100 MB)."""
MAX_TRACK_ARRAY_BYTES = 256 << 20
"""Bytes its arrays may unpack to (an hour at 30 fps is 173 MB of float64 rotations)."""
_TEXT_FIELDS = ("format", "name", "gender")
_NUMBER_FIELDS = ("fps", "root_positions", "local_rotations", "betas")


class CharacterTrackError(ValueError):
    """A track (or a track file) that does not hold a valid animation; ``field`` names the part."""

    def __init__(self, message: str, *, field: str | None = None, path: Path | None = None) -> None:
        self.message = message
        self.field = field
        self.path = path
        where = f"{path}: " if path is not None else ""
        what = f"field '{field}': " if field is not None else ""
        super().__init__(f"{where}{what}{message}")


@dataclass(frozen=True, eq=False)
class CharacterTrack:
    """Per-frame animation of one character; arrays are validated and made read-only."""

    name: str
    root_positions: np.ndarray
    local_rotations: np.ndarray
    fps: float = 30.0
    betas: np.ndarray = field(default_factory=lambda: np.zeros(NUM_BETAS))
    gender: Gender = "neutral"
    action_labels: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        name: object = self.name  # checked at run time: tracks are built from loaded files too
        if not isinstance(name, str) or not name.strip():
            raise CharacterTrackError("must be a non-empty string", field="name")
        fps = float(self.fps)
        if not np.isfinite(fps) or not MIN_FPS <= fps <= MAX_FPS:
            raise CharacterTrackError(
                f"must be between {MIN_FPS:g} and {MAX_FPS:g} frames per second, got {self.fps!r}", field="fps"
            )
        object.__setattr__(self, "fps", fps)

        root = _as_float_array(self.root_positions, "root_positions")
        if root.ndim != 2 or root.shape[1] != 3 or root.shape[0] < 1:
            raise CharacterTrackError(
                f"expected shape (N, 3) with N >= 1, got {root.shape}", field="root_positions"
            )
        n = root.shape[0]
        rot = _as_float_array(self.local_rotations, "local_rotations")
        if rot.shape != (n, NUM_JOINTS, 3, 3):
            raise CharacterTrackError(
                f"expected shape ({n}, {NUM_JOINTS}, 3, 3) to match root_positions, got {rot.shape}",
                field="local_rotations",
            )
        for lo in range(0, n, _CHECK_FRAMES):  # in blocks: a long track's temporaries stay small
            block = rot[lo : lo + _CHECK_FRAMES]
            ortho = np.abs(np.swapaxes(block, -1, -2) @ block - np.eye(3)).max(axis=(-1, -2))
            det = np.linalg.det(block)
            bad = (ortho > ROTATION_TOLERANCE) | (np.abs(det - 1.0) > ROTATION_TOLERANCE)
            if bad.any():
                frame, joint = np.argwhere(bad)[0]
                raise CharacterTrackError(
                    f"frame {lo + frame} joint {joint} is not a rotation matrix (orthonormal, det +1)",
                    field="local_rotations",
                )
        betas = _as_float_array(self.betas, "betas")
        if betas.shape != (NUM_BETAS,):
            raise CharacterTrackError(
                f"expected shape ({NUM_BETAS},), got {betas.shape}", field="betas"
            )
        _gender(self.gender)  # callers without a type checker may pass any string
        labels = self.action_labels
        if labels is not None:
            labels = tuple(labels)
            if len(labels) != n or not all(isinstance(s, str) for s in labels):
                raise CharacterTrackError(
                    f"expected {n} strings (one per frame)", field="action_labels"
                )
        for name, arr in (("root_positions", root), ("local_rotations", rot), ("betas", betas)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "action_labels", labels)

    def then(self, more: CharacterTrack) -> CharacterTrack:
        """This track followed by ``more`` (the same character, fps and body; both with action
        labels or both without). Each was checked when it was built, so no frame is checked again:
        a reader that gets a track a chunk at a time checks each chunk once."""
        same = (more.name == self.name and more.fps == self.fps and more.gender == self.gender
                and np.array_equal(more.betas, self.betas) and (more.action_labels is None) == (self.action_labels is None))
        if not same:
            raise CharacterTrackError(f"{more.name!r} cannot follow {self.name!r}: another character, fps, body or labelling")
        joined = object.__new__(CharacterTrack)  # the fields set as __post_init__ leaves them, without its checks
        arrays = {
            "root_positions": np.concatenate([self.root_positions, more.root_positions]),
            "local_rotations": np.concatenate([self.local_rotations, more.local_rotations]),
        }
        for name, arr in arrays.items():
            arr.setflags(write=False)
            object.__setattr__(joined, name, arr)
        labels = None if self.action_labels is None or more.action_labels is None else self.action_labels + more.action_labels
        for name, value in (("name", self.name), ("fps", self.fps), ("betas", self.betas), ("gender", self.gender),
                            ("action_labels", labels)):
            object.__setattr__(joined, name, value)
        return joined

    # ----- derived ------------------------------------------------------------------
    @property
    def num_frames(self) -> int:
        return int(self.root_positions.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    @property
    def times(self) -> np.ndarray:
        """Frame times (N,) in seconds from 0."""
        return np.arange(self.num_frames, dtype=float) / self.fps

    def joint_positions(self) -> np.ndarray:
        """World joint positions (N, 22, 3) in metres, z up."""
        return forward_kinematics(self.local_rotations, self.root_positions)[0]

    # ----- files --------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the track to ``path`` (.npz, deterministic bytes). Returns the path."""
        arrays: dict[str, np.ndarray] = {
            "format": np.array(TRACK_FORMAT),
            "name": np.array(self.name),
            "fps": np.array(self.fps),
            "root_positions": self.root_positions,
            "local_rotations": self.local_rotations,
            "betas": self.betas,
            "gender": np.array(self.gender),
        }
        if self.action_labels is not None:
            arrays["action_labels"] = np.array(self.action_labels, dtype=str)
        return write_npz(path, arrays)

    @classmethod
    def load(cls, path: str | Path) -> CharacterTrack:
        """Read a track written by :meth:`save` (bounded: see the module docstring); raises
        CharacterTrackError, naming the file and the field, on a bad file."""
        path = Path(path)
        arrays = _read_npz(path)
        if "format" not in arrays:
            raise CharacterTrackError("missing", field="format", path=path)
        if arrays["format"].ndim == 0 and arrays["format"].dtype.kind == "U" and str(arrays["format"]) != TRACK_FORMAT:
            raise CharacterTrackError(  # another kind of file: said before what it lacks
                f"expected '{TRACK_FORMAT}', got '{str(arrays['format'])[:60]}'", field="format", path=path
            )
        for key in ("name", "fps", "root_positions", "local_rotations", "betas", "gender"):
            if key not in arrays:
                raise CharacterTrackError("missing", field=key, path=path)
        for key in (*_TEXT_FIELDS, "fps"):
            if arrays[key].ndim != 0:
                raise CharacterTrackError(f"expected one value, got an array of shape {arrays[key].shape}", field=key, path=path)
        for key in _TEXT_FIELDS:
            if arrays[key].dtype.kind != "U":
                raise CharacterTrackError(f"expected text, got {arrays[key].dtype}", field=key, path=path)
        for key in _NUMBER_FIELDS:
            if arrays[key].dtype.kind not in "fiu":
                raise CharacterTrackError(f"expected real numbers, got {arrays[key].dtype}", field=key, path=path)
        fmt = str(arrays["format"])
        if fmt != TRACK_FORMAT:
            raise CharacterTrackError(
                f"expected '{TRACK_FORMAT}', got '{fmt[:60]}'", field="format", path=path
            )
        labels = arrays.get("action_labels")
        if labels is not None and (labels.ndim != 1 or labels.dtype.kind != "U"):
            raise CharacterTrackError(f"expected one text per frame, got {labels.dtype} of shape {labels.shape}",
                                      field="action_labels", path=path)
        try:
            return cls(
                name=str(arrays["name"]),
                root_positions=arrays["root_positions"],
                local_rotations=arrays["local_rotations"],
                fps=float(arrays["fps"]),
                betas=arrays["betas"],
                gender=_gender(str(arrays["gender"])),
                action_labels=None if labels is None else tuple(str(s) for s in labels),
            )
        except CharacterTrackError as exc:
            raise CharacterTrackError(exc.message, field=exc.field, path=path) from None


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` at ``path``, read within the module's limits, never unpickled."""
    try:
        return read_bounded_npz(path, MAX_TRACK_FILE_BYTES, MAX_TRACK_ARRAY_BYTES, str(path))
    except BoundedFileError as exc:
        problem = exc.problem if exc.problem.startswith(("cannot read as .npz", "its arrays", "array ")) else (
            f"cannot read as .npz ({exc.problem})")
        raise CharacterTrackError(problem, path=path) from None


def _gender(value: str) -> Gender:
    """``value`` as a :data:`Gender`; anything else is a :class:`CharacterTrackError`."""
    for gender in GENDERS:
        if value == gender:
            return gender
    raise CharacterTrackError(f"expected one of {list(GENDERS)}, got {value!r}", field="gender")


def _as_float_array(value: object, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)  # a copy: the track owns its data
    except (TypeError, ValueError) as exc:
        raise CharacterTrackError(f"not numeric ({exc})", field=name) from None
    if not np.isfinite(arr).all():
        raise CharacterTrackError("contains NaN or infinite values", field=name)
    return arr


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray], *, compress: bool = True) -> Path:
    """Write ``arrays`` as an .npz readable by ``np.load``, byte-identical for identical input.

    Entries keep the mapping's order; zip timestamps are fixed. Object arrays are refused
    (they would need pickling).
    """
    path = Path(path)
    buffer = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", compression=method) as zf:
        for key, value in arrays.items():
            arr = np.asarray(value)
            if arr.dtype.hasobject:
                raise TypeError(
                    f"array '{key}' has dtype object; it cannot be stored without pickling"
                )
            info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            payload = io.BytesIO()
            np.lib.format.write_array(payload, np.array(arr, order="C"), allow_pickle=False)
            zf.writestr(info, payload.getvalue(), compresslevel=NPZ_DEFLATE_LEVEL if compress else None)
    write_file(path, buffer.getbuffer())
    return path


def common_fps(tracks: Sequence[CharacterTrack]) -> float:
    """The common frame rate of ``tracks``; raises CharacterTrackError if they differ."""
    if not tracks:
        raise CharacterTrackError("no tracks given")
    rates = {t.fps for t in tracks}
    if len(rates) != 1:
        raise CharacterTrackError(f"tracks have different frame rates {sorted(rates)}", field="fps")
    return tracks[0].fps
