"""``storyteller scene ...``: list the bundled scenes, inspect one.

``scene inspect SCENE`` shows objects, relations (scene graph), region clusters and the
navigation grid; ``--json`` prints the same as one JSON object; ``--png FILE`` writes a
top-down picture. A bad scene (or a PNG path that cannot be written) is one line on stderr and
exit code 2.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from storyteller.orchestrator.terminal import say

if TYPE_CHECKING:  # commands import what they need, so that ``scene list`` starts at once
    from storyteller.sim.scene.model import Scene

scene_app = typer.Typer(help="Inspect scenes.", no_args_is_help=True)

EXIT_USAGE = 2
MAX_TABLE_RELATIONS = 1_000
"""Rows of the relations table (the bundled and reference scenes have 81-251 relations; ``--json``
lists them all). Relations grow with the square of packed objects: 400 overlapping boxes have
16,000, whose table took rich 15 s to draw (a hostile-inputs attack, issue 22)."""


class SceneInspectError(Exception):
    """A user error while inspecting: one sentence for stderr, exit code 2."""


def register(app: typer.Typer) -> None:
    app.add_typer(scene_app, name="scene")


@scene_app.command("list")
def list_scenes() -> None:
    """List the bundled scenes."""
    from storyteller.sim.scene.bundled import bundled_scene_names

    for name in bundled_scene_names():
        say(name)


def _r(value: float, digits: int = 4) -> float:
    return round(float(value), digits) + 0.0


def inspect_data(scene: Scene) -> dict[str, Any]:
    """Everything ``scene inspect`` reports, as plain JSON-ready data.

    Keys: ``scene`` (name), ``bounds`` ({min, max} xy in metres), ``objects`` (name, label,
    center [x, y, z], size [width, depth, height], facing [dx, dy], has_facing, seat, supporter),
    ``relations`` ([subject, relation, anchor] triples), ``clusters`` (lists of names), ``grid``
    (cell_size, body_radius, origin, shape [nx, ny], free_cells, blocked_cells,
    main_component_cells, components).
    """
    from storyteller.sim.paths.nav_grid import build_nav_grid
    from storyteller.tools.clusters import cluster_objects
    from storyteller.tools.scene_graph import build_scene_graph

    graph = build_scene_graph(scene)
    triples = [list(t) for t in graph.triples()]
    clusters = [list(c) for c in cluster_objects(scene)]
    grid = build_nav_grid(scene)
    components = grid.component[grid.component >= 0]
    objects = []
    for o in scene.objects:
        objects.append(
            {
                "name": o.name,
                "label": o.label,
                "center": [_r(v) for v in o.center],
                "size": [_r(v) for v in o.size],
                "facing": [_r(v) for v in o.facing],
                "has_facing": o.has_facing,
                "seat": o.is_seat,
                "supporter": graph.supporter(o.name),
            }
        )
    return {
        "scene": scene.name,
        "bounds": {
            "min": [_r(v) for v in scene.bounds_min],
            "max": [_r(v) for v in scene.bounds_max],
        },
        "objects": objects,
        "relations": triples,
        "clusters": clusters,
        "grid": {
            "cell_size": _r(grid.cell_size),
            "body_radius": _r(grid.body_radius),
            "origin": [_r(v) for v in grid.origin],
            "shape": [int(n) for n in grid.free.shape],
            "free_cells": int(grid.free.sum()),
            "blocked_cells": int(grid.free.size - grid.free.sum()),
            "main_component_cells": int((grid.component == grid.main_component).sum())
            if components.size
            else 0,
            "components": len(set(components.tolist())),
        },
        "_grid": grid,  # for the picture; removed before printing
    }


def _print_tables(data: dict[str, Any]) -> None:
    """The tables. Every name and label from the scene file is a rich ``Text`` of
    :func:`~storyteller.orchestrator.safe_text.plain` (control, format and bidi characters shown as
    escapes), never a markup string: rich parses neither markup nor emoji codes in it."""
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    from storyteller.orchestrator.safe_text import plain

    def text(value: object) -> Text:
        return Text(plain(value))

    console = Console()
    if not console.is_terminal:  # piped: do not squeeze the tables into 80 columns
        console = Console(width=max(console.width, 120))
    lo, hi = data["bounds"]["min"], data["bounds"]["max"]
    say(
        Text.assemble(
            (plain(data["scene"]), "bold"),
            f": {len(data['objects'])} objects, floor "
            f"[{lo[0]:.2f}, {hi[0]:.2f}] x [{lo[1]:.2f}, {hi[1]:.2f}] m",
        ),
        console=console,
    )
    objects = Table(title="Objects", title_justify="left")
    for col in ("name", "label", "center x y z (m)", "size w d h (m)", "facing", "seat", "on"):
        objects.add_column(col, no_wrap=col != "on")
    for o in data["objects"]:
        objects.add_row(
            text(o["name"]),
            text(o["label"]),
            " ".join(f"{v:6.2f}" for v in o["center"]),
            " ".join(f"{v:5.2f}" for v in o["size"]),
            " ".join(f"{v:+.2f}" for v in o["facing"]) if o["has_facing"] else "-",
            "yes" if o["seat"] else "",
            text(o["supporter"] or ""),
        )
    say(objects, console=console)

    rows = data["relations"][:MAX_TABLE_RELATIONS]
    relations = Table(title=f"Relations ({len(data['relations'])})", title_justify="left")
    for col in ("subject", "relation", "anchor"):
        relations.add_column(col)
    for s, r, a in rows:
        relations.add_row(text(s), text(r), text(a))
    say(relations, console=console)
    if len(rows) < len(data["relations"]):
        say(f"(the first {len(rows)} of {len(data['relations'])} relations shown; --json lists all)", console=console)

    clusters = Table(title=f"Clusters ({len(data['clusters'])})", title_justify="left")
    clusters.add_column("#", justify="right")
    clusters.add_column("objects")
    for k, names in enumerate(data["clusters"], 1):
        clusters.add_row(str(k), text(", ".join(names)))
    say(clusters, console=console)

    g = data["grid"]
    grid = Table(title="Navigation grid", title_justify="left", show_header=False)
    grid.add_column("key")
    grid.add_column("value", justify="right")
    grid.add_row("cell size (m)", f"{g['cell_size']:.2f}")
    grid.add_row("body radius (m)", f"{g['body_radius']:.2f}")
    grid.add_row("origin (m)", f"{g['origin'][0]:.2f}, {g['origin'][1]:.2f}")
    grid.add_row("cells (nx x ny)", f"{g['shape'][0]} x {g['shape'][1]}")
    grid.add_row("free / blocked", f"{g['free_cells']} / {g['blocked_cells']}")
    grid.add_row("connected areas", str(g["components"]))
    grid.add_row("largest area (cells)", str(g["main_component_cells"]))
    say(grid, console=console)


def _fail(message: str) -> typer.Exit:
    """One line on stderr (whitespace runs folded, control and bidi characters escaped)."""
    from storyteller.orchestrator.safe_text import plain

    say(f"error: {plain(' '.join(message.split()))}", err=True)
    return typer.Exit(code=EXIT_USAGE)


@scene_app.command("inspect")
def inspect_scene(
    scene_spec: Annotated[
        str,
        typer.Argument(
            metavar="SCENE",
            help="A bundled scene name, a reference folder, a .json scene or a mesh file.",
        ),
    ],
    as_json: Annotated[
        bool, typer.Option("--json", help="Print one JSON object instead of tables.")
    ] = False,
    png: Annotated[
        Path | None,
        typer.Option("--png", metavar="FILE", help="Also write a top-down picture here."),
    ] = None,
) -> None:
    """Show a scene's objects, relations, clusters and navigation grid."""
    from storyteller.orchestrator.safe_text import plain
    from storyteller.sim.paths.nav_grid import NavGridError
    from storyteller.sim.scene.bundled import resolve_scene
    from storyteller.sim.scene.files import SceneFileError

    if png is not None:  # fail before the work, not after it
        if png.is_dir():
            raise _fail(f"{png}: is a folder, expected a PNG file path")
        if not png.parent.is_dir():
            raise _fail(f"{png}: cannot write the picture (folder {png.parent} does not exist)")
    try:
        scene = resolve_scene(scene_spec)
        data = inspect_data(scene)
    except SceneFileError as exc:
        raise _fail(str(exc)) from None
    except NavGridError as exc:
        raise _fail(f"{scene_spec}: cannot build the navigation grid: {exc}") from None
    grid = data.pop("_grid")

    if png is not None:
        from storyteller.sim.export.topdown import save_topdown_png

        try:
            save_topdown_png(
                png,
                scene,
                clusters=data["clusters"],
                nav_free=grid.free,
                nav_origin=grid.origin,
                nav_cell_size=grid.cell_size,
                title=f"{plain(scene.name)}: {len(scene.objects)} objects, {len(data['clusters'])} clusters",
            )
        except OSError as exc:
            raise _fail(f"{png}: cannot write the picture ({exc.strerror or exc})") from None

    if as_json:
        if png is not None:
            data["png"] = str(png)
        say(json.dumps(data))
    else:
        _print_tables(data)
        if png is not None:
            say(f"wrote {plain(png)}")
