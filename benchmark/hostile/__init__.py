"""An outside attacker's corpus against every file the CLI reads back (issue 22), run by
``python -m storyteller.benchmark.hostile_inputs`` (:mod:`storyteller.benchmark.hostile.runner`).

:mod:`~storyteller.benchmark.hostile.harness` holds an attack's folder and command and the hostile data,
:mod:`~storyteller.benchmark.hostile.judging` runs a command and judges it, :mod:`~storyteller.benchmark.hostile.bases`
builds what the attacks start from; the attacks are grouped by target in
:mod:`~storyteller.benchmark.hostile.run_folders`, :mod:`~storyteller.benchmark.hostile.outputs`,
:mod:`~storyteller.benchmark.hostile.scenes`, :mod:`~storyteller.benchmark.hostile.meshes`,
:mod:`~storyteller.benchmark.hostile.inputs`,
:mod:`~storyteller.benchmark.hostile.sweeps`, :mod:`~storyteller.benchmark.hostile.models` and
:mod:`~storyteller.benchmark.hostile.viewer`; a second corpus, written from outside the first, in
:mod:`~storyteller.benchmark.hostile.folder_files` (how run folder files are opened and written: sparse,
special and linked files, floods, races), :mod:`~storyteller.benchmark.hostile.record_values` (values inside
files that parse) and :mod:`~storyteller.benchmark.hostile.costs` (small valid files that ask for work).
"""
