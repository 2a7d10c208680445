"""The world's view of ``CrowdNavigator``: walkers, stationary bodies, arrivals, planned futures.

A thin wrapper with string agent names. It adds two things the navigator does not do itself:

- several stationary discs per character (a seated body spans the approach cell and the
  seat): extra keys ``(name, k)``, released together;
- ``can_freeze``: whether a walker may turn into a stationary body now. The plan made at this
  step boundary is conflict-free for its first (committed) step; a walker whose own plan
  waits during that step can stop for good without invalidating anybody's committed move
  (the next replan then sees it as an obstacle). A walker planned to move (for instance to
  make way for a passer-by) must not be frozen yet.

``StandTargets`` turns an assignment into the point its walk ends on (``StandTarget``): the
exact target for a standing action, the seat's approach point (``NavGrid.approach_point``,
cached per object) for a seated one, the nearest cell centre with a typed ``TargetFallback``
when the exact point cannot be used; ``StandTargets.within_reach`` gives a free standing point
within reach of an object an action uses (``storyteller.sim.world.facing``) when the planner's point, or
where a stall left the walker, is out of reach.

Positions are metres (xy).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from storyteller.sim.paths.cooperative_astar import Cell, PathPlanner
from storyteller.sim.paths.following import Agent, CrowdNavigator, close_xy
from storyteller.sim.paths.nav_grid import ApproachPoint, NavGrid, NavGridError, body_clearance
from storyteller.sim.scene.model import FLOOR_STANDING_M, Scene, SceneObject
from storyteller.sim.world.facing import REACH_M, REACH_SLACK_M, surface_distance
from storyteller.sim.world.phases import StandTarget, TargetFallback

OFF_GRID_EPS = 1e-6  # metres: a point closer than this to its cell centre is on the grid


class WorldNavigator:
    """Thin wrapper over one ``CrowdNavigator``."""

    def __init__(self, grid: NavGrid, planner: PathPlanner, fps: int, seed: int) -> None:
        self.nav = CrowdNavigator(grid, planner=planner, fps=fps, seed=seed)
        self._arrivals_seen = 0
        self._extra: dict[str, int] = {}

    @property
    def grid(self) -> NavGrid:
        return self.nav.grid

    @property
    def planner(self) -> PathPlanner:
        return self.nav.planner

    @property
    def step_frames(self) -> int:
        return self.nav.step_frames

    def at_boundary(self) -> bool:
        """Whether the next ``tick`` starts a planning step (walkers may join only then)."""
        return self.nav.frame % self.nav.step_frames == 0

    # ----- membership ---------------------------------------------------------------------------
    def add_walker(
        self,
        name: str,
        cell: Cell,
        goal: Cell | None = None,
        start_xy: np.ndarray | None = None,
        final_xy: np.ndarray | None = None,
    ) -> None:
        """``name`` walks from ``cell`` (or from the exact point ``start_xy``, entering ``cell``)
        to ``goal`` (ending on the exact point ``final_xy`` when given)."""
        self.release(name)
        self.nav.add_walker(name, cell, goal, start_xy=start_xy, final_xy=final_xy)

    def set_goal(self, name: str, goal: Cell | None, final_xy: np.ndarray | None = None) -> None:
        """New goal cell (None: stay), ending on the exact point ``final_xy`` when given."""
        self.nav.set_goal(name, goal, final_xy=final_xy)

    def target_problem(self, cell: Cell, xy: np.ndarray) -> str | None:
        """Why a body cannot walk straight from ``cell``'s centre to ``xy`` and stand there."""
        return self.nav.target_problem(cell, xy)

    def detour_distance(self, name: str) -> float | None:
        """Metres left on the walker's route around stationary bodies, when it was planned so
        (``CrowdNavigator.detour_distance``); else None."""
        return self.nav.detour_distance(name)

    def position(self, name: str) -> np.ndarray:
        """The walker's xy at the last produced frame (metres)."""
        return self.nav.position(name)

    def is_off_grid(self, name: str) -> bool:
        """Whether the walker stands at, or walks to or from, a point off its cell centre."""
        return self.nav.is_off_grid(name)

    def goal_of(self, name: str) -> Cell | None:
        return self.nav.goal_of(name)

    def make_stationary(self, name: str, points: Sequence[np.ndarray]) -> None:
        """``name`` stops walking; its body covers discs centred on ``points`` (>= 1)."""
        self.release(name)
        self.nav.set_stationary(name, np.asarray(points[0], dtype=float))
        for k, p in enumerate(points[1:], start=1):
            self.nav.set_stationary((name, k), np.asarray(p, dtype=float))
        self._extra[name] = len(points) - 1

    def release(self, name: str) -> None:
        """Forget ``name``'s stationary discs (no-op for walkers)."""
        self.nav.release(name)
        for k in range(1, self._extra.pop(name, 0) + 1):
            self.nav.release((name, k))

    def is_walker(self, name: str) -> bool:
        return self.nav.is_walker(name)

    def cell(self, name: str) -> Cell:
        return self.nav.cell(name)

    def crowded_by_still_bodies(self, cell: Cell) -> bool:
        """Whether a body standing still keeps every walker off ``cell``'s centre."""
        return self.nav.crowded_by_still_bodies(cell)

    def can_freeze(self, name: str) -> bool:
        """Whether the walker's current plan keeps it in place for the committed step (call
        right after a boundary ``tick``)."""
        here = self.nav.position(name)
        there = self.nav.future(name, (self.nav.step_frames,))[0]
        return close_xy(here, there)

    # ----- time ----------------------------------------------------------------------------------
    def tick(self, ahead: Sequence[int] = ()) -> dict[Agent, np.ndarray]:
        """Walker positions at this frame, by name (then the navigator's clock advances);
        ``ahead``: the frame offsets ``futures`` will be asked for (sampled in the same pass)."""
        return self.nav.tick(ahead)

    def new_arrivals(self) -> list[str]:
        """Walkers that reached their goal since the last call, in order (with an exact target:
        once they stand on it)."""
        # walkers are added by name (``add_walker``); stationary discs, keyed (name, k), never arrive
        out = [a for _, a in self.nav.arrivals[self._arrivals_seen :] if isinstance(a, str)]
        self._arrivals_seen = len(self.nav.arrivals)
        return out

    def used_goal(self, name: str) -> Cell | None:
        """The goal the last plan actually used (the nearest free cell when the asked one was taken)."""
        res = self.nav.last_result
        return None if res is None else res.goals.get(name)

    def future(self, name: str, frames: Sequence[int]) -> np.ndarray:
        """Planned positions (len(frames), 2) ``frames`` after the last produced frame."""
        return self.nav.future(name, frames)

    def futures(self, names: Sequence[str], frames: Sequence[int]) -> np.ndarray:
        """``future`` of several walkers at once: (len(names), len(frames), 2)."""
        return self.nav.futures(names, frames)


