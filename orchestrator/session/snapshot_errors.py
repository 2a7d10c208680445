"""The one error of reading a session checkpoint back (:mod:`storyteller.orchestrator.session.snapshot_file`
and the checks it runs, :mod:`.snapshot_tree` and :mod:`.snapshot_sense`)."""

from __future__ import annotations


class SnapshotError(Exception):
    """A checkpoint file that cannot be read against this world (the message says why)."""
