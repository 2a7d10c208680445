"""An SMPL-X model folder (``--smplx-model``) is read as untrusted input (issue 22).

Found by ``benchmark/hostile_inputs.py``: ``smplx`` loads a model with ``np.load(...,
allow_pickle=True)`` (``.pkl``: ``pickle.load``), so ``view --export --smplx-model DIR`` with a
crafted ``SMPLX_NEUTRAL.npz`` ran code, and a zip bomb there took 1.3 GB before it was killed.
Now the model's numeric arrays are read by the bounded reader and handed to ``smplx`` in a
private copy; arrays of Python objects are left out (the real files' ``joint2num`` /
``part2num``), a ``.pkl`` model is refused.
"""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest

from storyteller.orchestrator.bodies.smplx_meshes import SmplxModelError, SmplxModels
from tests.support.smplx_standin import standin_model_arrays


class _Canary:
    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple[object, ...]:
        return (os.mkdir, (str(self.path),))


def _model(folder: Path, arrays: dict[str, object]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "SMPLX_NEUTRAL.npz"
    with zipfile.ZipFile(path, "w") as zf:  # np.savez's layout; object arrays pickled, as a crafted file holds them
        for name, array in arrays.items():
            with zf.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, np.asarray(array), allow_pickle=True)
    return path


def test_object_arrays_are_never_unpickled_and_the_numeric_model_loads(tmp_path: Path) -> None:
    canary = tmp_path / "CANARY"
    arrays: dict[str, object] = dict(standin_model_arrays())
    arrays["joint2num"] = np.array([_Canary(canary)], dtype=object)  # where the real files keep a dict
    _model(tmp_path / "ok", arrays)
    model = SmplxModels(tmp_path / "ok").model("neutral", 10)
    assert model.v_template.shape[1] == 3 and not canary.exists()

    arrays["v_template"] = np.array([_Canary(canary)], dtype=object)  # a needed array that is a pickle
    _model(tmp_path / "bad", arrays)
    with pytest.raises(SmplxModelError, match="not a usable SMPL-X model file"):
        SmplxModels(tmp_path / "bad").model("neutral", 10)
    assert not canary.exists()


def test_a_pickle_model_and_a_zip_bomb_are_refused(tmp_path: Path) -> None:
    (tmp_path / "pkl").mkdir()
    (tmp_path / "pkl" / "SMPLX_NEUTRAL.pkl").write_bytes(pickle.dumps({"v_template": 1}))
    with pytest.raises(SmplxModelError, match=r"\.pkl model is a pickle"):
        SmplxModels(tmp_path / "pkl").model("neutral", 10)
    buf = io.BytesIO()  # one array whose header claims 4 GiB: refused from the sizes, nothing inflated
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf, zf.open("v_template.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (1 << 29,)})
        f.write(bytes(1 << 20))
    (tmp_path / "bomb").mkdir()
    (tmp_path / "bomb" / "SMPLX_NEUTRAL.npz").write_bytes(buf.getvalue())
    with pytest.raises(SmplxModelError, match="claims more bytes"):
        SmplxModels(tmp_path / "bomb").model("neutral", 10)