REACH_LATTICE_M = 0.05  # metres between the candidate standing points around an object
REACH_SEARCH_M = 1.5  # metres off an object's footprint within which standing points are looked for

SEAT_PLACE_WIDTH = 0.6  # metres of a seat's width one sitting body takes (a seat twice as wide seats several)


def _covered(scene: Scene, obj: SceneObject, xy: np.ndarray) -> bool:
    """Whether ``xy`` lies inside the footprint of floor-standing furniture other than ``obj``."""
    return any(o.name != obj.name and abs(o.z_min - scene.floor_z) < FLOOR_STANDING_M and bool(o.contains_xy(xy))
               for o in scene.objects)


def seat_place(obj: SceneObject, target_xy: Sequence[float], scene: Scene | None = None) -> tuple[float, float]:
    """Where on ``obj`` a body sent to ``target_xy`` sits: on a one-place seat, its seat point, or
    ``target_xy`` when that lies on the seat and other furniture of ``scene`` covers the seat point
    (a stool pushed into a plant's leaves: the planner moves the point off it);
    on a seat wide enough for several (a couch), the point of its seat line nearest to
    ``target_xy`` (kept half a place inside the ends), so that two people share it side by side."""
    base = obj.seat_point()
    if obj.width < 2 * SEAT_PLACE_WIDTH:
        target = np.asarray(target_xy, dtype=float)
        if scene is not None and bool(obj.contains_xy(target)) and _covered(scene, obj, base):
            return (float(target[0]), float(target[1]))
        return (float(base[0]), float(base[1]))
    half = obj.width / 2.0 - SEAT_PLACE_WIDTH / 2.0
    lateral = float(np.clip((np.asarray(target_xy, dtype=float) - base) @ obj.right, -half, half))
    p = base + obj.right * lateral
    return (float(p[0]), float(p[1]))


