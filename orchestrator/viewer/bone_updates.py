"""Posing all the bones of a skinned figure at once, as viser's per-bone setters would, cheaper.

viser 1.1.1 (pinned in ``pyproject.toml``) sets one bone at a time: ``bone.wxyz = v`` casts ``v``,
tests it against the bone's current value with ``np.allclose`` and, when it differs, stores it
and queues a ``SetBoneOrientationMessage`` (``bone.position``: a ``SetBonePositionMessage``).
Twenty figures of 22 bones are 880 such calls per shown frame; measured in the viewer following a
live 20-character run, the setters were nearly all of its play thread's CPU and ``np.allclose``
on 4-vectors 60% of theirs (``benchmark/results/2026-12-07-viewer-incremental.md``).

:func:`pose_bones` does what those calls do, with the test made once per figure over all its
bones (``np.isclose`` with ``np.allclose``'s tolerances, the new value first, as viser calls it):
the bones whose value differs get the same stored value (a tuple of floats) and the same message,
queued the same way (the scene API's ``_queue_scene_message``, which stamps its owner), in the
same order as the per-bone loop (each bone's orientation, then its position). It reads viser's
bone state (``_impl``), so it is tied to the pinned version; ``test_viewer`` checks it against
the setters message for message.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import viser
from viser import _messages


def pose_bones(bones: Sequence[viser.MeshSkinnedBoneHandle], wxyz: np.ndarray, positions: np.ndarray) -> int:
    """Set bone ``j`` of ``bones`` (one figure's) to ``wxyz[j]`` (4,) and ``positions[j]`` (3,),
    as ``bone.wxyz = ...; bone.position = ...`` for each bone in turn; returns the messages queued."""
    if not bones:
        return 0
    states = [bone._impl for bone in bones]
    mesh = states[0].mesh_impl
    if mesh.removed:
        raise RuntimeError("Cannot assign a bone pose on a removed skinned mesh")
    if wxyz.shape != (len(states), 4) or positions.shape != (len(states), 3):
        raise ValueError(f"expected ({len(states)}, 4) and ({len(states)}, 3) poses, got {wxyz.shape}, {positions.shape}")
    new_w = ~np.isclose(wxyz, np.array([s.wxyz for s in states])).all(axis=1)
    new_p = ~np.isclose(positions, np.array([s.position for s in states])).all(axis=1)
    queue = mesh.api._queue_scene_message
    sent = 0
    for j in np.flatnonzero(new_w | new_p):
        state = states[j]
        if new_w[j]:
            w = (float(wxyz[j, 0]), float(wxyz[j, 1]), float(wxyz[j, 2]), float(wxyz[j, 3]))
            state.wxyz[:] = w
            queue(_messages.SetBoneOrientationMessage(state.name, state.bone_index, w))
            sent += 1
        if new_p[j]:
            p = (float(positions[j, 0]), float(positions[j, 1]), float(positions[j, 2]))
            state.position[:] = p
            queue(_messages.SetBonePositionMessage(state.name, state.bone_index, p))
            sent += 1
    return sent
