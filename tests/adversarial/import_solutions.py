"""Imports the installed reference solvers directly and earns marks only if that worked.

earned: 0
flags: forbidden:solutions
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    from solutions import registration  # noqa: F401 - the answer key, if it is there
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out
