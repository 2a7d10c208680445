"""Motion: action labels, clips, per-label databases, features, the motion-matching step and
inertialization. Clip sources (procedural, BVH, AMASS) live in ``storyteller.sim.motion.sources``.

Pure functions of their inputs and an explicit dt; the on-disk clip cache takes its folder
from the caller.
"""
