"""Motion databases (one per action label / database key) and exact nearest-frame search.

A database concatenates clips: per-frame local rotations, pelvis positions, root trajectory,
foot contacts, and feature vectors normalised per database (per-dimension mean, per-group
standard deviation, then a per-group weight). ``NearestFrameIndex`` answers "which frame's
features are closest to this query" with a scipy cKDTree and returns exactly the frame that
brute force returns: the smallest squared Euclidean distance, ties broken by the lowest frame
index, with both paths computing distances by the same arithmetic.

The default databases are built from the procedural clips (sim/motion/sources/procedural_library.py),
cached on disk by content hash (sim/motion/cache.py); clips imported from real mocap can be
added or can replace them (sim/motion/config.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics
from storyteller.sim.motion.action_labels import ActionFamily, all_database_keys, family_of
from storyteller.sim.motion.cache import cached_arrays
from storyteller.sim.motion.clips import MotionClip
from storyteller.sim.motion.features import (
    FEATURE_LAYOUTS,
    FUTURE_FRAMES,
    Control,
    FeatureConfig,
    Layout,
    LayoutName,
    assemble,
    layout_for_key,
    layout_size,
    relative_target,
    to_character_frame,
    vectors_to_character_frame,
)
from storyteller.sim.motion.kernels import nearest_rows
from storyteller.sim.motion.sources.procedural_library import GENERATOR_VERSION, procedural_clips

END_MARGIN = 5  # frames at the end of a non-looping clip that a search never jumps to
ENTRY_FRAMES = 8  # frames at the start of each clip where a completing action is entered
# Indexes with at most this many rows answer by an exact scan instead of the KD-tree: on
# ~30-dimensional motion features the scan measured faster than the tree up to ~3-10k rows on
# this (loaded, 2-core) machine (benchmark/bench_motion_search.py; then a matrix product + exact
# re-rank, now the compiled exact scan, which measured faster still, up to ~10-20k rows).
SCAN_THRESHOLD = 5_000


def squared_distances(rows: NDArray[np.float64], query: NDArray[np.float64]) -> NDArray[np.float64]:
    """Squared distances (N,) of ``rows`` (N,D) to ``query`` (D,), summed dimension by
    dimension in a fixed order so that any subset of rows gets bit-identical values."""
    if rows.shape[1] == 0 or rows.shape[0] > 64:
        acc = np.zeros(rows.shape[0])
        for d in range(rows.shape[1]):
            diff = rows[:, d] - query[d]
            acc += diff * diff
        return acc
    diff = rows - query  # few rows: same sums, without a Python loop over dimensions
    return np.cumsum(diff * diff, axis=1)[:, -1]  # cumsum adds strictly left to right


class NearestFrameIndex:
    """Exact nearest neighbour over feature rows (N,D), restricted to ``candidates``.

    ``query`` returns (row index, squared distance); KD-tree and brute force agree exactly.
    The tree is built on the rows rotated onto their principal axes (a rotation keeps
    distances, and splitting along the directions the data spreads in prunes far better),
    on the first tree search: an index of at most ``SCAN_THRESHOLD`` rows always scans;
    candidates within a tiny slack of the tree's best distance are re-ranked with the exact
    distance in the original space, so rounding in the rotation cannot change the answer.
    """

    def __init__(self, features: NDArray[np.float64], candidates: NDArray[np.intp] | None = None, leafsize: int = 16,
                 rotate: bool = True) -> None:
        self.features = np.ascontiguousarray(features, dtype=np.float64)
        if candidates is None:
            candidates = np.arange(len(self.features))
        self.candidates = np.asarray(candidates, dtype=np.int64)
        if len(self.candidates) == 0:
            raise ValueError("a motion search index needs at least one candidate frame")
        self.rows = self.features[self.candidates]
        self.center = self.rows.mean(axis=0)
        self._rotate, self._leafsize = rotate, leafsize
        self._rows_t = np.ascontiguousarray(self.rows.T)  # scan path: one dimension of all rows at a time
        self.use_scan = len(self.rows) <= SCAN_THRESHOLD

    @cached_property
    def basis(self) -> NDArray[np.float64]:
        """The principal axes of the rows (columns), or the identity (built on first use: an
        index that scans never needs it)."""
        if self._rotate and len(self.rows) > self.rows.shape[1]:
            sample = self.rows[:: max(1, len(self.rows) // 20000)] - self.center
            basis: NDArray[np.float64] = np.linalg.svd(sample, full_matrices=False)[2].T
            return basis
        return np.eye(self.rows.shape[1])

    @cached_property
    def tree(self) -> cKDTree:
        """The KD-tree over the rotated rows (built on first use, like ``basis``)."""
        return cKDTree((self.rows - self.center) @ self.basis, leafsize=self._leafsize, balanced_tree=False,
                       compact_nodes=True)

    def _tree_space(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        rotated: NDArray[np.float64] = (q - self.center) @ self.basis
        return rotated

    def brute_force(self, query: NDArray[np.float64]) -> tuple[int, float]:
        d = squared_distances(self.rows, np.asarray(query, dtype=np.float64))
        i = int(np.argmin(d))  # first minimum = lowest index among ties
        return int(self.candidates[i]), float(d[i])

    def _resolve(self, query: NDArray[np.float64], dists: NDArray[np.float64], idx: NDArray[np.float64]) -> tuple[int, float]:
        n = len(self.rows)
        valid = idx < n
        dists, idx = dists[valid], idx[valid]
        d0 = float(dists[0])
        slack = d0 * 1e-7 + 1e-9  # covers rounding of the rotation (tree distances are not squared)
        close = idx[dists <= d0 + slack]
        if len(close) == len(idx) and len(idx) < n:
            # every returned neighbour ties: collect all rows within the tie radius
            close = np.asarray(self.tree.query_ball_point(self._tree_space(query), d0 + slack), dtype=np.int64)
        exact = squared_distances(self.rows[close], query)
        best = np.flatnonzero(exact == exact.min())
        i = int(close[best].min())  # lowest index among exact ties (candidates are sorted)
        return int(self.candidates[i]), float(squared_distances(self.rows[i : i + 1], query)[0])

    def scan_many(self, queries: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Exact brute force for (M,D) queries, compiled (``storyteller.sim.motion.kernels.nearest_rows``):
        every row's squared distance summed dimension by dimension as ``squared_distances``
        does, the first minimum taken. Same answer as ``brute_force`` (lowest index among
        exact ties). Raises ValueError for a query with non-finite features."""
        q = np.ascontiguousarray(np.asarray(queries, dtype=np.float64).reshape(-1, self.rows.shape[1]))
        if not np.isfinite(q).all():
            raise ValueError(f"motion search query has non-finite features: {q[~np.isfinite(q).all(axis=1)][0]}")
        j, d = nearest_rows(self._rows_t, q)
        return self.candidates[j], d

    def query(self, query: NDArray[np.float64], k: int = 4) -> tuple[int, float]:
        q = np.asarray(query, dtype=np.float64)
        if self.use_scan:
            i, d = self.scan_many(q[None])
            return int(i[0]), float(d[0])
        k = min(k, len(self.rows))
        dists, idx = self.tree.query(self._tree_space(q), k=k)
        return self._resolve(q, np.atleast_1d(dists), np.atleast_1d(idx))

    def query_many(self, queries: NDArray[np.float64], k: int = 4, workers: int = 1) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Batched exact search: (M,D) -> (indices (M,), squared distances (M,))."""
        q = np.asarray(queries, dtype=np.float64).reshape(-1, self.rows.shape[1])
        if self.use_scan:
            return self.scan_many(q)
        k = min(k, len(self.rows))
        raw_d, raw_i = self.tree.query(self._tree_space(q), k=k, workers=workers)
        dists, idx = np.asarray(raw_d).reshape(len(q), k), np.asarray(raw_i).reshape(len(q), k)
        out_i = np.empty(len(q), dtype=np.int64)
        out_d = np.empty(len(q))
        for m in range(len(q)):
            out_i[m], out_d[m] = self._resolve(q[m], dists[m], idx[m])
        return out_i, out_d


@dataclass(frozen=True)
class MotionDatabase:
    """Frames of one database. F frames, C clips, D features.

    local_rotations (F,22,3,3); pelvis (F,3) world (clip frames); root_xy (F,2); heading (F,);
    contacts (F,2); clip_of_frame (F,) clip index; clip_ranges (C,2) [start, end) frame
    ranges; clip_loops (C,); clip_names; targets (C,4) [x, y, facing, height] per clip;
    raw_features (F,D); mean (D,), scale (D,): normalised = (raw - mean) / scale;
    searchable (F,) frames a search may jump to.
    """

    key: str
    family: ActionFamily
    local_rotations: NDArray[np.float64]
    pelvis: NDArray[np.float64]
    root_xy: NDArray[np.float64]
    heading: NDArray[np.float64]
    contacts: NDArray[np.float64]
    clip_of_frame: NDArray[np.float64]
    clip_ranges: NDArray[np.float64]
    clip_loops: NDArray[np.float64]
    clip_names: tuple[str, ...]
    targets: NDArray[np.float64]
    raw_features: NDArray[np.float64]
    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    searchable: NDArray[np.float64]
    _index: list[NearestFrameIndex] = field(default_factory=list, repr=False, compare=False)
    derived: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    """Data other modules compute once from this database's arrays and keep here, keyed by
    what it is (``storyteller.sim.motion.frames``: frames, frame tables, frame stores); it lives and dies
    with the database."""

    @property
    def num_frames(self) -> int:
        return int(self.local_rotations.shape[0])

    @property
    def layout_name(self) -> LayoutName:
        return layout_for_key(self.key)

    @property
    def layout(self) -> Layout:
        return FEATURE_LAYOUTS[self.layout_name]

    @property
    def features(self) -> NDArray[np.float64]:
        return (self.raw_features - self.mean) / self.scale

    def normalize(self, raw: NDArray[np.float64]) -> NDArray[np.float64]:
        return (np.asarray(raw, dtype=np.float64) - self.mean) / self.scale

    @property
    def index(self) -> NearestFrameIndex:
        """The search index over searchable frames (built on first use)."""
        if not self._index:
            self._index.append(NearestFrameIndex(self.features, np.flatnonzero(self.searchable)))
        return self._index[0]

    @property
    def entry_index(self) -> NearestFrameIndex:
        """Search index over the first ENTRY_FRAMES frames of every clip (how a completing
        action is entered: from its beginning)."""
        if len(self._index) < 2:
            self.index  # noqa: B018 - builds the main index first
            start = self.clip_ranges[self.clip_of_frame, 0]
            entry = self.searchable & (np.arange(self.num_frames) - start < ENTRY_FRAMES)
            self._index.append(NearestFrameIndex(self.features, np.flatnonzero(entry)))
        return self._index[1]

    def search(self, raw_query: NDArray[np.float64], entry: bool = False) -> tuple[int, float]:
        """Best frame for a raw feature vector: (frame, squared normalised distance);
        ``entry`` restricts the search to the first frames of each clip."""
        index = self.entry_index if entry else self.index
        return index.query(self.normalize(raw_query))

    def next_frame(self, frame: int) -> tuple[int, bool]:
        """Frame after ``frame``: wraps in looping clips; (frame, True) at a non-loop end."""
        c = int(self.clip_of_frame[frame])
        start, end = (int(v) for v in self.clip_ranges[c])
        if frame + 1 < end:
            return frame + 1, False
        if self.clip_loops[c]:
            return start, False
        return frame, True

    def frames_to_end(self, frame: int) -> int:
        return int(self.clip_ranges[int(self.clip_of_frame[frame]), 1]) - 1 - frame

    def arrays(self) -> dict[str, NDArray[np.float64]]:
        """Plain arrays for caching (``from_arrays`` restores the database)."""
        return {
            "local_rotations": self.local_rotations.astype(np.float32), "pelvis": self.pelvis,
            "root_xy": self.root_xy, "heading": self.heading, "contacts": self.contacts,
            "clip_of_frame": self.clip_of_frame, "clip_ranges": self.clip_ranges,
            "clip_loops": self.clip_loops, "clip_names": np.array(self.clip_names, dtype=str),
            "targets": self.targets, "raw_features": self.raw_features, "mean": self.mean,
            "scale": self.scale, "searchable": self.searchable,
            "meta": np.array([self.key, self.family], dtype=str),
        }

    @classmethod
    def from_arrays(cls, a: Mapping[str, NDArray[np.float64]]) -> MotionDatabase:
        key = str(a["meta"][0])  # meta also stores the family, which follows from the key
        return cls(key, family_of(key), a["local_rotations"].astype(float), a["pelvis"], a["root_xy"],
                   a["heading"], a["contacts"].astype(bool), a["clip_of_frame"], a["clip_ranges"],
                   a["clip_loops"].astype(bool), tuple(str(n) for n in a["clip_names"]), a["targets"],
                   a["raw_features"], a["mean"], a["scale"], a["searchable"].astype(bool))


def _future_roots(clip: MotionClip, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Root ground points and headings ``k`` frames after each frame (loops wrap with the
    loop's displacement; other clips hold their last frame)."""
    n = clip.num_frames
    j = np.arange(n) + k
    if not clip.loops:
        j = np.minimum(j, n - 1)
        return clip.root_xy[j], clip.heading[j]
    # pose "frame n" = last frame advanced by the last frame-to-frame step
    dh = clip.heading[-1] - clip.heading[-2]
    c, s = np.cos(dh), np.sin(dh)
    step = clip.root_xy[-1] - clip.root_xy[-2]
    root_n = clip.root_xy[-1] + np.array([c * step[0] - s * step[1], s * step[0] + c * step[1]])
    d_theta = clip.heading[-1] + dh - clip.heading[0]
    c, s = np.cos(d_theta), np.sin(d_theta)
    rot = np.array([[c, -s], [s, c]])
    wraps = j // n
    jj = j % n
    xy, hd = clip.root_xy[jj].copy(), clip.heading[jj].copy()
    for w in range(1, int(wraps.max()) + 1 if len(wraps) else 1):
        m = wraps >= w
        xy[m] = (xy[m] - clip.root_xy[0]) @ rot.T + root_n  # one more period per wrap
        hd[m] = hd[m] + d_theta
    return xy, hd


