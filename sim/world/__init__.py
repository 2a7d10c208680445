"""The world step: characters, story events and their phases, cooperative walking and motion,
one frame at a time, and the per-frame tracks the exporters read.

Deterministic: the same commands at the same frames give the same tracks.
"""
