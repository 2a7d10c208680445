"""Batched path following gives the very floats of the one-walker-at-a-time code.

``storyteller.sim.paths.tracks.path_tracks`` (compiled) against ``tests.support.path_reference.track_reference``
(numpy, one path), and ``CrowdNavigator``'s batched reads (``futures``, the positions ``tick`` returns) against its
per-agent ``future`` / ``_xy_at``, in a crowd that walks, takes exact off-grid legs and parks.
"""

from __future__ import annotations

import math

import numpy as np

from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.following import CrowdNavigator, close_xy
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.paths.plan_types import Cell
from storyteller.sim.paths.tracks import is_movement, path_tracks, walker_headings
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.phases import wrap_angle
from tests.support.path_reference import track_reference


def test_compiled_tracks_equal_the_reference_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        paths = [[(int(rng.integers(-3, 60)), int(rng.integers(-3, 60))) for _ in range(int(rng.integers(1, 24)))]
                 for _ in range(int(rng.integers(1, 12)))]
        origin = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)))
        cell, step_time = float(rng.choice([0.3, 0.25, 0.1])), 0.3
        fps = int(rng.choice([10, 30, 60]))  # whole frames per step, as CrowdNavigator requires
        step_frames = round(step_time * fps)
        stack, sizes = path_tracks(paths, origin, cell, step_frames, fps, step_time)
        assert stack.shape == (len(paths), max(sizes), 2)
        for i, p in enumerate(paths):
            ref = track_reference(p, origin, cell, step_frames, fps, step_time)
            assert sizes[i] == len(ref)
            assert np.array_equal(stack[i, : len(ref)], ref)
            assert np.array_equal(stack[i, len(ref):], np.broadcast_to(ref[-1], (stack.shape[1] - len(ref), 2)))
    empty, sizes = path_tracks([], (0.0, 0.0), 0.3, 9, 30, 0.3)
    assert empty.shape[0] == 0 and sizes == []


def _room() -> Scene:
    desk = SceneObject(name="desk_0", label="desk", idx=0, center=(2.5, 1.5, 0.4), size=(1.0, 0.6, 0.8))
    return Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(5.0, 4.0), objects=(desk,))


def test_batched_navigator_reads_equal_the_per_agent_ones() -> None:
    grid = build_nav_grid(_room())
    nav = CrowdNavigator(grid, PathPlanner(grid, seed=1), fps=30, seed=1)
    free: list[Cell] = [(int(i), int(j)) for i, j in np.argwhere(grid.free)]
    rng = np.random.default_rng(0)
    picks = [free[int(k)] for k in rng.permutation(len(free))]
    starts: list[Cell] = []
    for c in picks:
        if all(max(abs(c[0] - s[0]), abs(c[1] - s[1])) >= 2 for s in starts):
            starts.append(c)
        if len(starts) == 5:
            break
    for k, c in enumerate(starts):
        nav.add_walker(k, c)
    goals = list(reversed(starts))
    for k, g in enumerate(goals):
        final = None
        if k % 2 == 0:  # an exact point off the goal cell's centre: a leg, then parked
            p = grid.center_of(*g) + np.array([0.06, -0.04])
            if nav.target_problem(g, p) is None:
                final = p
        nav.set_goal(k, g, final_xy=final)
    horizon = (0, 1, 10, 20, 30, 95)
    legs = parked = 0
    for f in range(240):
        ticked = nav.tick(horizon if f % 3 else ())  # sampled ahead by the tick, or not
        agents = nav.walkers if f % 2 else list(reversed(nav.walkers))
        for a in agents:
            assert np.array_equal(ticked[a], nav._xy_at(a, nav.frame - 1))
        batch = nav.futures(agents, horizon)
        for i, a in enumerate(agents):
            assert np.array_equal(batch[i], nav.future(a, horizon))
        assert np.array_equal(nav.futures(agents[:2], (5, 0)), np.stack([nav.future(a, (5, 0)) for a in agents[:2]]))
        legs += bool(nav._legs)
        parked += bool(nav._parked)
    assert legs and parked  # the exact-point legs and parked walkers were exercised
    assert nav.arrivals


def test_float_helpers_match_numpy() -> None:
    rng = np.random.default_rng(5)
    for _ in range(2000):
        a = rng.normal(size=2) * 10.0 ** rng.integers(-12, 3)
        b = a + rng.normal(size=2) * 10.0 ** rng.integers(-14, 0)
        assert close_xy(a, b) == bool(np.allclose(a, b, atol=1e-9))
        assert close_xy(a, b, atol=1e-8) == bool(np.allclose(a, b))
        d = b - a
        assert is_movement(float(d[0]), float(d[1])) == (float(d @ d) > 1e-12)
    assert not close_xy(np.array([np.nan, 0.0]), np.array([np.nan, 0.0]))
    assert close_xy(np.array([np.inf, 0.0]), np.array([np.inf, 0.0]))


def _headings_reference(path: np.ndarray, heading: list[float], max_turn: float) -> tuple[list[float], np.ndarray, list[bool]]:
    """The world's walker loop before it was compiled (numpy arrays, Python floats)."""
    w_xy, w_prev, w_fut = path[:, 1], path[:, 0], path[:, 2:]
    ahead_all = w_fut[:, 3] - w_xy
    dist_all = np.hypot(ahead_all[:, 0], ahead_all[:, 1])
    moved = w_xy - w_prev
    moving_all = np.hypot(moved[:, 0], moved[:, 1]) > 1e-6
    steps_all = np.diff(np.concatenate([w_xy[:, None], w_fut[:, :3]], axis=1), axis=1)
    moves_ahead = np.hypot(steps_all[..., 0], steps_all[..., 1]) > 1e-6
    step_dir = np.arctan2(steps_all[..., 1], steps_all[..., 0])
    out_h, out_f = [], []
    for i, h0 in enumerate(heading):
        h = h0
        if float(dist_all[i]) > 0.05:
            err = wrap_angle(math.atan2(ahead_all[i][1], ahead_all[i][0]) - h0)
            h = h0 + float(min(max(err, -max_turn), max_turn))
        out_f.append(np.where(moves_ahead[i], step_dir[i], h))
        out_h.append(wrap_angle(h))
    return out_h, np.array(out_f), [bool(m) for m in moving_all]


def test_compiled_walker_headings_equal_the_python_loop() -> None:
    rng = np.random.default_rng(9)
    for trial in range(300):
        w = int(rng.integers(1, 12))
        path = rng.normal(scale=float(rng.choice([0.01, 0.3, 3.0])), size=(w, 6, 2))
        if trial % 4 == 0:  # standing still, or not moving for some of the future steps
            path[:, 1] = path[:, 0]
            path[:, 3] = path[:, 2]
        if trial % 5 == 0:  # the lookahead point at the 0.05 m threshold, give or take an ulp
            ang = rng.uniform(-math.pi, math.pi, size=w)
            path[:, 5] = path[:, 1] + 0.05 * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        heading = rng.uniform(-4.0, 4.0, size=w).tolist()
        max_turn = float(rng.choice([2.0 / 30, 0.5, 4.0]))
        steps = path[:, 2:5] - path[:, 1:4]
        wrapped, fut, moved = walker_headings(path[:, 0], path[:, 1:], np.array(heading),
                                              np.arctan2(steps[..., 1], steps[..., 0]), max_turn)
        ref_h, ref_f, ref_m = _headings_reference(path, heading, max_turn)
        assert wrapped.tolist() == ref_h
        assert np.array_equal(fut, ref_f) and fut.tobytes() == ref_f.tobytes()
        assert moved.tolist() == ref_m
