"""Exhausts memory at top level and inside a graded function (address space, not RAM).

earned: 7
min: 7
"""
# %% extra
hog = bytearray(10**13)
# %% replace invert_pose
def invert_pose(a_T_b):
    blocks = []
    while True:
        blocks.append(np.empty(10**8))
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