def clip_raw_features(clip: MotionClip, family: LayoutName) -> NDArray[np.float64]:
    """Raw feature vectors (F,D) of one clip."""
    pos = clip.joint_positions()
    vel = np.gradient(pos, axis=0) * clip.fps
    if clip.loops and clip.num_frames > 2:
        # wrap the velocity at the loop seam using the next period's first frame
        vel[0] = vel[1]
        vel[-1] = vel[-2]
    pos_c = to_character_frame(pos, clip.root_xy, clip.heading)
    vel_c = vectors_to_character_frame(vel, clip.heading)
    n = clip.num_frames
    fut_pos = np.zeros((n, 3, 2))
    fut_dir = np.zeros((n, 3, 2))
    for i, k in enumerate(FUTURE_FRAMES):
        xy, hd = _future_roots(clip, k)
        rel, d = relative_target(clip.root_xy, clip.heading, xy, hd)
        fut_pos[:, i], fut_dir[:, i] = rel, d
    tgt = clip.target
    if np.all(np.isfinite(tgt[:3])):
        t_pos, t_dir = relative_target(clip.root_xy, clip.heading, np.broadcast_to(tgt[:2], (n, 2)),
                                       np.full(n, tgt[2]))
    else:
        t_pos, t_dir = np.zeros((n, 2)), np.zeros((n, 2))
    height = np.full(n, tgt[3] if np.isfinite(tgt[3]) else 0.0)
    return assemble(family, pos_c, vel_c, Control(fut_pos, fut_dir, t_pos, t_dir, height))


