"""Playing a database's clips between searches: the tables of the compiled clip advance, the
database's own root motion, and the seat-height correction of a seated pelvis.

Pure functions of the databases (``StepDatabase``, ``MotionDatabase``) and explicit inputs;
the matcher (``storyteller.sim.motion.matching``) calls them every step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.database import MotionDatabase
from storyteller.sim.motion.frames import DatabaseFrames, StepDatabase

ClipTables = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_],
                   NDArray[np.bool_]]
"""``advance_clips``'s tables: per database base, per global frame next frame, non-loop end and
looping clip, per database completes and entry index (:func:`clip_tables`)."""


def clip_tables(step_dbs: Sequence[StepDatabase]) -> ClipTables:
    """The frame tables of ``step_dbs`` (in ``StepDatabase.index`` order) for ``advance_clips``:
    per database its base and whether it completes / has an entry index; per global frame
    (base + frame) the next frame, non-loop end, looping clip."""
    size = max((k.base + len(k.tab.nxt) for k in step_dbs), default=0)
    nxt = np.zeros(size, dtype=np.int64)
    end = np.zeros(size, dtype=np.bool_)
    loops = np.zeros(size, dtype=np.bool_)
    for k in step_dbs:
        f = len(k.tab.nxt)
        nxt[k.base: k.base + f] = k.tab.nxt
        end[k.base: k.base + f] = k.tab.end
        loops[k.base: k.base + f] = k.tab.loops
    return (np.array([k.base for k in step_dbs], dtype=np.int64), nxt, end, loops,
            np.array([k.tab.completes for k in step_dbs], dtype=np.bool_),
            np.array([k.tab.entry for k in step_dbs], dtype=np.bool_))


def root_motion(db: MotionDatabase, frame: int, frame_clock: float, root_xy: NDArray[np.float64], heading: float,
                step_frames: float) -> tuple[NDArray[np.float64], float]:
    """Root xy and heading after the database's own root motion over the frames the clock
    passes this step (from ``frame`` at ``frame_clock``; a character whose query gives no root)."""
    n_adv = math.floor(frame_clock + step_frames + 1e-9)
    root_xy = root_xy.copy()
    for _ in range(n_adv):
        nxt, end = db.next_frame(frame)
        if end:
            break
        if nxt == frame + 1:  # root motion of the database (not across a loop seam)
            d = db.root_xy[nxt] - db.root_xy[frame]
            c, s = np.cos(heading - db.heading[frame]), np.sin(heading - db.heading[frame])
            root_xy = root_xy + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
            heading += float(db.heading[nxt] - db.heading[frame])
        frame = nxt
    return root_xy, heading


def seat_correction(db: MotionDatabase, frames: DatabaseFrames, frame: int, seat_height: float | None) -> float:
    """Raise/lower a seated pelvis by the difference between the query's seat height and
    the clip's, weighted by how far the clip has sat down (0 standing .. 1 seated)."""
    if seat_height is None or db.layout_name not in ("sitting", "seated"):
        return 0.0
    clip = int(db.clip_of_frame[frame])
    clip_h = float(db.targets[clip, 3])
    if not np.isfinite(clip_h):
        return 0.0
    top, bottom = (float(v) for v in frames.clip_z[clip])
    w = 1.0 if top - bottom < 0.05 else (top - float(db.pelvis[frame, 2])) / (top - bottom)
    return (float(seat_height) - clip_h) * w
