"""Per-frame output buffers of a world: pelvis, joint rotations, labels, contacts, event ids.

Arrays are indexed (frame, character, ...) and grow by doubling, so appending a frame writes
into pre-allocated memory instead of copying per-frame lists. Rotations are stored as float32
(orthonormal to ~1e-7, well inside ``CharacterTrack``'s tolerance); strings (motion labels and
event ids) are stored as indices into ``label_names``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sim.body.skeleton import NUM_JOINTS


@dataclass
class TrackBuffers:
    """Per-frame output of every character, grown by doubling (frames, characters, ...)."""

    names: tuple[str, ...]
    capacity: int
    length: int = 0
    pelvis: np.ndarray = field(init=False)
    rotations: np.ndarray = field(init=False)
    labels: np.ndarray = field(init=False)
    contacts: np.ndarray = field(init=False)
    events: np.ndarray = field(init=False)
    label_names: list[str] = field(default_factory=list)
    _label_index: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        n = len(self.names)
        self.pelvis = np.zeros((self.capacity, n, 3))
        self.rotations = np.zeros((self.capacity, n, NUM_JOINTS, 3, 3), dtype=np.float32)
        self.labels = np.zeros((self.capacity, n), dtype=np.int32)
        self.contacts = np.zeros((self.capacity, n, 2), dtype=bool)
        self.events = np.zeros((self.capacity, n), dtype=np.int32)

    def label_id(self, label: str) -> int:
        """Index of ``label`` in ``label_names`` (added on first use)."""
        k = self._label_index.get(label)
        if k is None:
            k = self._label_index[label] = len(self.label_names)
            self.label_names.append(label)
        return k

    def append(
        self, pelvis: np.ndarray, rotations: np.ndarray, labels: Sequence[str], contacts: np.ndarray,
        events: Sequence[str],
    ) -> None:
        """Record one frame: pelvis (N, 3), rotations (N, 22, 3, 3), motion labels (N,), foot
        contacts (N, 2) and event ids (N,; "" outside events)."""
        if self.length == self.capacity:
            grow = max(self.capacity, 1)
            for name in ("pelvis", "rotations", "labels", "contacts", "events"):
                arr = getattr(self, name)
                setattr(self, name, np.concatenate([arr, np.zeros_like(arr[:grow])]))
            self.capacity += grow
        f = self.length
        self.pelvis[f] = pelvis
        self.rotations[f] = rotations
        self.labels[f] = [self.label_id(s) for s in labels]
        self.contacts[f] = contacts
        self.events[f] = [self.label_id(s) for s in events]
        self.length += 1

    def trimmed(self) -> TrackBuffers:
        """A copy holding exactly the recorded frames."""
        out = copy.copy(self)
        out.capacity = max(self.length, 1)
        out.pelvis = self.pelvis[: out.capacity].copy()
        out.rotations = self.rotations[: out.capacity].copy()
        out.labels = self.labels[: out.capacity].copy()
        out.contacts = self.contacts[: out.capacity].copy()
        out.events = self.events[: out.capacity].copy()
        out.label_names = list(self.label_names)
        out._label_index = dict(self._label_index)
        return out