def build_database(key: str, clips: Sequence[MotionClip], config: FeatureConfig | None = None) -> MotionDatabase:
    """Concatenate clips into a normalised database for ``key``."""
    if not clips:
        raise ValueError(f"database {key!r} has no clips")
    config = config or FeatureConfig()
    family = family_of(key)
    layout_name = layout_for_key(key)
    layout = FEATURE_LAYOUTS[layout_name]
    raws, ranges, of_frame, searchable = [], [], [], []
    start = 0
    for c, clip in enumerate(clips):
        raws.append(clip_raw_features(clip, layout_name))
        n = clip.num_frames
        ranges.append((start, start + n))
        of_frame.append(np.full(n, c))
        s = np.ones(n, dtype=bool)
        if not clip.loops:
            s[max(1, n - END_MARGIN):] = False
        searchable.append(s)
        start += n
    raw = np.concatenate(raws)
    assert raw.shape[1] == layout_size(layout)
    mean = raw.mean(axis=0)
    std = raw.std(axis=0)
    scale = np.empty_like(mean)
    offset = 0
    for name, size in layout:
        group_std = float(std[offset : offset + size].mean())
        scale[offset : offset + size] = (group_std if group_std > 1e-6 else 1.0) / max(config.weight(name), 1e-9)
        offset += size
    assert offset == raw.shape[1]
    return MotionDatabase(
        key=key, family=family,
        local_rotations=np.concatenate([c.local_rotations for c in clips]),
        pelvis=np.concatenate([c.pelvis for c in clips]),
        root_xy=np.concatenate([c.root_xy for c in clips]),
        heading=np.concatenate([c.heading for c in clips]),
        contacts=np.concatenate([c.contacts for c in clips]).astype(bool),
        clip_of_frame=np.concatenate(of_frame), clip_ranges=np.array(ranges, dtype=np.int64),
        clip_loops=np.array([c.loops for c in clips], dtype=bool),
        clip_names=tuple(c.name for c in clips), targets=np.stack([c.target for c in clips]),
        raw_features=raw, mean=mean, scale=scale, searchable=np.concatenate(searchable),
    )


