"""Attacks on the model and prompt folders a command names: ``--smplx-model``, ``--motion-config``,
``plan --prompts`` and ``plan --runs-db`` / ``--replay``.
"""

from __future__ import annotations

import gzip
import io
import pickle
import struct
import zipfile

from storyteller.benchmark.hostile.harness import (
    Attack,
    Box,
    Reduce,
    Spec,
    export,
    registrar,
    sparse_file,
    zip_bomb_npz,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("smplx", "--smplx-model folder whose .npz holds a pickled object array")
def _smplx_pickle(box: Box) -> Spec:
    box.copy_run()
    folder = box.root / "smplx"
    folder.mkdir()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z, z.open("v_template.npy", "w") as f:
        text = b"{'descr': '|O', 'fortran_order': False, 'shape': (1,), }"
        text += b" " * (63 - (len(text) + 10) % 64) + b"\n"
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text)
        f.write(pickle.dumps([Reduce(f"touch {box.canary}")], protocol=2))
    for gender in ("NEUTRAL", "MALE", "FEMALE"):
        (folder / f"SMPLX_{gender}.npz").write_bytes(buf.getvalue())
    spec = export(box)
    spec.argv += ["--smplx-model", str(folder)]
    return spec


@attack("smplx", "--smplx-model folder whose .npz is a zip bomb")
def _smplx_bomb(box: Box) -> Spec:
    box.copy_run()
    folder = box.root / "smplx"
    folder.mkdir()
    for gender in ("NEUTRAL", "MALE", "FEMALE"):
        (folder / f"SMPLX_{gender}.npz").write_bytes(zip_bomb_npz("v_template", 3))
    spec = export(box)
    spec.argv += ["--smplx-model", str(folder)]
    return spec


@attack("motion config", "--motion-config naming /dev/zero and a FIFO as clips")
def _motion_config(box: Box) -> Spec:
    fifo = box.fifo(box.root / "clip.bvh")
    text = (f'root = "{box.root}"\nreplace_procedural = true\n[[clips]]\nfile = "/dev/zero"\nlabel = "walk"\n'
            f'[[clips]]\nfile = "{fifo.name}"\nlabel = "sit"\n')
    out = box.root / "o"
    return Spec(["run", "home", "--motion-config", str(box.file("motion.toml", text)), "--out", str(out), "-d", "2",
                 "--no-interactive", "--no-live"], "run", "bad", writable=(out,))


@attack("prompts", "plan --prompts folder of FIFOs and a 50 MB prompt")
def _prompts(box: Box) -> Spec:
    folder = box.root / "prompts" / "narrator"
    folder.mkdir(parents=True)
    box.fifo(folder / "system.md")
    (folder / "request.md").write_text("{{ x }}" * 5_000_000, encoding="utf-8")
    return Spec(["plan", "home", "--prompts", str(box.root / "prompts"), "--runs-db", ":memory:"], "plan", "bad")


@attack("plan", "plan --runs-db a FIFO, --replay a gzip trace")
def _plan_db(box: Box) -> Spec:
    trace = box.file("t.jsonl", gzip.compress(b'{"kind": "run"}\n'))
    return Spec(["plan", "home", "--runs-db", str(box.fifo(box.root / "db.sqlite")), "--replay", str(trace)],
                "plan", "bad")


def _clip_run(box: Box, clip: str) -> Spec:
    config = box.file("motion.toml", f'root = "{box.root}"\n[[clips]]\nfile = "{clip}"\nlabel = "walk"\n')
    out = box.root / "o"
    return Spec(["run", "home", "--motion-config", str(config), "--out", str(out), "-d", "2", "--no-interactive",
                 "--no-live"], "run", "bad", writable=(out,))


@attack("motion config", "--motion-config clip: a sparse 3 GB .bvh")
def _clip_sparse(box: Box) -> Spec:
    sparse_file(box.root / "big.bvh", 3 << 30)
    return _clip_run(box, "big.bvh")


@attack("motion config", "--motion-config clip: an AMASS .npz zip bomb (3 GB)")
def _clip_bomb(box: Box) -> Spec:
    box.file("bomb.npz", zip_bomb_npz("poses", 3))
    return _clip_run(box, "bomb.npz")
