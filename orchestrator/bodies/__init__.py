"""Body meshes from licensed body-model files, computed at the edge (``smplx`` + ``torch``, CPU).

What lives here: :mod:`.smplx_meshes` turns a character's exported SMPL-X parameters
(``<name>.smplx.npz``, see :mod:`storyteller.sim.export.smplx_npz`) and the user's SMPL-X model folder
into a skinned body (rest mesh, faces, skin weights on our 22 joints, as plain numpy arrays for
:class:`storyteller.sim.export.glb.SkinnedBody`) and per-frame world bone transforms (for the viewer).

May import ``sim``, ``numpy``; ``smplx`` and ``torch`` only inside functions, so importing
this package (or a CLI that names it) never loads them.

Guarantees: outputs are numpy arrays (no tensors leak out); the skinned mesh posed with the
per-frame bone transforms is the model's own output for the exported parameters, up to the
model's pose-corrective blend shapes (``posedirs``), which linear skinning cannot carry.
"""
