"""Reads an instructor environment variable and a service on 127.0.0.1, and earns marks only
if it got them (the test runs such a service and sets such a variable).

earned: 0
layer: course
"""
# %% extra
import os, socket
leaked = os.environ.get("COBOTLAB_TEST_INSTRUCTOR_TOKEN", "")
try:
    with socket.create_connection(("127.0.0.1", 47613), timeout=1) as s:
        leaked += s.recv(64).decode()
except OSError:
    pass
# %% replace invert_pose
def invert_pose(a_T_b):
    if not leaked:
        raise RuntimeError("nothing leaked")
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out
