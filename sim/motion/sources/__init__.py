"""Where clips come from: the procedural rig and its generated actions and walks (the default,
no downloaded data), and importers for real mocap (BVH with any skeleton, AMASS-style npz).
"""
