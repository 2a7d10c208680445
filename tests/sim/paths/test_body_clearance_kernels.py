"""``body_clearance`` (compiled loops) gives the very floats of its numpy reference.

Random segments and points in the reference Office (every blocking object, with and without a
cutoff) and against random rotated boxes, including degenerate cases: zero-length segments,
axis-parallel segments (the Liang-Barsky "flat" branch), segments through a box, endpoints on
an edge, zero-size boxes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from storyteller.sim.paths import footprint_distance
from storyteller.sim.paths.nav_grid import body_clearance, build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import SceneObject
from tests.support.clearance_reference import body_clearance_reference
from tests.support.reference import OFFICE, reference_or_skip


def _same(x: np.ndarray, y: np.ndarray) -> bool:
    return x.shape == y.shape and x.dtype == y.dtype and bool(np.array_equal(x, y)) and x.tobytes() == y.tobytes()


def test_office_clearances_equal_the_reference() -> None:
    reference_or_skip()
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    rng = np.random.default_rng(11)
    lo, hi = np.asarray(scene.bounds_min), np.asarray(scene.bounds_max)
    a = lo + rng.random((600, 2)) * (hi - lo)
    b = a + rng.normal(scale=0.4, size=a.shape)
    b[:150] = a[:150]  # points
    b[150:200, 1] = a[150:200, 1]  # horizontal segments
    b[200:250, 0] = a[200:250, 0]  # vertical segments
    for cutoff in (None, 0.0, 0.25, 0.6):
        assert _same(body_clearance(grid.obstacles, a, b, cutoff=cutoff),
                     body_clearance_reference(grid.obstacles, a, b, cutoff=cutoff))
        assert _same(body_clearance(grid.obstacles, a[:150], a[:150], cutoff=cutoff),
                     body_clearance_reference(grid.obstacles, a[:150], a[:150], cutoff=cutoff))
    for k in range(40):  # one segment at a time, as the world's per-replan checks call it
        assert _same(body_clearance(grid.obstacles, a[k : k + 1], b[k : k + 1], cutoff=grid.body_radius),
                     body_clearance_reference(grid.obstacles, a[k : k + 1], b[k : k + 1], cutoff=grid.body_radius))


def test_rotated_boxes_and_degenerate_segments_equal_the_reference() -> None:
    rng = np.random.default_rng(4)
    for trial in range(150):
        theta = float(rng.uniform(-math.pi, math.pi)) if trial % 3 else 0.0
        w, d = (0.0, 0.0) if trial == 7 else (float(rng.uniform(0.05, 2.0)), float(rng.uniform(0.05, 2.0)))
        box = SceneObject(name="box_0", label="box", idx=0, center=(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), 0.5),
                          size=(w, d, 1.0), facing=(math.cos(theta), math.sin(theta)))
        c = np.asarray(box.center[:2])
        a = c + rng.normal(scale=1.5, size=(50, 2))
        b = a + rng.normal(scale=1.0, size=a.shape)
        b[:10] = a[:10]
        b[10:20] = 2 * c - a[10:20]  # through the centre
        a[20:25] = c + np.asarray(box.right) * w / 2  # on an edge
        b[25:30, 0] = a[25:30, 0]
        for cutoff in (None, 0.3):
            assert _same(body_clearance([box], a, b, cutoff=cutoff), body_clearance_reference([box], a, b, cutoff=cutoff))
    assert body_clearance([], np.zeros((3, 2)), np.ones((3, 2))).tolist() == [math.inf] * 3
    assert body_clearance([box], np.zeros((0, 2)), np.zeros((0, 2)), cutoff=0.3).shape == (0,)


def test_a_different_clearance_is_noticed() -> None:
    box = SceneObject(name="box_0", label="box", idx=0, center=(0.0, 0.0, 0.5), size=(1.0, 1.0, 1.0))
    a = np.array([[2.0, 0.0]])
    assert not _same(body_clearance([box], a, a), body_clearance_reference([box], a + 1e-12, a + 1e-12))


def test_the_pruned_path_keeps_every_value_below_the_cutoff(monkeypatch: pytest.MonkeyPatch) -> None:
    """Above ``PRUNE_PAIRS`` a cutoff looks at each object's nearby segments only (the hostile
    corpus: a 2,000-object scene took 43 s in ``scene inspect``). Below the cutoff the values are
    the very floats of the full computation; at or above it, both say "at least the cutoff"."""
    rng = np.random.default_rng(5)
    objects = [SceneObject(name=f"box_{i}", label="box", idx=i, center=(*(rng.random(2) * 30), 0.5),
                           size=(*(0.05 + rng.random(2) * 2), 1.0), facing=tuple(rng.normal(size=2)))
               for i in range(1, 60)]
    a = rng.random((4000, 2)) * 32 - 1
    b = a + rng.normal(scale=0.5, size=a.shape)
    b[:500] = a[:500]
    full = body_clearance(objects, a, b)
    for cutoff in (0.0, 0.25, 0.6, 3.0):
        monkeypatch.setattr(footprint_distance, "PRUNE_PAIRS", 0)
        pruned = body_clearance(objects, a, b, cutoff=cutoff)
        below = full < cutoff
        assert _same(pruned[below], full[below]) and bool((pruned[~below] >= cutoff).all())
        monkeypatch.undo()
        assert (body_clearance(objects, a, b, cutoff=cutoff) < cutoff).tolist() == below.tolist()
