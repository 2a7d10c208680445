"""The body: the 22-joint SMPL-X skeleton and its forward kinematics, analytic leg IK and the
foot filter that pins planted feet and keeps them out of furniture.
"""
