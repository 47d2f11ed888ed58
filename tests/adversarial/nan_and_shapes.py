"""Returns NaN, wrong shapes, strings and objects that only pretend to be arrays.

earned: 0
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.full((4, 4), np.nan)
# %% replace compose_chain
def compose_chain(poses):
    class Liar:
        shape = (4, 4)
        def __array__(self, *a, **k):
            return np.eye(4)
        def __eq__(self, other):
            return True
    return [Liar(), "np.eye(4)", np.eye(3)]
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    return np.eye(4)[:3]
