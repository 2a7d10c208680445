"""A track's joint rotations as one scipy ``Rotation``, converted from matrices once for every
exporter of a run.

``Rotation.from_matrix`` orthonormalises every matrix (an SVD each; about 0.05 s per minute of one
character). The SMPL-X npz (axis-angle), the BVH (Euler angles) and the GLB (quaternions) all
start from the same local rotations; only the root's differs, premultiplied by the file's axes
(:meth:`JointRotations.with_root`). :class:`JointRotations` converts the local rotations once and
each export indexes them.

Guarantee: every value is bit for bit the one a conversion of the same matrices inside each
exporter gives, because scipy converts each matrix on its own (its result does not depend on
the other matrices of the batch or their order); ``tests/sim/export/test_export_joint_rotations.py`` checks
it against the per-exporter conversion.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.sim.world.character_track import CharacterTrack


@dataclass(frozen=True)
class JointRotations:
    """``local``: the (N * J,) rotations of ``matrices`` (N frames, J joints), frame-major."""

    matrices: NDArray[np.float64]
    local: Rotation

    @classmethod
    def of(cls, track: CharacterTrack) -> JointRotations:
        m = track.local_rotations
        return cls(m, Rotation.from_matrix(m.reshape(-1, 3, 3)))

    @property
    def frames(self) -> int:
        return int(self.matrices.shape[0])

    @property
    def joints(self) -> int:
        return int(self.matrices.shape[1])

    def with_root(self, axes: NDArray[np.float64], order: Sequence[int] | None = None) -> Rotation:
        """(N * J,) frame-major rotations of the matrices with the root's (joint 0) replaced by
        ``axes @ root``, the joints of each frame in ``order`` (default: as stored): what
        ``Rotation.from_matrix`` of those matrices gives."""
        n, j = self.frames, self.joints
        root = Rotation.from_matrix(axes @ self.matrices[:, 0])
        index = np.arange(n * j).reshape(n, j)
        index[:, 0] = n * j + np.arange(n)
        if order is not None:
            index = index[:, list(order)]
        return Rotation.concatenate([self.local, root])[index.reshape(-1)]


__all__ = ["JointRotations"]
