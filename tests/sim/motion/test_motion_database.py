"""Motion databases: layouts, normalisation, cache, and exact KD-tree == brute-force search."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.motion.database import (
    SCAN_THRESHOLD,
    MotionDatabase,
    NearestFrameIndex,
    build_database,
    load_databases,
    squared_distances,
)
from storyteller.sim.motion.features import FEATURE_LAYOUTS, layout_for_key, layout_size
from storyteller.sim.motion.sources.procedural_library import procedural_clips


@pytest.fixture(scope="module")
def walk_db() -> MotionDatabase:
    return build_database("walk", procedural_clips("walk")[:6])


def test_layouts_and_database_shapes(walk_db: MotionDatabase) -> None:
    assert layout_size(FEATURE_LAYOUTS["locomotion"]) == 36
    assert walk_db.raw_features.shape == (walk_db.num_frames, 36)
    assert walk_db.local_rotations.shape == (walk_db.num_frames, 22, 3, 3)
    feats = walk_db.features
    assert np.all(np.isfinite(feats))
    assert np.abs(feats.mean(axis=0)).max() < 1e-6
    assert walk_db.clip_ranges[-1, 1] == walk_db.num_frames
    assert layout_for_key("drink@seated") == "seated" and layout_for_key("sit_down") == "sitting"
    # future trajectory of a straight 1.0 m/s walk: 1/3 m ahead after 10 frames
    i = walk_db.clip_ranges[1, 0] + 5
    assert walk_db.clip_names[1] == "walk_1.0"
    assert walk_db.raw_features[i, 24] == pytest.approx(1.0 / 3.0, abs=0.02)
    # pelvis and spine3 positions (character frame): the pelvis at its height, spine3 above it
    assert walk_db.raw_features[i, 14] == pytest.approx(walk_db.pelvis[i, 2], abs=1e-9)
    assert walk_db.raw_features[i, 17] > walk_db.raw_features[i, 14] + 0.2


def test_next_frame_loops_and_ends() -> None:
    db = build_database("sit_down", procedural_clips("sit_down"))
    start, end = db.clip_ranges[0]
    assert db.next_frame(int(start)) == (int(start) + 1, False)
    assert db.next_frame(int(end) - 1) == (int(end) - 1, True)
    loop = build_database("chat", procedural_clips("chat"))
    s, e = loop.clip_ranges[0]
    assert loop.next_frame(int(e) - 1) == (int(s), False)


def test_search_finds_the_frame_a_query_was_taken_from(walk_db: MotionDatabase) -> None:
    for i in np.flatnonzero(walk_db.searchable)[::37]:
        frame, dist = walk_db.search(walk_db.raw_features[i])
        assert dist == pytest.approx(0.0, abs=1e-18)
        assert np.array_equal(walk_db.raw_features[frame], walk_db.raw_features[i])


def test_cached_databases_equal_fresh_ones(tmp_path: Path) -> None:
    keys = ["handshake", "sit_idle"]
    fresh = load_databases(keys)  # no cache folder: nothing written
    first = load_databases(keys, cache_dir=tmp_path / "motion")
    again = load_databases(keys, cache_dir=tmp_path / "motion")
    assert [p.name for p in tmp_path.iterdir()] == ["motion"]
    assert len(list((tmp_path / "motion").glob("*.npz"))) == 2
    for k in keys:
        assert np.allclose(fresh[k].local_rotations, again[k].local_rotations, atol=1e-6)
        assert np.array_equal(first[k].raw_features, again[k].raw_features)
        assert again[k].search(again[k].raw_features[3])[0] == fresh[k].search(fresh[k].raw_features[3])[0]


rows_strategy = st.integers(1, 60).flatmap(
    lambda n: st.tuples(
        st.lists(st.lists(st.integers(-3, 3), min_size=4, max_size=4), min_size=n, max_size=n),
        st.lists(st.integers(-4, 4), min_size=4, max_size=4),
    )
)


@settings(max_examples=150, deadline=None)
@given(rows_strategy, st.floats(0.01, 2.0))
def test_kd_tree_equals_brute_force_with_ties(data: tuple[list[list[int]], list[int]], scale: float) -> None:
    rows, query = data
    feats = np.array(rows, dtype=float) * scale  # small integer grid: many exact ties
    q = np.array(query, dtype=float) * scale / 2
    index = NearestFrameIndex(feats, leafsize=2)
    want = index.brute_force(q)
    for scan in (True, False):  # exact scan (small indexes) and KD-tree path
        index.use_scan = scan
        assert index.query(q) == want
        many_i, many_d = index.query_many(np.stack([q, q * 0.5]))
        assert (int(many_i[0]), float(many_d[0])) == want
        assert (int(many_i[1]), float(many_d[1])) == index.brute_force(q * 0.5)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_kd_tree_and_scan_equal_brute_force_on_random_subsets(seed: int) -> None:
    rng = np.random.default_rng(seed)
    feats = rng.normal(size=(300, 27))
    feats[rng.integers(0, 300, 20)] = feats[rng.integers(0, 300, 20)]  # duplicated rows
    candidates = np.sort(rng.choice(300, size=200, replace=False))
    index = NearestFrameIndex(feats, candidates)
    queries = np.concatenate([rng.normal(size=(5, 27)), feats[candidates[:3]]])
    scan_i, scan_d = index.scan_many(queries * 1e3)  # large offsets: rounding bound of the scan
    for m, q in enumerate(queries):
        index.use_scan = False
        got = index.query(q)
        want = index.brute_force(q)
        assert got == want
        index.use_scan = True
        assert index.query(q) == want
        assert (int(scan_i[m]), float(scan_d[m])) == index.brute_force(q * 1e3)
        assert got[0] in set(candidates.tolist())
        assert got[1] == pytest.approx(float(squared_distances(feats[candidates], q).min()))


def test_squared_distances_adds_dimensions_in_order() -> None:
    rng = np.random.default_rng(5)
    rows = rng.normal(size=(100, 27)) * rng.uniform(1e-3, 1e3, size=27)
    q = rng.normal(size=27)
    acc = np.zeros(len(rows))
    for d in range(27):
        acc += (rows[:, d] - q[d]) ** 2
    assert np.array_equal(squared_distances(rows, q), acc)  # many rows: loop path
    assert np.array_equal(squared_distances(rows[:7], q), acc[:7])  # few rows: cumsum path
    assert np.array_equal(squared_distances(rows[3:4], q), acc[3:4])


def test_small_indexes_scan_and_large_ones_use_the_tree() -> None:
    assert NearestFrameIndex(np.zeros((SCAN_THRESHOLD, 2))).use_scan
    assert not NearestFrameIndex(np.zeros((SCAN_THRESHOLD + 1, 2))).use_scan
