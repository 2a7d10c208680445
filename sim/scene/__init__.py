"""Scenes: the typed model (oriented boxes on a z-up floor), loaders for reference folders,
our own JSON and instance-segmented meshes, and the bundled scenes.

Imports only ``sim`` siblings and numpy/trimesh; no clock, no network, no environment reads.
"""
