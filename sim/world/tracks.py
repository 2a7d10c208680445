"""Per-frame output buffers of a world: pelvis, joint rotations, labels, contacts, event ids.

Arrays are indexed (frame, character, ...) and grow by doubling, so appending a frame writes
into pre-allocated memory instead of copying per-frame lists. Rotations are stored as float32
(orthonormal to ~1e-7, well inside ``CharacterTrack``'s tolerance); strings (motion labels and
event ids) are stored as indices into ``label_names``.

Streaming (``stream_to``): with a :class:`~storyteller.sim.world.track_chunks.ChunkStore`, the buffers hold
only the frames since ``base`` (at most ``window`` of them); when the window is full, its frames
are appended to the store's chunk files and dropped, so memory stays bounded however long the
story runs. Without a store, ``base`` stays 0 and every frame stays in memory (rows are frames).
``frames(k)`` gives a character's whole history either way, read back bit for bit.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.world.track_chunks import ChunkError, ChunkStore, Frames, concat_frames


@dataclass
class TrackBuffers:
    """Per-frame output of every character, grown by doubling (rows, characters, ...); row
    ``r`` is frame ``base + r``."""

    names: tuple[str, ...]
    capacity: int
    length: int = 0
    """Frames recorded so far (on disk and in memory)."""
    base: int = 0
    """Frames already in the chunk store (the first row's frame); 0 without a store."""
    window: int = 0
    """Frames held in memory at most while streaming (0: not streaming)."""
    store: ChunkStore | None = field(default=None, repr=False, compare=False)
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
        if self.store is not None and self.length - self.base >= self.window:
            self.spill()
        f = self.length - self.base
        if f == self.capacity:
            grow = max(self.capacity, 1)
            for name in ("pelvis", "rotations", "labels", "contacts", "events"):
                arr = getattr(self, name)
                setattr(self, name, np.concatenate([arr, np.zeros_like(arr[:grow])]))
            self.capacity += grow
        self.pelvis[f] = pelvis
        self.rotations[f] = rotations
        self.labels[f] = self._label_ids(labels)
        self.contacts[f] = contacts
        self.events[f] = self._label_ids(events)
        self.length += 1

    def _label_ids(self, names: Sequence[str]) -> list[int]:
        """``label_id`` of every name (one dictionary lookup each when all are known)."""
        try:
            return list(map(self._label_index.__getitem__, names))
        except KeyError:  # a new name: added in order
            return [self.label_id(s) for s in names]

    @property
    def held(self) -> int:
        """Frames held in memory (rows in use)."""
        return self.length - self.base

    def stream_to(self, store: ChunkStore, window: int) -> None:
        """From now on keep at most ``window`` frames in memory, the older ones in ``store``
        (which must hold exactly the frames before ``base``)."""
        if window < 1:
            raise ValueError(f"window must be >= 1 frame, got {window}")
        if store.frames != self.base:
            raise ChunkError(f"{store.folder}: the chunk files hold {store.frames} frames, the buffers start at {self.base}")
        self.store, self.window = store, window
        if self.held >= window:
            self.spill()

    def spill(self) -> None:
        """Append the frames held in memory to the store and drop them."""
        if self.store is None:
            raise ChunkError("these track buffers do not stream to a chunk store")
        rows = self.held
        if rows == 0:
            return
        names = self.label_names
        labels = [[names[i] for i in self.labels[:rows, k]] for k in range(len(self.names))]
        events = [[names[i] for i in self.events[:rows, k]] for k in range(len(self.names))]
        self.store.append(self.base, self.pelvis[:rows], self.rotations[:rows], self.contacts[:rows], labels, events)
        self.base = self.length

    def frames(self, k: int) -> Frames:
        """Every frame of character ``k`` so far (the store's, then the ones in memory)."""
        names = self.label_names
        rows = self.held
        held = Frames(
            self.base, self.pelvis[:rows, k].copy(), self.rotations[:rows, k].copy(), self.contacts[:rows, k].copy(),
            tuple(names[i] for i in self.labels[:rows, k]), tuple(names[i] for i in self.events[:rows, k]),
        )
        if self.base == 0:
            return held
        if self.store is None:
            raise ChunkError(f"the first {self.base} frames are in a chunk store these buffers do not have")
        return concat_frames(0, [self.store.read(self.names[k], self.base), held])

    def trimmed(self) -> TrackBuffers:
        """A copy holding exactly the frames held in memory (and ``base``), without the store."""
        out = copy.copy(self)
        out.store = None
        out.capacity = max(self.held, 1)
        out.pelvis = self.pelvis[: out.capacity].copy()
        out.rotations = self.rotations[: out.capacity].copy()
        out.labels = self.labels[: out.capacity].copy()
        out.contacts = self.contacts[: out.capacity].copy()
        out.events = self.events[: out.capacity].copy()
        out.label_names = list(self.label_names)
        out._label_index = dict(self._label_index)
        return out
