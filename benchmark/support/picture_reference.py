"""A frozen copy of the top-down renderer as it was before the animation drew its static
layers once (``sim/export/topdown.py`` and the frame loop of ``sim/export/video.py``).

Every frame is a new matplotlib figure drawn from scratch. ``tests/sim/export/test_run_animation.py``
checks the new animation's frames against these within a tolerance, and
``benchmark/bench_pictures.py`` times the new animation against ``reference_animation_frames``
in the same run. Not used by the product.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle
from numpy.typing import NDArray

from storyteller.sim.export.topdown import CharacterMarker
from storyteller.sim.export.video import RunRecording, RunVideoError
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.motion_layer import root_yaw

BODY_RADIUS = 0.25  # metres: radius of a character's disc in the picture
_FLOOR_COLOUR = "#4a6fa5"
_SUPPORTED_COLOUR = "#9bb7d4"
_EDGE_COLOUR = "#1f2a38"


def _figure_size(scene: Scene, size_px: int, dpi: int) -> tuple[float, float]:
    """Figure size in inches: width ``size_px`` pixels, height from the scene's aspect, both even."""
    dx = scene.bounds_max[0] - scene.bounds_min[0] + 1.0
    dy = scene.bounds_max[1] - scene.bounds_min[1] + 1.0
    width = max(2, int(size_px) // 2 * 2)
    height = int(np.clip(width * dy / dx * 0.92 + 70, 200, 4 * width)) // 2 * 2
    return width / dpi, height / dpi


def reference_draw_topdown(
    scene: Scene,
    *,
    clusters: Sequence[Sequence[str]] | None = None,
    nav_free: NDArray[np.float64] | None = None,
    nav_origin: tuple[float, float] = (0.0, 0.0),
    nav_cell_size: float = 0.3,
    characters: Sequence[CharacterMarker] | None = None,
    paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None = None,
    title: str | None = None,
    captions: Sequence[str] | None = None,
    show_names: bool = True,
    size_px: int = 900,
    dpi: int = 100,
) -> Figure:
    """A top-down figure of ``scene`` with the given layers (see the module docstring)."""
    fig = Figure(figsize=_figure_size(scene, size_px, dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.07, 0.06, 0.9, 0.86 if title else 0.9))
    (x0, y0), (x1, y1) = scene.bounds_min, scene.bounds_max
    ax.add_patch(
        Rectangle(
            (x0, y0), x1 - x0, y1 - y0, facecolor="#f7f5f0", edgecolor="#888888", lw=1.0, zorder=0
        )
    )

    _draw_nav_grid(ax, nav_free, nav_origin, nav_cell_size)
    _draw_objects(ax, scene, clusters, show_names)
    _draw_characters(ax, characters, paths)

    margin = 0.3
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim(y0 - margin, y1 + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    if captions:
        ax.text(
            0.01,
            0.99,
            "\n".join(captions),
            transform=ax.transAxes,
            fontsize=7,
            ha="left",
            va="top",
            zorder=10,
            bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "#888888", "alpha": 0.85},
        )
    return fig


def _draw_nav_grid(
    ax: Axes, nav_free: NDArray[np.float64] | None, nav_origin: tuple[float, float], nav_cell_size: float
) -> None:
    """The navigation grid's blocked cells, shaded (nothing without ``nav_free``)."""
    if nav_free is None:
        return
    free = np.asarray(nav_free, dtype=bool)
    if free.ndim != 2:
        raise ValueError(f"nav_free must be a 2-D bool array (nx, ny), got shape {free.shape}")
    nx, ny = free.shape
    ox, oy = nav_origin
    blocked = np.ma.masked_where(free.T, np.ones((ny, nx)))
    ax.imshow(
        blocked,
        origin="lower",
        extent=(ox, ox + nx * nav_cell_size, oy, oy + ny * nav_cell_size),
        cmap="Reds",
        vmin=0.0,
        vmax=2.5,
        alpha=0.45,
        interpolation="nearest",
        zorder=1,
    )


def _draw_objects(ax: Axes, scene: Scene, clusters: Sequence[Sequence[str]] | None, show_names: bool) -> None:
    """Every object's footprint (coloured by cluster), facing arrows, seat points and names."""
    colour_of: dict[str, tuple[float, float, float, float]] = {}
    if clusters:
        cmap = colormaps["tab20"]
        for k, names in enumerate(clusters):
            for name in names:
                colour_of[name] = cmap(k % 20)

    floor_z = scene.floor_z
    carried = [o for o in scene.objects if o.z_min - floor_z >= 0.1]
    arrows_xy, arrows_uv = [], []
    for obj in sorted(scene.objects, key=lambda o: (o.z_min, o.name)):
        on_floor = obj.z_min - floor_z < 0.1
        face = colour_of.get(obj.name, _FLOOR_COLOUR if on_floor else _SUPPORTED_COLOUR)
        if not on_floor and obj.name in colour_of:  # lighter than its supporter of the same cluster
            r, g, b = (0.55 * np.asarray(face[:3], dtype=np.float64) + 0.45).tolist()
            face = (r, g, b, 1.0)
        ax.add_patch(
            Polygon(
                obj.footprint(),
                closed=True,
                facecolor=face,
                edgecolor=_EDGE_COLOUR,
                lw=0.8,
                alpha=0.75 if on_floor else 0.9,
                zorder=2 if on_floor else 3,
            )
        )
        if obj.has_facing:
            reach = obj.depth / 2.0 + 0.2
            arrows_xy.append(obj.center_xy)
            arrows_uv.append(np.asarray(obj.facing) * reach)
        if obj.is_seat:
            seat = obj.seat_point()
            ax.plot(
                [seat[0]],
                [seat[1]],
                marker="o",
                ms=2.5,
                color="white",
                mec=_EDGE_COLOUR,
                mew=0.5,
                zorder=4,
            )
        if show_names:
            name_xy = obj.center_xy
            if on_floor and any(
                o.z_min >= obj.z_max - 0.05 and bool(obj.contains_xy(o.center_xy)) for o in carried
            ):  # something stands on it: move its name towards its back, out of the way
                name_xy = name_xy - np.asarray(obj.facing) * obj.depth * 0.3
            ax.text(
                name_xy[0],
                name_xy[1],
                obj.name,
                fontsize=5.5,
                ha="center",
                va="center" if on_floor else "bottom",
                zorder=6,
                bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.6},
            )
    if arrows_xy:
        xy, uv = np.array(arrows_xy), np.array(arrows_uv)
        ax.quiver(
            xy[:, 0], xy[:, 1], uv[:, 0], uv[:, 1],
            angles="xy", scale_units="xy", scale=1.0, width=0.003, color="#c0392b", zorder=5,
        )  # fmt: skip


