"""``storyteller view RUN --export story.html``: the whole story in one self-contained file.

The run is put into a ``viser`` scene exactly as the live viewer shows it (:mod:`.scene_view`)
and recorded with viser's scene serializer: the scene, then one pose per recorded frame with
the wall time between them. ``StateSerializer.as_html`` writes that recording into a copy of
the browser client built into the ``viser`` wheel, so the file plays in a browser opened from
disk, with no server, no network and nothing of this project installed. The recording keeps
the 3D scene, the labels (name and action above each figure) and the caption with the events
on at each moment; viser records no GUI panel, so the clickable event list is live only.
"""

from __future__ import annotations

from pathlib import Path

from storyteller.orchestrator.viewer.access import ViewerAccess
from storyteller.orchestrator.viewer.guarded_server import guarded_server
from storyteller.orchestrator.viewer.run_folder import load_run
from storyteller.orchestrator.viewer.scene_view import SceneView

EXPORT_FPS = 15.0  # recorded poses per second of story (the browser interpolates nothing)


def export_html(folder: Path, out: Path, smplx_model: Path | None = None) -> Path:
    """Record the run in ``folder`` into the HTML file ``out``; returns ``out``.

    With ``smplx_model`` the characters are their SMPL-X bodies (:mod:`storyteller.orchestrator.bodies`).
    """
    run = load_run(folder)
    bodies = None
    if smplx_model is not None:
        from storyteller.orchestrator.bodies.smplx_meshes import SmplxModels, run_bodies

        bodies = run_bodies(folder, [t.name for t in run.tracks], SmplxModels(smplx_model))
    stride = max(1, round(run.fps / EXPORT_FPS))
    # a server only to record the scene: on loopback, answering only its own pages (none open)
    server = guarded_server(ViewerAccess.for_host("127.0.0.1"), port=0, label="storyteller", verbose=False)
    try:
        view = SceneView(server, run, bodies=bodies)
        view.show(0)
        recording = server.get_scene_serializer()
        for frame in range(stride, run.num_frames, stride):
            recording.insert_sleep(stride / run.fps)
            view.show(frame)
        recording.insert_sleep(1.0)  # hold the last pose a moment before the player loops
        html = recording.as_html()
    finally:
        server.stop()
    out.write_text(html, encoding="utf-8")
    return out
