"""Raises everything: SystemExit, KeyboardInterrupt, a BaseException, and kills its process.

earned: 0
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    raise SystemExit(0)
# %% replace compose_chain
def compose_chain(poses):
    raise KeyboardInterrupt
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    import os
    os._exit(3)
