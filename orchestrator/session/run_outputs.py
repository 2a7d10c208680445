"""What a finished ``run`` writes to its folder: ``story.json`` (:func:`story_json`), ``story.md``
and ``metrics.json`` (``storyteller.orchestrator.session.run_report``), ``scene.json``, the motion exports
and the pictures (:func:`write_outputs`). Every file is written without following a link
(``storyteller.sim.no_follow_writes``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from storyteller.agents.messages import ParsedEvent, PlanningFailure
from storyteller.agents.story_text import step_text
from storyteller.orchestrator.session.session_types import SessionResult
from storyteller.sim.no_follow_writes import replacing, write_file
from storyteller.sim.run_folder_names import (
    ANIMATION_STEM,
    METRICS_JSON,
    SCENE_JSON,
    STORY_JSON,
    STORY_MD,
    TOPDOWN_PNG,
)
from storyteller.sim.scene.model import Scene

if TYPE_CHECKING:
    from storyteller.sim.world.step import World


def story_json(result: SessionResult, scene_name: str, names: list[str], instruction: str, fps: int) -> dict[str, Any]:
    """``story.json``: every planning step with the frame it was applied at, and every event."""
    steps = []
    for (index, outcome), frame in zip(result.outcomes, result.applied_frames, strict=True):
        entry: dict[str, Any] = {"index": index, "applied_frame": frame}
        if outcome is None:
            entry.update(kind="wait", text=step_text(None))
        elif isinstance(outcome, PlanningFailure):
            entry.update(kind="failed", node=outcome.node, feedback=outcome.feedback, text=step_text(outcome))
        elif isinstance(outcome, ParsedEvent):
            entry.update(
                kind="event",
                characters=list(outcome.event.characters),
                activity=outcome.event.activity,
                plans=[
                    {
                        "character": p.character,
                        "action": p.action,
                        "area": p.area,
                        "position": [round(p.position[0], 3), round(p.position[1], 3)],
                        "facing": [round(p.facing[0], 3), round(p.facing[1], 3)],
                        "seat": p.seat,
                    }
                    for p in outcome.plans
                ],
            )
        steps.append(entry)
    events = [
        {
            "event_id": e.event_id,
            "index": e.index,
            "characters": list(e.characters),
            "activity": e.activity,
            "requested_frame": e.requested_frame,
            "applied_frame": e.applied_frame,
            "state": e.state,
            "finished_frame": e.finished_frame,
            "failure": e.failure,
            "part": e.part,
            "text": e.text,
            "narration": e.narration,
        }
        for e in result.events
    ]
    return {
        "scene": scene_name,
        "characters": names,
        "instruction": instruction,
        "instructions": [
            {"frame": i.frame, "time_s": round(i.frame / fps, 3), "source": i.source, "text": i.text}
            for i in result.instructions
        ],
        "fps": fps,
        "frames": result.frames,
        "steps": steps,
        "events": events,
    }


def write_outputs(
    out: Path, scene: Scene, world: World, result: SessionResult, names: list[str], instruction: str, fps: int, gif: bool,
    video: bool = False,
    trace_path: Path | None = None,
    smplx_model: Path | None = None,
) -> None:
    """``story.json``, ``story.md``, ``metrics.json`` (LLM use from ``trace_path``, when the run
    wrote a trace), ``scene.json`` (the scene as run, for ``storyteller view``), the motion
    exports (npz, BVH, GLB; with ``smplx_model`` the GLB carries SMPL-X body meshes) and the
    top-down pictures in ``out``."""
    from storyteller.orchestrator.session.run_report import run_metrics, story_markdown
    from storyteller.sim.export.bundle import export_run
    from storyteller.sim.export.video import (
        RunRecording,
        animation_suffix,
        save_run_animation,
        save_run_png,
    )

    write_scene_json(scene, out)
    payload = story_json(result, scene.name, names, instruction, fps)
    write_file(out / STORY_JSON, (json.dumps(payload, indent=2) + "\n").encode("utf-8"))
    write_file(out / STORY_MD, story_markdown(payload).encode("utf-8"))
    metrics = run_metrics(payload, trace_path, wall_s=result.wall_s, frame_intervals_s=list(result.frame_intervals_s))
    write_file(out / METRICS_JSON, (json.dumps(metrics, indent=2) + "\n").encode("utf-8"))
    tracks = world.tracks()
    bodies = None
    if smplx_model is not None:
        from storyteller.orchestrator.bodies.smplx_meshes import smplx_bodies
        from storyteller.sim.export.smplx_npz import smplx_parameters

        params = {t.name: smplx_parameters(t) for t in tracks.values()}
        bodies = {name: body.skin for name, body in smplx_bodies(smplx_model, params).items()}
    export_run(out, scene, list(tracks.values()), bodies=bodies)
    recording = RunRecording(scene, tracks, world.event_ids(), world.grid)  # the tracks read above, not again
    save_run_png(out / TOPDOWN_PNG, recording)
    # --video: story.mp4 (story.gif without imageio-ffmpeg); --gif: story.gif
    animations = {name for name, wanted in ((f"{ANIMATION_STEM}.gif", gif), (f"{ANIMATION_STEM}{animation_suffix()}", video))
                  if wanted}
    for name in sorted(animations):
        save_run_animation(out / name, recording, stride=10, speed=4.0)


def write_scene_json(scene: Scene, out: Path) -> None:
    """``scene.json`` (the scene as run, for ``storyteller view``), replaced through a fresh name."""
    from storyteller.sim.scene.files import save_scene_json

    with replacing(out / SCENE_JSON) as fresh:
        save_scene_json(scene, fresh)
