"""Top-down pictures of a scene (matplotlib, Agg canvas; no pyplot, no global state).

One pure drawing function and two outputs:

- ``draw_topdown(scene, **layers) -> Figure``;
- ``render_topdown_rgb(scene, **layers) -> (H, W, 3) uint8``: one frame, for assembling an
  animated GIF / MP4 of a run (same scene and ``size_px`` give frames of the same shape; both
  sides are even numbers of pixels, as video encoders want);
- ``save_topdown_png(path, scene, **layers) -> Path``;
- ``TopdownAnimation(scene, **static layers).frame(**moving layers)``: the frames of an
  animation. The static layers (floor, grid, furniture, names, axes, title) are drawn once;
  each frame restores that picture and draws only the moving layers on it (matplotlib
  blitting), with the same artists and z-order as ``draw_topdown``, so a frame equals
  ``render_topdown_rgb`` with the same layers up to anti-aliasing at the edges.

Layers (all optional): ``clusters`` (lists of object names, one colour each),
``nav_free`` + ``nav_origin`` + ``nav_cell_size`` (a navigation-grid mask, ``nav_free[i, j]``
True when cell (i, j) is walkable, ``i`` along +x, ``origin`` the corner of cell (0, 0)),
``characters`` (``CharacterMarker``: position, heading, label), ``paths`` (polylines, either a
list or a mapping from character name to polyline so the colours match), ``title``,
``captions`` (lines of text in the top-left corner, e.g. the events under way), ``show_names``.
Coordinates in metres, x to the right, y up.

Every text drawn (object and character names, labels, captions, the title) comes from a scene
file, a model or an event program, so it is data: it is drawn through
``storyteller.sim.visible_text.plain`` (control, format, separator and surrogate characters shown as
escapes; a character's name and label, and the caption lines, keep the line breaks this module
puts between them) and with ``parse_math=False`` (``$`` is text, not mathtext).
"""

from __future__ import annotations

import io
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np
from matplotlib import colormaps
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Polygon, Rectangle
from matplotlib.text import Annotation, Text
from numpy.typing import NDArray

from storyteller.sim.no_follow_writes import write_file
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.visible_text import plain

BODY_RADIUS = 0.25  # metres: radius of a character's disc in the picture
_FLOOR_COLOUR = "#4a6fa5"
_SUPPORTED_COLOUR = "#9bb7d4"
_EDGE_COLOUR = "#1f2a38"


@dataclass(frozen=True)
class CharacterMarker:
    """A character drawn as a disc with a heading arrow. Metres; heading is a unit-ish xy vector."""

    name: str
    position: tuple[float, float]
    heading: tuple[float, float] | None = None
    label: str | None = None  # e.g. the current action or event; shown under the name


