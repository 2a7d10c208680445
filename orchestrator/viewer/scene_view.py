"""A run in a ``viser`` scene: the scene's boxes, each character's path, figure and label.

:class:`SceneView` adds the static parts once (floor, one labelled box per object, each
character's path as a line on the floor) and, per frame, poses the figures (skinned meshes: the stand-in
figure of :mod:`.figures`, or a character's SMPL-X body from :mod:`storyteller.orchestrator.bodies` when
given) and moves the labels ("name: action" above each head, and a caption with what the
events on at that frame have the characters do: their plan sentences, ``storyteller.agents.story_text``). Everything goes through ``server.scene``, so every connected browser
and a scene recording (:mod:`.export`) see the same thing. World frame: z up, metres. Names,
actions and activities are data: labels get them with control characters shown as escapes
(:func:`storyteller.orchestrator.safe_text.plain`; viser draws label text literally, no markup).

A run in progress grows: :meth:`SceneView.extend` poses only the frames that arrived and redraws
the paths, so a live viewer neither rebuilds the scene nor re-poses the whole story per chunk.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping

import numpy as np
import viser

from storyteller.orchestrator.bodies.smplx_meshes import SmplxBody
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.viewer.bone_updates import pose_bones
from storyteller.orchestrator.viewer.figures import BonePoses, FigureRig, bone_poses, standin_rig
from storyteller.orchestrator.viewer.run_folder import RunData
from storyteller.orchestrator.viewer.timeline import action_at, active_events, clock, event_text
from storyteller.sim.body.skeleton import JOINT_INDEX, NUM_JOINTS
from storyteller.sim.world.character_track import CharacterTrack

CHARACTER_RGB: tuple[tuple[int, int, int], ...] = (
    (217, 84, 64), (64, 140, 217), (89, 179, 89), (230, 179, 51),
    (153, 102, 191), (51, 191, 191), (217, 115, 166), (140, 140, 140),
)  # fmt: skip
LABEL_ABOVE_HEAD = 0.35  # metres above the head joint
PATH_LIFT = 0.01  # metres above the floor, so the path is not hidden by it
PATH_STRIDE = 3  # frames between path points
MAX_CAPTION_EVENTS = 24
"""Events a caption lists (a character is in one event at a time, and a run has at most 24):
9,000 overlapping events of 2,000 characters took ``view --export`` to 1.3 GB in captions."""


def object_rgb(label: str) -> tuple[int, int, int]:
    """A stable pastel colour per object label (as in the GLB export)."""
    h = zlib.crc32(label.encode("utf-8"))
    r, g, b = (int(255 * (0.45 + 0.4 * (((h >> s) & 0xFF) / 255))) for s in (0, 8, 16))
    return r, g, b


def _yaw_wxyz(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))


def _body_rig(body: SmplxBody) -> FigureRig:
    """A body mesh as a viser skinned mesh (dense weights over the 22 bones)."""
    skin = body.skin
    weights = np.zeros((skin.vertices.shape[0], NUM_JOINTS))
    np.add.at(weights, (np.arange(skin.vertices.shape[0])[:, None], skin.joints), skin.weights)
    return FigureRig(vertices=skin.vertices, faces=skin.faces, skin_weights=weights, bind_positions=skin.bind_joints)


def _body_poses(body: SmplxBody) -> BonePoses:
    return BonePoses(wxyz=body.bone_wxyz, positions=body.bone_positions)


class SceneView:
    """The viser scene of one run; :meth:`show` poses it at a frame."""

    def __init__(
        self,
        server: viser.ViserServer,
        run: RunData,
        *,
        object_labels: bool = True,
        bodies: Mapping[str, SmplxBody] | None = None,
    ) -> None:
        self.server = server
        self.run = run
        self.last_frame = run.num_frames - 1
        bodies = bodies or {}
        self.poses: dict[str, BonePoses] = {
            t.name: bone_poses(t) if t.name not in bodies else _body_poses(bodies[t.name]) for t in run.tracks
        }
        scene = server.scene
        scene.set_up_direction("+z")
        self._add_scene(object_labels)
        standin = standin_rig()
        identity = np.tile([1.0, 0.0, 0.0, 0.0], (NUM_JOINTS, 1))
        self.figures: dict[str, viser.MeshSkinnedHandle] = {}
        self.labels: dict[str, viser.LabelHandle] = {}
        self.grows = not bodies
        """Whether :meth:`extend` can add frames (not with SMPL-X bodies, computed for the whole run)."""
        for i, track in enumerate(run.tracks):
            rgb = CHARACTER_RGB[i % len(CHARACTER_RGB)]
            self._add_path(track, rgb)
            body = bodies.get(track.name)
            rig = standin if body is None else _body_rig(body)
            self.figures[track.name] = scene.add_mesh_skinned(
                f"/characters/{track.name}",
                rig.vertices,
                rig.faces,
                bone_wxyzs=identity,
                bone_positions=rig.bind_positions,
                skin_weights=rig.skin_weights,
                color=rgb,
                flat_shading=body is None,
            )
            self.labels[track.name] = scene.add_label(
                f"/labels/{track.name}", plain(track.name), anchor="bottom-center", font_screen_scale=1.2
            )
        self.caption = scene.add_label("/caption", "", position=self._caption_position(), anchor="bottom-left")
        self._set_camera()

    def extend(self, run: RunData) -> bool:
        """Show ``run`` when it is this view's run with more frames (a run in progress): pose
        the new frames and redraw the paths, the rest of the scene untouched. False, changing
        nothing, when it is not (other characters or scene, frames that differ or are gone,
        SMPL-X bodies): the caller builds a new view then."""
        old = self.run
        if not self.grows or run.scene != old.scene or [t.name for t in run.tracks] != [t.name for t in old.tracks]:
            return False
        for before, after in zip(old.tracks, run.tracks, strict=True):
            k = before.num_frames
            if after.num_frames < k or not np.array_equal(after.root_positions[:k], before.root_positions):
                return False
        for i, (before, after) in enumerate(zip(old.tracks, run.tracks, strict=True)):
            if after.num_frames > before.num_frames:
                self.poses[after.name] = self.poses[after.name].then(bone_poses(after, start=before.num_frames))
                self._add_path(after, CHARACTER_RGB[i % len(CHARACTER_RGB)])
        self.run = run
        self.last_frame = run.num_frames - 1
        return True

    # ----- static parts --------------------------------------------------------------
    def _add_path(self, track: CharacterTrack, rgb: tuple[int, int, int]) -> None:
        """The character's path on the floor (replaces the one drawn before)."""
        root = track.root_positions[::PATH_STRIDE]
        pts = np.column_stack([root[:, :2], np.full(len(root), self._floor_z() + PATH_LIFT)])
        if len(pts) >= 2:
            self.server.scene.add_line_segments(
                f"/paths/{track.name}", np.stack([pts[:-1], pts[1:]], axis=1), rgb, thickness=0.03
            )

    def _floor_z(self) -> float:
        return self.run.scene.floor_z if self.run.scene is not None else 0.0

    def _add_scene(self, object_labels: bool) -> None:
        scene = self.server.scene
        s = self.run.scene
        if s is None:
            scene.add_grid("/floor", width=10.0, height=10.0, plane="xy")
            return
        (x0, y0), (x1, y1) = s.bounds_min, s.bounds_max
        scene.add_box(
            "/floor", color=(225, 225, 220), dimensions=(x1 - x0, y1 - y0, 0.02),
            position=((x0 + x1) / 2, (y0 + y1) / 2, s.floor_z - 0.01),
        )  # fmt: skip
        for obj in s.objects:
            width, depth, height = (max(v, 1e-3) for v in obj.size)
            scene.add_box(
                f"/objects/{obj.name}",
                color=object_rgb(obj.label),
                dimensions=(width, depth, height),
                wxyz=_yaw_wxyz(obj.yaw - math.pi / 2),
                position=np.array(obj.center),
            )
            if object_labels:
                scene.add_label(
                    f"/object_names/{obj.name}", plain(obj.name), position=(obj.center[0], obj.center[1], obj.z_max + 0.05),
                    anchor="bottom-center", font_screen_scale=0.7,
                )  # fmt: skip

    def _caption_position(self) -> tuple[float, float, float]:
        s = self.run.scene
        if s is None:
            return (-5.0, 5.0, 2.5)
        return (s.bounds_min[0], s.bounds_max[1], s.floor_z + 2.5)

    def _set_camera(self) -> None:
        s = self.run.scene
        if s is None:
            center, size = np.zeros(3), 8.0
        else:
            lo, hi = np.array(s.bounds_min), np.array(s.bounds_max)
            center = np.array([*(lo + hi) / 2, s.floor_z])
            size = float(np.max(hi - lo))
        cam = self.server.initial_camera
        cam.look_at = center
        cam.position = center + np.array([0.0, -0.9 * size, 0.9 * size])
        cam.up = (0.0, 0.0, 1.0)

    # ----- per frame -----------------------------------------------------------------
    def caption_text(self, frame: int) -> str:
        """The caption: the clock and the events on at ``frame``."""
        on = active_events(self.run.events, frame, self.last_frame)
        lines = [f"{clock(frame, self.run.fps)}"] + [event_text(self.run.events[i]) for i in on[:MAX_CAPTION_EVENTS]]
        if len(on) > MAX_CAPTION_EVENTS:
            lines.append(f"(and {len(on) - MAX_CAPTION_EVENTS} more)")
        return "\n".join(lines)

    def show(self, frame: int) -> None:
        """Pose every figure and label at ``frame`` (held at the last frame past a track's end)."""
        head = JOINT_INDEX["head"]
        with self.server.atomic():
            for track in self.run.tracks:
                wxyz, pos = self.poses[track.name].at(frame)
                pose_bones(self.figures[track.name].bones, wxyz, pos)  # each bone's setter, cheaper
                label = self.labels[track.name]
                label.position = pos[head] + np.array([0.0, 0.0, LABEL_ABOVE_HEAD])
                action = action_at(track, frame)
                label.text = plain(f"{track.name}: {action}" if action else track.name)
            self.caption.text = self.caption_text(frame)
