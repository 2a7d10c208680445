"""The names of the files in a run folder: one home for every name the project writes there.

``storyteller run`` (and ``resume``, ``replay --out``) writes these into its folder; the
simulation's writers (the chunk files, the exports) and the orchestrator's (story, trace,
manifest, checkpoint) take their names from here, and :func:`run_folder_entries` lists them
all for a run's characters (what ``storyteller.orchestrator.session.run_folder_links`` checks before a run
writes anything). Constants only, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

STORY_JSON = "story.json"
"""Every planning step and event, written when the run ends (its presence marks a finished run)."""
STORY_MD = "story.md"
METRICS_JSON = "metrics.json"
TRACE_JSONL = "trace.jsonl"
"""Every LLM call attempt (append-only)."""
RUN_JSON = "run.json"
"""The run's arguments and thread id, written before the first frame."""
SCENE_JSON = "scene.json"
SCENE_GLB = "scene.glb"
RUNS_DB = "runs.sqlite"
"""langgraph checkpoints and the story log (SQLite writes it in place)."""
RUNS_DB_SIDECARS = tuple(f"{RUNS_DB}{suffix}" for suffix in ("-journal", "-wal", "-shm"))
"""The files SQLite keeps next to ``runs.sqlite`` while it writes (journal, write-ahead log, its index)."""
SNAPSHOT = "session.snapshot"
"""The session's last checkpoint, replaced atomically."""
SNAPSHOT_TMP = f"{SNAPSHOT}.tmp"
"""The name ``storyteller.orchestrator.session.snapshot_file`` writes a checkpoint to before renaming it."""
STORY_STREAM = "story.jsonl"
"""The story as it happens, for a live viewer (append-only)."""
VIEWER_INSTRUCTIONS = "viewer_instructions.jsonl"
"""Instructions typed in a viewer's box, appended by the viewer and read by the run (append-only)."""
VIEWER_CONTROLS = "viewer_controls.jsonl"
"""Pause, resume and speed pressed in a viewer, appended by the viewer and read by the run (append-only)."""
LIVE_STATE = "live.json"
"""The run now (frame, pause, speed, the planner's roles, each character), replaced a few times a second."""
TOPDOWN_PNG = "topdown.png"
ANIMATION_STEM = "story"
ANIMATIONS = tuple(f"{ANIMATION_STEM}{suffix}" for suffix in (".gif", ".mp4"))
"""``--gif`` / ``--video``: the run animated (``story.mp4``, or ``story.gif`` without an MP4 encoder)."""
MOTION_FOLDER = "motion"
"""The sub-folder that holds the chunk files."""
CHUNK_SUFFIX = ".chunks"
"""``motion/<slug>.chunks``: a character's motion as it is simulated (append-only)."""
SMPLX_SUFFIX = ".smplx.npz"
BVH_SUFFIX = ".bvh"
TRACK_SUFFIX = ".track.npz"
CHARACTER_SUFFIXES = (SMPLX_SUFFIX, BVH_SUFFIX, TRACK_SUFFIX)
"""``<slug><suffix>``: the exports of each character."""

APPENDED = (TRACE_JSONL, STORY_STREAM, VIEWER_INSTRUCTIONS, VIEWER_CONTROLS, RUNS_DB, *RUNS_DB_SIDECARS)
"""The files written in place (appended to, or SQLite's) rather than replaced whole; with the chunk files."""

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


def file_slug(name: str) -> str:
    """The file-name form of a character name: anything but letters, digits, ``-`` and ``_``
    becomes ``_`` (``character`` for a name with nothing left)."""
    return _UNSAFE.sub("_", name.strip()) or "character"


def chunk_entry(name: str) -> str:
    """``motion/<slug>.chunks`` of the character ``name``, relative to the run folder."""
    return f"{MOTION_FOLDER}/{file_slug(name)}{CHUNK_SUFFIX}"


def run_folder_entries(names: Sequence[str]) -> tuple[str, ...]:
    """Every path (relative to the run folder, ``/``-separated) a run of the characters
    ``names`` may write, ``motion`` before the chunk files in it."""
    whole = (STORY_JSON, STORY_MD, METRICS_JSON, RUN_JSON, SCENE_JSON, SCENE_GLB, SNAPSHOT, SNAPSHOT_TMP,
             TOPDOWN_PNG, LIVE_STATE, *ANIMATIONS)
    exports = tuple(f"{file_slug(n)}{suffix}" for n in names for suffix in CHARACTER_SUFFIXES)
    return (*APPENDED, *whole, *exports, MOTION_FOLDER, *(chunk_entry(n) for n in names))
