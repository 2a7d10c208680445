"""The searches of a batched motion-matching step: which frame each searching character plays next.

Characters are grouped per (database, entry index) and searched together (one nearest-frame
query per group); the frame found stands for the pose shown last frame, so its successor is the
one to show now. A character switches (and the caller blends the switch) when its action
changed, the frame found lies in another clip, or it is not a short step ahead of the frame it
plays (``continuation_window`` frames); otherwise it plays on. Deterministic: groups are
searched in the order their first member appears.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.frames import DatabaseFrames, StepDatabase
from storyteller.sim.motion.query_vectors import (
    PoseHistory,
    Steering,
    compiled_query_features,
    query_features_many,
)


def raw_queries(frames_of: Callable[[str], DatabaseFrames], members: Sequence[int], states: Sequence[PoseHistory],
                queries: Sequence[Steering], roots: Sequence[NDArray[np.float64]], headings: Sequence[float],
                info: StepDatabase) -> NDArray[np.float64]:
    """Raw query vectors (M,D) of characters ``members`` searching ``info``'s database: the
    compiled path (``compiled_query_features``) when every one has an output pose, else
    ``query_features_many``."""
    if any(states[i].pose_local is None or states[i].pose_pelvis is None for i in members):
        return query_features_many(frames_of, info.db, [states[i] for i in members], [queries[i] for i in members],
                                   [roots[i] for i in members], [headings[i] for i in members])
    return compiled_query_features(members, states, queries, roots, headings, info.sources)



def search_frames(frames_of: Callable[[str], DatabaseFrames], states: Sequence[PoseHistory],
                  queries: Sequence[Steering], roots: Sequence[NDArray[np.float64]], headings: Sequence[float],
                  infos: Sequence[StepDatabase], need: NDArray[np.bool_], frames: list[int], changed: list[bool],
                  entry: list[bool], continuation_window: int) -> tuple[list[int], list[int]]:
    """The searches of the characters that ``need`` one (``infos``: each one's database,
    ``entry``: whether it searches the entry index, ``changed``: whether its action changed),
    grouped per (database, entry index): every character's frame after them (``frames``: before),
    and the characters that switched (sorted)."""
    new_frames = list(frames)
    switched: list[int] = []
    groups: dict[tuple[str, bool], list[int]] = {}
    for i in np.flatnonzero(need).tolist():
        groups.setdefault((infos[i].key, entry[i]), []).append(i)
    for (_key, ent), members in groups.items():
        info = infos[members[0]]
        db = info.db
        raw = raw_queries(frames_of, members, states, queries, roots, headings, info)
        if len(members) == 1:
            found: Sequence[int] | NDArray[np.int64] = [db.search(raw[0], entry=ent)[0]]
        else:
            index = db.entry_index if ent else db.index
            found = index.query_many(db.normalize(raw))[0]
        clip_of, succ, last_frame = info.tab.clip, info.tab.nxt, info.tab.end
        for i, b in zip(members, found, strict=True):
            # the query is the pose shown last frame, so the frame found stands for that
            # pose: its successor is the one to show now (playing the found frame itself
            # would repeat a frame's pose at every search, and slow a walk's steps)
            b, frame = int(b), frames[i]
            b = b if last_frame[b] else int(succ[b])
            if changed[i] or clip_of[b] != clip_of[frame] or not 0 <= b - frame <= continuation_window:
                switched.append(i)
                new_frames[i] = b
    switched.sort()
    return new_frames, switched
