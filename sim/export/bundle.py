"""Write every export of a run into one folder.

Per character ``<slug>`` (its name with anything but letters, digits, ``-`` and ``_`` turned
into ``_``): ``<slug>.smplx.npz`` (AMASS-style SMPL-X parameters), ``<slug>.bvh`` and
``<slug>.track.npz`` (the raw track, reloadable with ``CharacterTrack.load``); plus one
``scene.glb`` with the scene and every character.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from sim.export.bvh import Units, export_bvh
from sim.export.glb import SkinnedBody, export_glb
from sim.export.smplx_npz import export_smplx_npz
from sim.scene.model import Scene
from sim.world.character_track import CharacterTrack

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


@dataclass(frozen=True)
class RunExports:
    """Paths written by :func:`export_run`."""

    glb: Path
    smplx: dict[str, Path]
    bvh: dict[str, Path]
    tracks: dict[str, Path]

    def all_paths(self) -> list[Path]:
        return [self.glb, *self.smplx.values(), *self.bvh.values(), *self.tracks.values()]


def file_slug(name: str) -> str:
    """A file-name-safe form of a character name."""
    return _UNSAFE.sub("_", name.strip()) or "character"


def export_run(
    outdir: str | Path,
    scene: Scene | None,
    tracks: Sequence[CharacterTrack],
    *,
    bvh_units: Units = "m",
    bodies: Mapping[str, SkinnedBody] | None = None,
) -> RunExports:
    """Write all exports of a run into ``outdir`` (created if missing); returns their paths.

    ``bodies`` (by character name) are body meshes for the GLB (see :func:`export_glb`).
    Raises ValueError when two characters would get the same file name.
    """
    outdir = Path(outdir)
    slugs = [file_slug(t.name) for t in tracks]
    if len({s.lower() for s in slugs}) != len(slugs):
        raise ValueError(
            f"character names {[t.name for t in tracks]} collide as file names {slugs}"
        )
    outdir.mkdir(parents=True, exist_ok=True)
    smplx: dict[str, Path] = {}
    bvh: dict[str, Path] = {}
    raw: dict[str, Path] = {}
    for track, slug in zip(tracks, slugs, strict=True):
        smplx[track.name] = export_smplx_npz(track, outdir / f"{slug}.smplx.npz")
        bvh[track.name] = export_bvh(track, outdir / f"{slug}.bvh", units=bvh_units)
        raw[track.name] = track.save(outdir / f"{slug}.track.npz")
    glb = export_glb(outdir / "scene.glb", scene, tracks, bodies)
    return RunExports(glb=glb, smplx=smplx, bvh=bvh, tracks=raw)