def _draw_characters(
    ax: Axes, characters: Sequence[CharacterMarker] | None,
    paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None,
) -> None:
    """The paths, then each character's disc, heading arrow and name."""
    char_colour: dict[str, tuple[float, float, float, float]] = {}
    for k, marker in enumerate(characters or ()):
        char_colour[marker.name] = colormaps["tab10"](k % 10)
    if paths is not None:
        items = paths.items() if isinstance(paths, Mapping) else enumerate(paths)
        for key, line in items:
            pts = np.asarray(line, dtype=np.float64).reshape(-1, 2)
            if len(pts) == 0:
                continue
            fallback = zlib.crc32(key.encode()) if isinstance(key, str) else int(key)
            colour = char_colour.get(str(key), colormaps["tab10"](fallback % 10))
            ax.plot(pts[:, 0], pts[:, 1], "-", lw=1.4, color=colour, alpha=0.85, zorder=7)
            ax.plot([pts[-1, 0]], [pts[-1, 1]], marker="x", ms=5, color=colour, zorder=7)
    for marker in characters or ():
        colour = char_colour[marker.name]
        px, py = marker.position
        ax.add_patch(
            Circle((px, py), BODY_RADIUS, facecolor=colour, edgecolor="black", lw=0.8, zorder=8)
        )
        if marker.heading is not None:
            h = np.asarray(marker.heading, dtype=np.float64)
            norm = float(np.hypot(*h))
            if norm > 1e-9:
                h = h / norm * (BODY_RADIUS + 0.2)
                ax.annotate(
                    "",
                    xy=(px + h[0], py + h[1]),
                    xytext=(px, py),
                    arrowprops={"arrowstyle": "-|>", "color": "black", "lw": 1.0},
                    zorder=9,
                )
        text = marker.name if not marker.label else f"{marker.name}\n{marker.label}"
        ax.text(
            px,
            py - BODY_RADIUS - 0.05,
            text,
            fontsize=6,
            ha="center",
            va="top",
            zorder=9,
            fontweight="bold",
        )


