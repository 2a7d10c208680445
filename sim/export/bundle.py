"""Write every export of a run into one folder.

Per character ``<slug>`` (its name with anything but letters, digits, ``-`` and ``_`` turned
into ``_``): ``<slug>.smplx.npz`` (AMASS-style SMPL-X parameters), ``<slug>.bvh`` and
``<slug>.track.npz`` (the raw track, reloadable with ``CharacterTrack.load``); plus one
``scene.glb`` with the scene and every character.

Each file is written to a fresh temporary name and renamed over its own
(``storyteller.sim.no_follow_writes``), so a symbolic link planted at one of these names is replaced, never
written through. The names are ``storyteller.sim.run_folder_names``.

The files are written by :data:`WRITER_THREADS` threads: each file's bytes depend only on its
track (and the scene), never on the order, and the npz files spend most of their time in zlib,
which runs without the interpreter lock, so the text and GLB writers go on meanwhile. The first
error raised by a writer is raised once every writer has finished.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from storyteller.sim.export.bvh import Units, export_bvh
from storyteller.sim.export.glb import SkinnedBody, export_glb
from storyteller.sim.export.joint_rotations import JointRotations
from storyteller.sim.export.smplx_npz import export_smplx_npz
from storyteller.sim.run_folder_names import BVH_SUFFIX, SCENE_GLB, SMPLX_SUFFIX, TRACK_SUFFIX, file_slug
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.character_track import CharacterTrack

WRITER_THREADS = 2
"""Threads that write a run's files (the machines this runs on have two cores)."""


@dataclass(frozen=True)
class RunExports:
    """Paths written by :func:`export_run`."""

    glb: Path
    smplx: dict[str, Path]
    bvh: dict[str, Path]
    tracks: dict[str, Path]

    def all_paths(self) -> list[Path]:
        return [self.glb, *self.smplx.values(), *self.bvh.values(), *self.tracks.values()]


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
    rotations = {t.name: JointRotations.of(t) for t in tracks}  # once for the npz, BVH and GLB
    with ThreadPoolExecutor(max_workers=WRITER_THREADS, thread_name_prefix="export") as pool:

        def each(write: Callable[[CharacterTrack, Path], Path], suffix: str) -> dict[str, Future[Path]]:
            return {t.name: pool.submit(write, t, outdir / f"{slug}{suffix}") for t, slug in zip(tracks, slugs, strict=True)}

        # the npz writers first: their zlib work overlaps the others' Python work
        raw = each(lambda t, path: t.save(path), TRACK_SUFFIX)
        smplx = each(lambda t, path: export_smplx_npz(t, path, rotations=rotations[t.name]), SMPLX_SUFFIX)
        bvh = each(lambda t, path: export_bvh(t, path, units=bvh_units, rotations=rotations[t.name]), BVH_SUFFIX)
        glb = pool.submit(export_glb, outdir / SCENE_GLB, scene, tracks, bodies, rotations)
    written = [glb, *raw.values(), *smplx.values(), *bvh.values()]
    for failed in (f.exception() for f in written):
        if failed is not None:
            raise failed

    def paths(futures: dict[str, Future[Path]]) -> dict[str, Path]:
        return {name: f.result() for name, f in futures.items()}

    return RunExports(glb=glb.result(), smplx=paths(smplx), bvh=paths(bvh), tracks=paths(raw))
