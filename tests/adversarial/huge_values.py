"""Values that raised in the trusted process (issue 37, item 4): a 400-digit integer as the
answer, an object array of them, and a forged reply on every open file descriptor whose
CPU seconds are a 400-digit integer. Each costs the student that function, never the
grade of the whole submission (no grader_error, no NOT GRADED row).

earned: 0
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return 10**400
# %% replace compose_chain
def compose_chain(poses):
    return np.array([[10**400] * 4] * 4, dtype=object)
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    import json, os, struct
    body = json.dumps({"ok": True, "value": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                             [0, 0, 0, 1]],
                       "seconds": 0.1, "cpu_seconds": 10**400}).encode()
    for fd in range(3, 64):
        try:
            os.write(fd, struct.pack("<Q", len(body)) + body)
        except OSError:
            pass
    return np.eye(4)