def reference_topdown_rgb(scene: Scene, **layers: object) -> NDArray[np.uint8]:
    """The picture as an ``(H, W, 3)`` uint8 array (one frame of an animation)."""
    fig = reference_draw_topdown(scene, **layers)  # type: ignore[arg-type]  # frozen copy: keyword layers passed through untyped, as the old renderer did
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def reference_frame_rgb(
    rec: RunRecording, frame: int = -1, *, trail_s: float = 3.0, size_px: int = 900, title: str | None = None,
    show_names: bool = True, show_grid: bool = True,
) -> NDArray[np.uint8]:
    """One frame of the run as an (H, W, 3) uint8 picture (``frame`` may be negative)."""
    n = rec.num_frames
    f = frame + n if frame < 0 else frame
    if not 0 <= f < n:
        raise RunVideoError(f"frame {frame} is outside the run's {n} frames")
    lo = max(0, f - round(trail_s * rec.fps))
    markers, trails, under_way = [], {}, []
    for name, t in rec.tracks.items():
        xy = t.root_positions[f, :2]
        yaw = float(root_yaw(t.local_rotations[f, 0]))
        action = t.action_labels[f] if t.action_labels is not None else None
        event = rec.events[name][f] if rec.events is not None else ""
        label = " / ".join(s for s in (action, event) if s) or None
        markers.append(CharacterMarker(name, (float(xy[0]), float(xy[1])), (np.cos(yaw), np.sin(yaw)), label))
        trails[name] = t.root_positions[lo : f + 1, :2]
        if event and event not in under_way:
            under_way.append(event)
    caption = [f"t = {f / rec.fps:6.2f} s   frame {f}"]
    if under_way:
        caption.append("events: " + ", ".join(under_way))
    grid: dict[str, object] = {}
    if show_grid and rec.grid is not None:
        grid = {"nav_free": rec.grid.free, "nav_origin": rec.grid.origin, "nav_cell_size": rec.grid.cell_size}
    return reference_topdown_rgb(
        rec.scene, characters=markers, paths=trails, title=title, captions=caption,
        show_names=show_names, size_px=size_px, **grid,
    )


def reference_animation_frames(
    rec: RunRecording, *, stride: int = 6, start: int = 0, stop: int | None = None, **kw: object
) -> list[NDArray[np.uint8]]:
    """Pictures of every ``stride``-th frame in [start, stop) (the last frame always included)."""
    if stride < 1:
        raise RunVideoError(f"stride must be >= 1 frame, got {stride}")
    end = rec.num_frames if stop is None else min(stop, rec.num_frames)
    picks = list(range(max(0, start), end, stride))
    if not picks:
        raise RunVideoError(f"no frame in [{start}, {end})")
    if picks[-1] != end - 1:
        picks.append(end - 1)
    return [reference_frame_rgb(rec, f, **kw) for f in picks]  # type: ignore[arg-type]  # frozen copy: style keywords passed through untyped, as the old renderer did