def _figure_size(scene: Scene, size_px: int, dpi: int) -> tuple[float, float]:
    """Figure size in inches: width ``size_px`` pixels, height from the scene's aspect, both even."""
    dx = scene.bounds_max[0] - scene.bounds_min[0] + 1.0
    dy = scene.bounds_max[1] - scene.bounds_min[1] + 1.0
    width = max(2, int(size_px) // 2 * 2)
    height = int(np.clip(width * dy / dx * 0.92 + 70, 200, 4 * width)) // 2 * 2
    return width / dpi, height / dpi


def _new_axes(scene: Scene, title: str | None, size_px: int, dpi: int) -> tuple[Figure, Axes]:
    fig = Figure(figsize=_figure_size(scene, size_px, dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig, fig.add_axes((0.07, 0.06, 0.9, 0.86 if title else 0.9))


def _draw_static(
    fig: Figure,
    ax: Axes,
    scene: Scene,
    *,
    clusters: Sequence[Sequence[str]] | None,
    nav_free: NDArray[np.float64] | None,
    nav_origin: tuple[float, float],
    nav_cell_size: float,
    title: str | None,
    show_names: bool,
) -> None:
    """The layers that do not move: floor, blocked cells, furniture, names, axes, title."""
    (x0, y0), (x1, y1) = scene.bounds_min, scene.bounds_max
    ax.add_patch(
        Rectangle(
            (x0, y0), x1 - x0, y1 - y0, facecolor="#f7f5f0", edgecolor="#888888", lw=1.0, zorder=0
        )
    )
    if nav_free is not None:
        _draw_blocked(ax, nav_free, nav_origin, nav_cell_size)
    _draw_objects(ax, scene, _cluster_colours(clusters), show_names)
    margin = 0.3
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim(y0 - margin, y1 + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    if title:
        fig.suptitle(plain(title), fontsize=9, parse_math=False)


def _draw_blocked(
    ax: Axes, nav_free: NDArray[np.float64], nav_origin: tuple[float, float], nav_cell_size: float
) -> None:
    """The navigation grid's blocked cells, shaded (``nav_free``: (nx, ny) bool, True = free)."""
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


def _cluster_colours(clusters: Sequence[Sequence[str]] | None) -> dict[str, tuple[float, float, float, float]]:
    """Object name -> the colour of its cluster (tab20, cycling); no entry outside every cluster."""
    colour_of: dict[str, tuple[float, float, float, float]] = {}
    if clusters:
        cmap = colormaps["tab20"]
        for k, names in enumerate(clusters):
            for name in names:
                colour_of[name] = cmap(k % 20)
    return colour_of


def _draw_objects(
    ax: Axes, scene: Scene, colour_of: Mapping[str, tuple[float, float, float, float]], show_names: bool
) -> None:
    """Every object's footprint (lowest first), its facing arrow, its seat point and its name."""
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
            _draw_name(ax, obj, on_floor, carried)
    if arrows_xy:
        xy, uv = np.array(arrows_xy), np.array(arrows_uv)
        ax.quiver(
            xy[:, 0], xy[:, 1], uv[:, 0], uv[:, 1],
            angles="xy", scale_units="xy", scale=1.0, width=0.003, color="#c0392b", zorder=5,
        )  # fmt: skip


def _draw_name(ax: Axes, obj: SceneObject, on_floor: bool, carried: Sequence[SceneObject]) -> None:
    """``obj``'s name on its footprint: centred, set above the centre for an object standing on
    another, moved towards the back of one that something stands on."""
    name_xy = obj.center_xy
    if on_floor and any(
        o.z_min >= obj.z_max - 0.05 and bool(obj.contains_xy(o.center_xy)) for o in carried
    ):  # something stands on it: move its name towards its back, out of the way
        name_xy = name_xy - np.asarray(obj.facing) * obj.depth * 0.3
    ax.text(
        name_xy[0],
        name_xy[1],
        plain(obj.name),
        parse_math=False,  # names are data: '$\\bar$' is text, not mathtext
        fontsize=5.5,
        ha="center",
        va="center" if on_floor else "bottom",
        zorder=6,
        bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.6},
    )


def _marker_text(marker: CharacterMarker) -> str:
    """A character's name, and its label on a second line: each escaped (one line each)."""
    return plain(marker.name) if not marker.label else f"{plain(marker.name)}\n{plain(marker.label)}"


def _caption_text(captions: Sequence[str]) -> str:
    """The caption lines, each escaped (one line each), one under the other."""
    return "\n".join(plain(line) for line in captions)


def _draw_moving(
    ax: Axes,
    *,
    characters: Sequence[CharacterMarker] | None,
    paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None,
    captions: Sequence[str] | None,
) -> list[Artist]:
    """The layers of one moment (trails, characters, captions), drawn above every static layer
    (z-order 7 and up); returns the artists added to ``ax``."""
    before = set(ax.get_children())
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
        ax.text(
            px,
            py - BODY_RADIUS - 0.05,
            _marker_text(marker),
            parse_math=False,
            fontsize=6,
            ha="center",
            va="top",
            zorder=9,
            fontweight="bold",
        )

    if captions:
        ax.text(
            0.01,
            0.99,
            _caption_text(captions),
            parse_math=False,
            transform=ax.transAxes,
            fontsize=7,
            ha="left",
            va="top",
            zorder=10,
            bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "#888888", "alpha": 0.85},
        )
    return [a for a in ax.get_children() if a not in before]


class TopdownLayers(TypedDict, total=False):
    """The keyword arguments of :func:`draw_topdown` after the scene (see the module doc)."""

    clusters: Sequence[Sequence[str]] | None
    nav_free: NDArray[np.float64] | None
    nav_origin: tuple[float, float]
    nav_cell_size: float
    characters: Sequence[CharacterMarker] | None
    paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None
    title: str | None
    captions: Sequence[str] | None
    show_names: bool
    size_px: int
    dpi: int


def draw_topdown(
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
    fig, ax = _new_axes(scene, title, size_px, dpi)
    _draw_static(
        fig, ax, scene, clusters=clusters, nav_free=nav_free, nav_origin=nav_origin,
        nav_cell_size=nav_cell_size, title=title, show_names=show_names,
    )  # fmt: skip
    _draw_moving(ax, characters=characters, paths=paths, captions=captions)
    return fig


def render_topdown_rgb(scene: Scene, **layers: Unpack[TopdownLayers]) -> NDArray[np.uint8]:
    """The picture as an ``(H, W, 3)`` uint8 array (one frame of an animation)."""
    fig = draw_topdown(scene, **layers)
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class TopdownAnimation:
    """Frames of one scene: the static layers drawn once, the moving ones per frame.

    ``frame(characters=..., paths=..., captions=...)`` returns an ``(H, W, 3)`` uint8 picture
    of the same shape as ``render_topdown_rgb(scene, size_px=...)``. Frames are independent:
    each starts from the saved static picture, so the moving layers of one frame never show in
    the next.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        clusters: Sequence[Sequence[str]] | None = None,
        nav_free: NDArray[np.float64] | None = None,
        nav_origin: tuple[float, float] = (0.0, 0.0),
        nav_cell_size: float = 0.3,
        title: str | None = None,
        show_names: bool = True,
        size_px: int = 900,
        dpi: int = 100,
    ) -> None:
        self._fig, self._ax = _new_axes(scene, title, size_px, dpi)
        _draw_static(
            self._fig, self._ax, scene, clusters=clusters, nav_free=nav_free,
            nav_origin=nav_origin, nav_cell_size=nav_cell_size, title=title, show_names=show_names,
        )  # fmt: skip
        canvas = self._fig.canvas
        assert isinstance(canvas, FigureCanvasAgg)
        self._canvas = canvas
        canvas.draw()  # lays out the axes (equal aspect) and renders every static layer
        self._background = canvas.copy_from_bbox(self._fig.bbox)
        self._artists: list[Artist] = []  # the moving layers' artists, in drawing order
        # the same, by kind, in the order _draw_moving made them
        self._lines: list[Line2D] = []
        self._discs: list[Circle] = []
        self._arrows: list[Annotation] = []
        self._texts: list[Text] = []
        self._layout: object = None

    def frame(
        self,
        *,
        characters: Sequence[CharacterMarker] | None = None,
        paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None = None,
        captions: Sequence[str] | None = None,
    ) -> NDArray[np.uint8]:
        """The static picture with these moving layers drawn on it."""
        self._canvas.restore_region(self._background)
        if not self._update(characters, paths, captions):  # another cast: new artists
            for artist in self._artists:
                artist.remove()
            self._artists = _draw_moving(self._ax, characters=characters, paths=paths, captions=captions)
            self._layout = _layout(characters, paths, captions)
            self._lines = [a for a in self._artists if isinstance(a, Line2D)]
            self._discs = [a for a in self._artists if isinstance(a, Circle)]
            self._arrows = [a for a in self._artists if isinstance(a, Annotation)]
            self._texts = [a for a in self._artists if isinstance(a, Text) and not isinstance(a, Annotation)]
            # the order of a full draw: by z-order, ties in the order the artists were added
            self._artists.sort(key=lambda a: a.get_zorder())
        for artist in self._artists:
            self._ax.draw_artist(artist)
        return np.asarray(self._canvas.buffer_rgba())[..., :3].copy()

    def _update(
        self,
        characters: Sequence[CharacterMarker] | None,
        paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None,
        captions: Sequence[str] | None,
    ) -> bool:
        """Move the previous frame's artists to these layers; False when the layers are not
        the same kinds of things as last time (then the artists are made anew)."""
        if self._layout is None or _layout(characters, paths, captions) != self._layout:
            return False
        assert isinstance(paths, Mapping) and characters is not None
        lines = iter(self._lines)
        for line in paths.values():
            pts = np.asarray(line, dtype=np.float64).reshape(-1, 2)
            trail, end = next(lines), next(lines)
            trail.set_data(pts[:, 0], pts[:, 1])
            end.set_data([pts[-1, 0]], [pts[-1, 1]])
        arrows = iter(self._arrows)
        texts = iter(self._texts)
        for marker, disc in zip(characters, self._discs, strict=True):
            px, py = marker.position
            disc.set_center((px, py))
            h = np.asarray(marker.heading, dtype=np.float64)
            h = h / float(np.hypot(*h)) * (BODY_RADIUS + 0.2)
            arrow = next(arrows)
            arrow.xy = (px + h[0], py + h[1])
            arrow.set_position((px, py))
            label = next(texts)
            label.set_position((px, py - BODY_RADIUS - 0.05))
            label.set_text(_marker_text(marker))
        if captions:
            next(texts).set_text(_caption_text(captions))
        return True


def _layout(
    characters: Sequence[CharacterMarker] | None,
    paths: Sequence[NDArray[np.float64]] | Mapping[str, NDArray[np.float64]] | None,
    captions: Sequence[str] | None,
) -> object:
    """What decides which artists a frame has; None when frames of this kind are drawn anew
    each time (trails not keyed by character, a character without a heading, an empty trail)."""
    if not isinstance(paths, Mapping) or characters is None:
        return None
    for marker in characters:
        if marker.heading is None or float(np.hypot(*marker.heading)) <= 1e-9:
            return None
    if any(len(np.asarray(line).reshape(-1, 2)) == 0 for line in paths.values()):
        return None
    return (tuple(m.name for m in characters), tuple(paths), bool(captions))

def topdown_png_bytes(scene: Scene, **layers: Unpack[TopdownLayers]) -> bytes:
    """The picture as PNG bytes."""
    fig = draw_topdown(scene, **layers)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def save_topdown_png(path: Path | str, scene: Scene, **layers: Unpack[TopdownLayers]) -> Path:
    """Write the picture to ``path`` as PNG; returns the path."""
    path = Path(path)
    write_file(path, topdown_png_bytes(scene, **layers))
    return path