def load_databases(
    keys: Iterable[str] | None = None,
    *,
    config: FeatureConfig | None = None,
    extra_clips: Mapping[str, Sequence[MotionClip]] | None = None,
    replace_procedural: bool = True,
    cache_dir: Path | None = None,
) -> dict[str, MotionDatabase]:
    """Databases for ``keys`` (default: every label and seated variant).

    ``extra_clips`` (e.g. imported mocap) are used for their keys; with ``replace_procedural``
    they replace the procedural clips of those keys, otherwise they are added. Databases made
    only of procedural clips are cached by content hash in the folder ``cache_dir`` (None: no
    disk cache; the application's folder is ``storyteller.orchestrator.cache_paths.motion_cache_dir()``).
    """
    config = config or FeatureConfig()
    extra = dict(extra_clips or {})
    out: dict[str, MotionDatabase] = {}
    for key in keys if keys is not None else all_database_keys():
        family_of(key)  # validates the key
        mine = list(extra.get(key, ()))
        if mine:
            clips = mine if replace_procedural else [*procedural_clips(key), *mine]
            out[key] = build_database(key, clips, config)
            continue
        payload = {"generator": GENERATOR_VERSION, "key": key, "weights": config.weights,
                   "layout": FEATURE_LAYOUTS[layout_for_key(key)], "joints": NUM_JOINTS}
        if cache_dir is None:
            out[key] = build_database(key, procedural_clips(key), config)
            continue

        def build(key: str = key) -> dict[str, NDArray[np.float64]]:
            return build_database(key, procedural_clips(key), config).arrays()

        arrays = cached_arrays(payload, build, cache_dir)
        out[key] = MotionDatabase.from_arrays(arrays)
    return out


def database_pose(db: MotionDatabase, frame: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World joint positions (22,3) and local rotations of one database frame (clip world)."""
    pos, _ = forward_kinematics(db.local_rotations[frame], db.pelvis[frame])
    return pos, db.local_rotations[frame]
