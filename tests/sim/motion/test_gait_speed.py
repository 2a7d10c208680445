"""The procedural walk against the real CMU walks, as a function of speed (issue 25).

The real figures are the least-squares lines against speed over the fitting walks
(``storyteller.benchmark.gait_fit``: the CMU walks less ``HELD_OUT``), measured as the benchmark measures;
the held-out walk checks that the fit carries over. Skipped without the shared mocap folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from storyteller.benchmark.gait_fit import Walks
from tests.support.reference import requires_mocap

pytestmark = requires_mocap


@pytest.fixture(scope="module")
def walks() -> tuple[Walks, Walks]:
    from storyteller.benchmark.gait_fit import HELD_OUT, measure_walks, real_walks

    motions, names = real_walks()
    held = {Path(f).stem for f in HELD_OUT}
    fit = measure_walks([j for j, n in zip(motions, names, strict=True) if n not in held])
    out = measure_walks([j for j, n in zip(motions, names, strict=True) if n in held])
    return fit, out


def _generated(speed: float) -> dict[str, float]:
    from storyteller.benchmark.gait_fit import measure_walks
    from storyteller.sim.motion.sources.procedural_locomotion import _const, locomotion_clip

    clip = locomotion_clip("test", _const(speed), _const(0.0), 6.0)
    return measure_walks([np.asarray(clip.joint_positions())]).windows[0]


@pytest.mark.parametrize("measure", ["arm_swing", "bob_oscillation", "trunk_twist"])
@pytest.mark.parametrize("speed", [0.9, 1.2])
def test_walk_swings_bobs_and_twists_like_the_real_walks_at_its_speed(walks: tuple[Walks, Walks], measure: str, speed: float) -> None:
    from storyteller.benchmark.gait_fit import speed_lines

    fit, _ = walks
    real = speed_lines(fit)[measure].value(speed)
    got = _generated(speed)[measure]
    assert 0.8 * real <= got <= 1.2 * real, f"{measure} at {speed} m/s: {got:.4f} against real {real:.4f}"


def test_walk_carries_over_to_the_held_out_walk(walks: tuple[Walks, Walks]) -> None:
    """The held-out CMU walk (another conversion, curving): step, cadence, bob and twist within 20%
    of a walk generated at its speed (its arm swing, 0.16 m, is the lowest of the CMU walkers'
    and is not checked)."""
    from storyteller.benchmark.gait_fit import held_out_rows
    from storyteller.sim.motion.sources.gait_params import FITTED_GAIT

    _, held = walks
    assert held.windows
    rows = held_out_rows(FITTED_GAIT, held)
    for m in ("cadence", "step_length", "bob_oscillation", "trunk_twist"):
        assert 0.8 <= rows[m] <= 1.2, f"{m}: {rows[m]:.2f}x"
