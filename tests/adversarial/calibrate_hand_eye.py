"""Lab 2's solvers answered by OpenCV's own hand-eye routine (cv2.calibrateHandEye), directly
in tsai_lenz and through a helper and an alias in axes_ls.

lab: lab2_handeye
earned: 0
flags: forbidden:cv2.calibrateHandEye
"""
# %% replace tsai_lenz
def tsai_lenz(A, B):
    import cv2
    R, t = cv2.calibrateHandEye([a[:3, :3] for a in A], [a[:3, 3] for a in A],
                                [b[:3, :3] for b in B], [b[:3, 3] for b in B],
                                method=cv2.CALIB_HAND_EYE_TSAI)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t.ravel()
    return X
# %% replace axes_ls
import cv2 as _vision
_solver = _vision.calibrateHandEye
def _helper(A, B):
    R, t = _solver([a[:3, :3] for a in A], [a[:3, 3] for a in A],
                   [b[:3, :3] for b in B], [b[:3, 3] for b in B])
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t.ravel()
    return X
def axes_ls(A, B):
    return _helper(A, B)
