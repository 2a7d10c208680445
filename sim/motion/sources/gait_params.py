"""The walk's shape as numbers: step length against speed, pelvis bob and sway, arm swing,
trunk twist and turn lean, read by the procedural locomotion (``procedural_locomotion``).

``FITTED_GAIT`` holds the values that ``python -m storyteller.benchmark.gait_fit --write`` fitted to real
walks: CMU Graphics Lab Motion Capture Database clips (walks 05_01, 07_03, 07_06, 08_08, 16_15,
16_31 and 131_01 / 131_02, imported on our skeleton; 16_11 is held out to check the fit). Only these few numbers ship, no
frame of the clips. Attribution, as the CMU terms ask: "The data used in this project was
obtained from mocap.cs.cmu.edu. The database was created with funding from NSF EIA-0196217."
Nothing here is fitted on a non-commercial data set.

Each amplitude is a *generator* parameter (what the generator is told), calibrated so that the
generated clips *measure* like the real ones with the benchmark's measures
(``storyteller.benchmark.motion_metrics.gait``); the fitting script prints both. Lengths are metres,
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
    bob_dip_1ms: float
    """Further lowering of the pelvis at each double support, m, at 1 m/s (a narrow dip after
    each landing; the legs bend for it, so it never asks them to reach further)."""
    bob_dip_speed_slope: float
    """Dip added per m/s, m per m/s (the dip is held at or above 0)."""
    sway_amplitude: float
    """Sideways pelvis shift over the stance foot, m (either way of the path)."""
    arm_swing_1ms: float
    """Wrist's fore-aft swing either way of its rest, m, at 1 m/s."""
    arm_swing_speed_slope: float
    """Arm swing added per m/s, m per m/s."""
    trunk_twist: float
    """Yaw of the chest against the pelvis, either way, rad (the shoulders counter the hips),
    at 1 m/s."""
    trunk_twist_speed_slope: float
    """Trunk twist added per m/s, rad per m/s."""
    pelvis_yaw: float
    """Yaw of the pelvis with the swinging leg, either way, rad."""
    turn_lean_gain: float
    """Trunk roll into a turn as a multiple of ``atan(lateral acceleration / g)``."""
    foot_clearance: float
    """Highest lift of the ball of a swinging foot above its planted height, m."""


# BEGIN FITTED (written by `python -m storyteller.benchmark.gait_fit --write`; edit there, not here)
FITTED_GAIT = GaitParams(
    step_length_1ms=0.5939,
    step_length_exponent=0.479,
    step_length_min=0.3,
    bob_follow=0.7927,
    bob_dip_1ms=0.0022,
    bob_dip_speed_slope=0.0075,
    sway_amplitude=0.039,
    arm_swing_1ms=0.1519,
    arm_swing_speed_slope=0.281,
    trunk_twist=0.1475,
    trunk_twist_speed_slope=0.3357,
    pelvis_yaw=0.0942,
    turn_lean_gain=0.9429,
    foot_clearance=0.1246,
)
# END FITTED

__all__ = ["FITTED_GAIT", "GaitParams"]
