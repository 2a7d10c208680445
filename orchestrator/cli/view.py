"""``storyteller view RUN_DIR``: watch a run in the browser (logic in ``storyteller.orchestrator.viewer``).

Serves an interactive 3D viewer on 127.0.0.1 (``--port``, the next free port when taken) and
prints its URL. It answers only the pages it served (no other site's page, no DNS rebinding:
``storyteller.orchestrator.viewer.access``). ``--host`` listens on another address (``0.0.0.0``: every
interface), for other machines: then the printed URL carries a token made for this viewer, which
every request must bring, and the line says who can reach it; ``--export FILE`` instead writes one self-contained HTML file that plays the
story. ``--smplx-model DIR`` shows each character's SMPL-X body (computed from its
``<name>.smplx.npz`` with the model files in DIR) instead of the stand-in figure. ``viser``,
``smplx`` and ``torch`` are imported only when the command runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from storyteller.orchestrator.cli.options import fail
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import say


def register(app: typer.Typer) -> None:
    app.command("view")(view_command)


def view_command(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of `storyteller run` (may still be running).")],
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="Port to listen on (0: any free port).")] = 8080,
    host: Annotated[str, typer.Option("--host", help="Address to listen on. 127.0.0.1 (the default): this machine only. Any other (0.0.0.0: every interface) lets other machines connect, with the token in the printed URL.")] = "127.0.0.1",
    export: Annotated[Path | None, typer.Option("--export", help="Write a self-contained HTML file instead of serving.")] = None,
    play: Annotated[bool, typer.Option("--play/--paused", help="Start playing as soon as the run is loaded.")] = False,
    smplx_model: Annotated[Path | None, typer.Option("--smplx-model", help="Folder with the SMPL-X model files (SMPLX_NEUTRAL.npz ...): show body meshes instead of stand-in figures.")] = None,
    parent: Annotated[int | None, typer.Option("--parent", hidden=True, help="Stop when this process is no longer the parent (run --view's child).")] = None,
) -> None:
    """Show a run in 3D in the browser: figures, paths, labels, timeline and event list."""
    from storyteller.orchestrator.bodies.smplx_meshes import SmplxModelError, model_file
    from storyteller.orchestrator.viewer.run_folder import RunFolderError

    if smplx_model is not None:
        try:
            model_file(smplx_model, "neutral")
        except SmplxModelError as exc:
            fail(str(exc))
    if export is not None:
        from storyteller.orchestrator.viewer.export import export_html

        try:
            export_html(run_dir, export, smplx_model=smplx_model)
        except (RunFolderError, SmplxModelError) as exc:
            fail(str(exc))
        except OSError as exc:
            fail(f"{export}: cannot write ({exc.strerror})")
        say(f"wrote {plain(export)}")
        return
    if run_dir.exists() and not run_dir.is_dir():
        fail(f"{run_dir}: not a folder (expected the --out folder of `storyteller run`)")
    import os
    import threading

    from storyteller.orchestrator.viewer.server import ViewerApp

    try:
        viewer = ViewerApp(run_dir, port=port, host=host, autoplay=play, smplx_model=smplx_model)
    except OSError as exc:  # an address this machine does not have, or cannot resolve
        fail(f"--host {host}: cannot listen there ({exc.strerror or exc})")
    viewer.start()
    say(viewer.reach(str(run_dir)))
    try:
        while not threading.Event().wait(1.0):
            if parent is not None and os.getppid() != parent:  # `run --view` ended, even by kill -9
                break
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()


__all__ = ["register", "view_command"]
