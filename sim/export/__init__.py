"""Exports of a run: SMPL-X npz, BVH, one skinned animated GLB, top-down pictures and video.
"""
