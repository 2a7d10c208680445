"""``storyteller scene ...`` commands."""

from __future__ import annotations

import typer

scene_app = typer.Typer(help="Inspect scenes.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.add_typer(scene_app, name="scene")


@scene_app.command("list")
def list_scenes() -> None:
    """List the bundled scenes."""
    from sim.bundled_scenes import bundled_scene_names

    for name in bundled_scene_names():
        typer.echo(name)