class StandTargets:
    """Resolves assignments to ``StandTarget``s on one grid; approach points are cached per
    (object, component, sitting place) because ``NavGrid.approach_point`` is slow (~0.15 s);
    one that another body's standing point crowds is searched again without the cache.
    Deterministic."""

    def __init__(self, grid: NavGrid) -> None:
        self.grid = grid
        self._approach: dict[tuple[str, int, tuple[float, float]], ApproachPoint | str] = {}
        self._room: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._limit: dict[tuple[str, int], float] = {}

    # ----- standing within reach of an object ----------------------------------------------------
    def _room_near(self, obj: SceneObject) -> tuple[np.ndarray, np.ndarray]:
        """Points (K, 2) of a lattice around ``obj`` where a body fits (in bounds, clear of every
        blocking object) within ``REACH_SEARCH_M`` of its footprint, and their distances (K,) to
        it, nearest first (ties in lattice order). Cached per object."""
        hit = self._room.get(obj.name)
        if hit is not None:
            return hit
        g, r = self.grid, self.grid.body_radius
        n = int(math.ceil((math.hypot(obj.width, obj.depth) / 2.0 + REACH_SEARCH_M) / REACH_LATTICE_M))
        ax = np.arange(-n, n + 1) * REACH_LATTICE_M
        gx, gy = np.meshgrid(ax, ax, indexing="ij")
        pts = obj.center_xy + np.stack([gx.ravel(), gy.ravel()], axis=1)
        local = obj.to_local(pts)
        dist = np.hypot(np.maximum(np.abs(local[:, 0]) - obj.width / 2.0, 0.0),
                        np.maximum(np.abs(local[:, 1]) - obj.depth / 2.0, 0.0))
        lo, hi = np.asarray(g.bounds_min) + r - 1e-9, np.asarray(g.bounds_max) - r + 1e-9
        keep = (dist <= REACH_SEARCH_M) & np.all((pts >= lo) & (pts <= hi), axis=1)
        pts, dist = pts[keep], dist[keep]
        keep = body_clearance(g.obstacles, pts, pts, cutoff=r) >= r - 1e-9
        pts, dist = pts[keep], dist[keep]
        order = np.argsort(dist, kind="stable")
        hit = (pts[order], dist[order])
        self._room[obj.name] = hit
        return hit

    def reach_limit(self, obj: SceneObject, component: int) -> float:
        """Metres from ``obj``'s footprint within which a body standing in ``component`` works on
        it: ``REACH_M``, or ``REACH_SLACK_M`` beyond the nearest point a walker of ``component``
        can stand on when furniture keeps every point further (inf when there is none)."""
        key = (obj.name, int(component))
        limit = self._limit.get(key)
        if limit is None:
            limit = math.inf
            pts, dist = self._room_near(obj)
            for p, d in zip(pts, dist, strict=True):
                if self.grid.entry_cell(p, component=int(component)) is not None:
                    limit = max(REACH_M, float(d) + REACH_SLACK_M)
                    break
            self._limit[key] = limit
        return limit

    def within_reach(self, obj: SceneObject, component: int, prefer: Sequence[float] | np.ndarray,
                     avoid: Sequence[tuple[float, float]] = ()) -> StandTarget | None:
        """The free point within ``reach_limit`` of ``obj`` that a walker of ``component`` walks
        onto straight from a cell's centre, with the point and that walk two body radii clear of
        the points of ``avoid`` (other bodies), and the least distance to ``prefer`` plus distance
        to ``obj`` (near where it was meant to stand, close to the object); None when there is none.
        The target's ``fallback`` is ``out_of_reach`` (the caller writes the message)."""
        g, r = self.grid, self.grid.body_radius
        limit = self.reach_limit(obj, component)
        if not math.isfinite(limit):
            return None
        pts, dist = self._room_near(obj)
        within = dist <= limit + 1e-9
        pts, dist = pts[within], dist[within]
        taken = np.asarray(avoid, dtype=float).reshape(-1, 2)
        if len(taken) and len(pts):
            clear = np.min(np.linalg.norm(pts[:, None, :] - taken[None, :, :], axis=2), axis=1) >= 2.0 * r
            pts, dist = pts[clear], dist[clear]
        if len(pts) == 0:
            return None
        score = np.linalg.norm(pts - np.asarray(prefer, dtype=float), axis=1) + dist
        for k in np.argsort(score, kind="stable"):
            p = pts[k]
            cell = g.entry_cell(p, component=int(component))
            if cell is None:
                continue
            a = g.center_of(*cell)
            if len(taken):
                ab = p - a
                t = np.clip((taken - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
                if float(np.min(np.linalg.norm(taken - (a + t[:, None] * ab), axis=1))) < 2.0 * r:
                    continue
            off = float(np.linalg.norm(p - a)) > OFF_GRID_EPS
            xy = (float(p[0]), float(p[1])) if off else self._centre(cell)
            return StandTarget(cell, xy, off, "out_of_reach")
        return None

    def reaches(self, obj: SceneObject, component: int, xy: Sequence[float] | np.ndarray) -> bool:
        """Whether a body standing at ``xy`` (in ``component``) works on ``obj`` (``reach_limit``)."""
        return surface_distance(obj, xy) <= self.reach_limit(obj, component) + 1e-9

    def _centre(self, cell: Cell) -> tuple[float, float]:
        c = self.grid.center_of(*cell)
        return (float(c[0]), float(c[1]))

    def standing(self, nav: WorldNavigator, xy: np.ndarray, component: int) -> StandTarget | None:
        """The exact point ``xy`` entered from the closest free cell of ``component`` with a
        straight furniture-free walk to it; else the nearest free cell of ``component``
        (``fallback`` says why). None when the grid has no free cell there."""
        g = self.grid
        p = np.asarray(xy, dtype=float)
        cell = g.entry_cell(p, component=component)
        if cell is not None:
            why = nav.target_problem(cell, p)
            if why is None:
                off = float(np.linalg.norm(p - g.center_of(*cell))) > OFF_GRID_EPS
                return StandTarget(cell, (float(p[0]), float(p[1])) if off else self._centre(cell), off)
            reason: TargetFallback = "no_straight_approach"
            msg = why
        elif not g.is_free_xy(p):
            reason, msg = "target_blocked", (
                f"a body of radius {g.body_radius} m cannot stand at ({p[0]:.2f}, {p[1]:.2f})")
        else:
            reason, msg = "no_straight_approach", (
                f"no free cell near ({p[0]:.2f}, {p[1]:.2f}) has a straight walk to it clear of furniture")
        near = g.nearest_free_cell(p, component=component)
        if not g.is_free(*near):
            return None
        return StandTarget(near, self._centre(near), False, reason, msg)

    def approach_point(self, obj: SceneObject, component: int, place: tuple[float, float] | None = None,
                       avoid: Sequence[tuple[float, float]] = ()) -> ApproachPoint | str:
        """``NavGrid.approach_point(obj, component=component, seat_xy=place)`` (cached), or why
        there is none; when it (or the walk onto it from its cell's centre) comes within two
        body radii of a point of ``avoid`` (where other bodies stand or sit down), the best one
        clear of them (not cached)."""
        seat = obj.seat_point() if place is None else np.asarray(place, dtype=float)
        if place is not None and float(np.linalg.norm(seat - obj.seat_point())) <= 1e-9:
            place = None  # the seat point itself: the object's own approach point
        key = (obj.name, int(component), (round(float(seat[0]), 6), round(float(seat[1]), 6)))
        hit = self._approach.get(key)
        if hit is None:
            hit = self._search(obj, component, place, ())
            self._approach[key] = hit
        if isinstance(hit, ApproachPoint) and len(avoid):
            taken = np.asarray(avoid, dtype=float).reshape(-1, 2)
            a, b = self.grid.center_of(*hit.cell), np.asarray(hit.xy)
            t = np.clip((taken - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-12), 0.0, 1.0)
            near = float(np.min(np.linalg.norm(taken - (a + t[:, None] * (b - a)), axis=1)))
            if near < 2.0 * self.grid.body_radius:  # the point or the walk onto it
                return self._search(obj, component, place, avoid)
        return hit

    def _search(self, obj: SceneObject, component: int, place: tuple[float, float] | None,
                avoid: Sequence[tuple[float, float]]) -> ApproachPoint | str:
        try:
            return self.grid.approach_point(obj, component=int(component), seat_xy=place, avoid=avoid)
        except NavGridError as exc:
            return str(exc)

    def seated(self, nav: WorldNavigator, obj: SceneObject, component: int, place: tuple[float, float] | None = None,
               avoid: Sequence[tuple[float, float]] = ()) -> StandTarget | None:
        """The approach point of ``obj`` (for the sitting ``place`` on it, default its seat point)
        reachable in ``component`` and clear of ``avoid`` (see ``approach_point``); else the
        object's approach cell (``no_approach_point``). None when neither is reachable from
        ``component``."""
        ap = self.approach_point(obj, component, place, avoid)
        if isinstance(ap, ApproachPoint):
            p = np.asarray(ap.xy, dtype=float)
            if nav.target_problem(ap.cell, p) is None:
                off = float(np.linalg.norm(p - self.grid.center_of(*ap.cell))) > OFF_GRID_EPS
                return StandTarget(ap.cell, ap.xy if off else self._centre(ap.cell), off)
            why = nav.target_problem(ap.cell, p) or ""
        else:
            why = ap
        g = self.grid
        cell = g.approach_cell(obj)
        if int(g.component[cell]) != int(component):
            return None
        return StandTarget(cell, self._centre(cell), False, "no_approach_point", why)
