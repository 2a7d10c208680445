"""Per-database data the motion matcher steps over, computed once per database.

``DatabaseFrames``: frame rotations and pelvis in the character frame, finite-difference
frame pairs and inertialization velocities; ``FrameTable``: next-frame / clip facts as Python
lists; ``StepDatabase``: both plus the feature-layout gather and the database's place in a
``FrameStore``, the frames of a set of databases in one array per quantity for the compiled
step (``storyteller.sim.motion.kernels``). Frames, tables and stores are computed once and kept by the
database they come from (``MotionDatabase.derived``), so matchers over the same database objects
share them and they go away with the databases.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.motion.action_labels import family_of
from storyteller.sim.motion.clips import FPS
from storyteller.sim.motion.database import MotionDatabase
from storyteller.sim.motion.features import Control, LayoutName, assemble, to_character_frame
from storyteller.sim.motion.inertialization import angular_velocity
from storyteller.sim.motion.kernels import (
    SRC_FUT_DIR,
    SRC_FUT_POS,
    SRC_POS,
    SRC_SIZE,
    SRC_T_DIR,
    SRC_T_H,
    SRC_T_POS,
    SRC_VEL,
)
from storyteller.sim.motion.sources.procedural_rig import rot_z


@dataclass(frozen=True)
class DatabaseFrames:
    """Per-database arrays, computed once per database: F frames, C clips.

    rot (F,22,3,3) local rotations with joint 0 in the frame's character frame; pelvis (F,3)
    character frame; pair_a, pair_b (F,) the finite-difference frame pair of each frame (equal
    when the frame has no neighbour in its clip); clip_z (C,2) highest / lowest pelvis height
    per clip. ``motion(frame)`` gives the inertialization velocities, memoised per frame.
    """

    rot: np.ndarray
    pelvis: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray
    clip_z: np.ndarray
    _motion: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def motion(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Angular velocities (22,3) rad/s and pelvis velocity (3,) m/s at ``frame``."""
        mo = self._motion
        if not mo:  # every frame at once, on first use
            a, b = self.pair_a, self.pair_b
            ang = angular_velocity(self.rot[a], self.rot[b], 1.0 / FPS)
            lin = (self.pelvis[b] - self.pelvis[a]) * FPS
            still = a == b
            ang[still] = 0.0
            lin[still] = 0.0
            mo["ang"], mo["lin"] = ang, lin
        return mo["ang"][frame], mo["lin"][frame]


def database_frames(db: MotionDatabase) -> DatabaseFrames:
    """``DatabaseFrames`` of a database (frame pairs: ``next_frame``, vectorised)."""
    rot = np.array(db.local_rotations, dtype=float)
    rot[:, 0] = rot_z(-np.asarray(db.heading, dtype=float)) @ rot[:, 0]
    pelvis = to_character_frame(np.asarray(db.pelvis, dtype=float)[:, None], db.root_xy, db.heading)[:, 0]
    f = np.arange(db.num_frames)
    clip = np.asarray(db.clip_of_frame, dtype=np.int64)
    ranges = np.asarray(db.clip_ranges, dtype=np.int64)
    start, end = ranges[clip, 0], ranges[clip, 1]
    loops = np.asarray(db.clip_loops, dtype=bool)[clip]
    inside = f + 1 < end
    nxt = np.where(inside, f + 1, np.where(loops, start, f))  # next_frame, vectorised
    at_end = ~inside & ~loops
    a = np.where(at_end, np.maximum(f - 1, 0), f)
    b = np.where(at_end, f, nxt)
    a = np.where((clip[a] != clip[b]) | (a == b), b, a)
    z = np.asarray(db.pelvis, dtype=float)[:, 2]
    clip_z = np.array([[z[s:e].max(), z[s:e].min()] for s, e in ranges])
    return DatabaseFrames(rot, pelvis, a, b, clip_z.reshape(-1, 2))


def shared_frames(db: MotionDatabase) -> DatabaseFrames:
    """``database_frames`` of ``db``, computed once and kept by the database (``derived``), so
    matchers built over the same databases reuse it."""
    out: DatabaseFrames | None = db.derived.get("frames")
    if out is None:
        out = db.derived["frames"] = database_frames(db)
    return out


@dataclass(frozen=True)
class FrameTable:
    """Per-database frame facts as Python lists: next frame and non-loop end (``next_frame``),
    whether the frame's clip loops, its clip id; ``completes``: the family plays non-looping
    clips through (in-place, partner, sitting); ``entry``: a switch into it searches the entry
    index."""

    nxt: list[int]
    end: list[bool]
    loops: list[bool]
    clip: list[int]
    completes: bool
    entry: bool


def frame_table(db: MotionDatabase, key: str) -> FrameTable:
    """``FrameTable`` of a database: ``next_frame`` of every frame, vectorised."""
    f = np.arange(db.num_frames)
    clip = np.asarray(db.clip_of_frame, dtype=np.int64)
    ranges = np.asarray(db.clip_ranges, dtype=np.int64)
    loops = np.asarray(db.clip_loops, dtype=bool)[clip]
    inside = f + 1 < ranges[clip, 1]
    nxt = np.where(inside, f + 1, np.where(loops, ranges[clip, 0], f))
    fam = family_of(key)
    return FrameTable(nxt=nxt.tolist(), end=(~inside & ~loops).tolist(), loops=loops.tolist(), clip=clip.tolist(),
                      completes=fam in ("in_place", "partner", "sitting"),
                      entry=fam in ("in_place", "partner") and not bool(np.asarray(db.clip_loops).all()))


