"""An outside attacker's corpus against every file the CLI reads back (issue 22), run by
``python -m benchmark.hostile_inputs`` (:mod:`benchmark.hostile.runner`).

:mod:`~benchmark.hostile.harness` holds an attack's folder and command and the hostile data,
:mod:`~benchmark.hostile.judging` runs a command and judges it, :mod:`~benchmark.hostile.bases`
builds what the attacks start from; the attacks are grouped by target in
:mod:`~benchmark.hostile.run_folders`, :mod:`~benchmark.hostile.outputs`,
:mod:`~benchmark.hostile.scenes`, :mod:`~benchmark.hostile.inputs`,
:mod:`~benchmark.hostile.sweeps`, :mod:`~benchmark.hostile.models` and
:mod:`~benchmark.hostile.viewer`.
"""
