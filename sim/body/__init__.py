"""The body: the 22-joint SMPL-X skeleton and its forward kinematics, analytic leg IK, the
foot filter that pins planted feet and keeps them out of furniture, and the filter that keeps
the legs of different characters apart (``leg_separation``).
"""