def shared_table(db: MotionDatabase, key: str) -> FrameTable:
    """``frame_table`` of ``db`` for ``key``, computed once and kept by the database, as
    ``shared_frames``."""
    name = f"table:{key}"
    out: FrameTable | None = db.derived.get(name)
    if out is None:
        out = db.derived[name] = frame_table(db, key)
    return out


@dataclass(frozen=True)
class StepDatabase:
    """What the step needs about one database, looked up once: its frame tables and arrays,
    whether seat heights correct its pelvis, ``sources``: the positions of its feature layout
    in the SRC_* vector of ``sim.motion.kernels.query_features``, and ``base``: the global index
    of its frame 0 in the matcher's ``FrameStore``."""

    key: str
    db: MotionDatabase
    tab: FrameTable
    frames: DatabaseFrames
    seat: bool
    sources: np.ndarray
    base: int
    index: int = 0
    """Its position among the databases of the matcher that made it (the step's arrays of
    per-database facts are indexed by it)."""


_SOURCES: dict[str, np.ndarray] = {}


def feature_sources(layout: LayoutName) -> np.ndarray:
    """Indices (D,) into the SRC_* vector of ``query_features`` that ``assemble`` picks for
    ``layout``: ``assemble`` itself run on inputs whose values are their own source positions."""
    out = _SOURCES.get(layout)
    if out is None:
        pos = (SRC_POS + np.arange(NUM_JOINTS * 3, dtype=float)).reshape(NUM_JOINTS, 3)
        vel = (SRC_VEL + np.arange(NUM_JOINTS * 3, dtype=float)).reshape(NUM_JOINTS, 3)
        ctrl = Control((SRC_FUT_POS + np.arange(6.0)).reshape(3, 2), (SRC_FUT_DIR + np.arange(6.0)).reshape(3, 2),
                       SRC_T_POS + np.arange(2.0), SRC_T_DIR + np.arange(2.0), np.asarray(float(SRC_T_H)))
        idx = assemble(layout, pos, vel, ctrl)
        assert np.array_equal(idx, np.round(idx)) and idx.min() >= 0 and idx.max() < SRC_SIZE, layout
        out = _SOURCES[layout] = idx.astype(np.int64)
    return out


class FrameStore:
    """The frames of a set of databases in one array per quantity, filled per database on first
    use, so that a kernel reads any character's frame by a global frame index (the database's
    base + its frame): ``rot`` (G,22,3,3) as ``DatabaseFrames.rot``, ``aux`` (G,5) the
    ``DatabaseFrames.pelvis`` (3) and foot contacts (2, as 0 / 1). Shared by the matchers over
    the same databases (``shared_store``)."""

    def __init__(self, capacity: int) -> None:
        self.size = 0
        self.rot = np.empty((capacity, NUM_JOINTS, 3, 3))  # uninitialised: memory is used as frames arrive
        self.aux = np.empty((capacity, 5))
        self.bases: dict[str, int] = {}

    def base(self, key: str, frames: DatabaseFrames, contacts: np.ndarray) -> int:
        """Base index of database ``key`` (its frames are copied in on first use)."""
        out = self.bases.get(key)
        if out is None:
            out, f = self.size, len(frames.pelvis)
            if out + f > len(self.rot):  # a database added to the matcher later: grow
                rot, aux = np.empty((2 * (out + f), NUM_JOINTS, 3, 3)), np.empty((2 * (out + f), 5))
                rot[:out], aux[:out] = self.rot[:out], self.aux[:out]
                self.rot, self.aux = rot, aux
            self.rot[out : out + f] = frames.rot
            self.aux[out : out + f, :3] = frames.pelvis
            self.aux[out : out + f, 3:] = np.asarray(contacts, dtype=bool)
            self.size += f
            self.bases[key] = out
        return out


def shared_store(databases: Mapping[str, MotionDatabase]) -> FrameStore:
    """A ``FrameStore`` for ``databases``, shared by the matchers over the same database objects
    under the same keys. The store is kept by the first database in key order
    (``derived["stores"]``, one entry per set of the other databases it was used with, which the
    entry holds on to), so it lives as long as the databases do."""
    items = sorted(databases.items())
    size = sum(int(db.num_frames) for db in databases.values())
    if not items:
        return FrameStore(size)
    keys = tuple(k for k, _db in items)
    others = tuple(db for _k, db in items[1:])
    stores: list[tuple[tuple[str, ...], tuple[MotionDatabase, ...], FrameStore]] = items[0][1].derived.setdefault(
        "stores", [])
    for known_keys, known, store in stores:
        if known_keys == keys and all(a is b for a, b in zip(known, others, strict=True)):
            return store
    out = FrameStore(size)
    stores.append((keys, others, out))
    return out
