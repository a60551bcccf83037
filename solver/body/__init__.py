"""Bodies and their poses: the body model, its rig, skinning, retargeting captured skeletons
onto the rig, where poses come from, and relaxing a pose onto a surface (inverse kinematics).

Depends on `solver.mesh` (and capture, posedb); never on `solver.scene`, `solver.io` or the CLI.
"""
