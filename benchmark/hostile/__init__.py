"""An outside attacker's corpus against every file the CLI reads back (issue 22), run by
``python -m benchmark.hostile_inputs`` (:mod:`benchmark.hostile.runner`).

:mod:`~benchmark.hostile.harness` holds an attack's folder and command and the hostile data,
:mod:`~benchmark.hostile.judging` runs a command and judges it, :mod:`~benchmark.hostile.bases`
builds what the attacks start from; the attacks are grouped by target in
:mod:`~benchmark.hostile.run_folders`, :mod:`~benchmark.hostile.outputs`,
:mod:`~benchmark.hostile.scenes`, :mod:`~benchmark.hostile.inputs`,
:mod:`~benchmark.hostile.sweeps`, :mod:`~benchmark.hostile.models` and
:mod:`~benchmark.hostile.viewer`; a second corpus, written from outside the first, in
:mod:`~benchmark.hostile.folder_files` (how run folder files are opened and written: sparse,
special and linked files, floods, races), :mod:`~benchmark.hostile.record_values` (values inside
files that parse) and :mod:`~benchmark.hostile.costs` (small valid files that ask for work).
"""
