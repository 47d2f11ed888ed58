"""Correct answers in a mangled notebook: test cells deleted, solution cells duplicated and
retyped, grade ids changed, nbgrader metadata stripped. Graded by name: full marks.

earned: 10
min: 10
"""
# %% mangle
# %% replace invert_pose
def invert_pose(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out
# %% replace compose_chain
def compose_chain(poses):
    out = np.eye(4)
    for T in poses:
        out = out @ T
    return out
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 0:
        kx, ky, kz = rvec / theta
        K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
        T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
    T[:3, 3] = t
    return T
