"""Loops forever at top level, in a function, and in a function that blocks the alarm.

earned: 3
min: 3
flags: suspicious_signal_handling
"""
# %% extra
while True:
    pass
# %% replace invert_pose
def invert_pose(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out
# %% replace compose_chain
def compose_chain(poses):
    while True:
        pass
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    import signal
    signal.signal(signal.SIGALRM, signal.SIG_IGN)
    while True:
        try:
            pass
        except BaseException:
            pass
