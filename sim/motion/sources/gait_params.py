"""The walk's shape as numbers: step length against speed, pelvis bob and sway, arm swing,
trunk twist and turn lean, read by the procedural locomotion (``procedural_locomotion``).

``FITTED_GAIT`` holds the values that ``python -m benchmark.gait_fit --write`` fitted to real
walks: CMU Graphics Lab Motion Capture Database clips (walks 05_01, 07_03, 07_06, 08_08, 16_15,
16_31, 16_11 and 131_01 / 131_02, imported on our skeleton). Only these few numbers ship, no
frame of the clips. Attribution, as the CMU terms ask: "The data used in this project was
obtained from mocap.cs.cmu.edu. The database was created with funding from NSF EIA-0196217."
Nothing here is fitted on a non-commercial data set.

Each amplitude is a *generator* parameter (what the generator is told), calibrated so that the
generated clips *measure* like the real ones with the benchmark's measures
(``benchmark.motion_metrics.gait``); the fitting script prints both. Lengths are metres,
angles radians, speeds m/s.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class GaitParams:
    """Parameters of the procedural walk (see the module docstring)."""

    step_length_1ms: float
    """Step length (one foot's landing to the other's) at 1 m/s, m."""
    step_length_exponent: float
    """Step length grows as ``speed ** step_length_exponent`` (so cadence as its complement)."""
    step_length_min: float
    """Shortest step of a slow walk, m (the power law is held above it)."""
    bob_follow: float
    """Share (0-1) of the legs' own rise and fall the pelvis follows: 0 keeps it level at the
    lowest height of each step, 1 as high as the legs reach at every frame (bob)."""
    sway_amplitude: float
    """Sideways pelvis shift over the stance foot, m (either way of the path)."""
    arm_swing_1ms: float
    """Wrist's fore-aft swing either way of its rest, m, at 1 m/s."""
    arm_swing_speed_slope: float
    """Arm swing added per m/s, m per m/s."""
    trunk_twist: float
    """Yaw of the chest against the pelvis, either way, rad (the shoulders counter the hips)."""
    pelvis_yaw: float
    """Yaw of the pelvis with the swinging leg, either way, rad."""
    turn_lean_gain: float
    """Trunk roll into a turn as a multiple of ``atan(lateral acceleration / g)``."""
    foot_clearance: float
    """Highest lift of the ball of a swinging foot above its planted height, m."""


# BEGIN FITTED (written by `python -m benchmark.gait_fit --write`; edit there, not here)
FITTED_GAIT = GaitParams(
    step_length_1ms=0.586,
    step_length_exponent=0.6121,
    step_length_min=0.3,
    bob_follow=0.7927,
    sway_amplitude=0.0382,
    arm_swing_1ms=0.1395,
    arm_swing_speed_slope=0.2991,
    trunk_twist=0.1564,
    pelvis_yaw=0.088,
    turn_lean_gain=0.9502,
    foot_clearance=0.1207,
)
# END FITTED

__all__ = ["FITTED_GAIT", "GaitParams"]
