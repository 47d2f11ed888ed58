"""Three forked children of 1.35 GB each (under a per-process limit of 2 GB), and a fork
bomb: both at top level and inside a graded function; daemons meant to outlive the grader.

earned: 0
layer: host
"""
# %% extra
import os, time
def _spawn(n, size):
    for _ in range(n):
        try:
            if os.fork() == 0:
                try:
                    os.setsid()
                    block = b"\x01" * size
                    time.sleep(120 + len(block) % 2)
                finally:
                    os._exit(0)
        except OSError:
            break
_spawn(3, int(1.35 * 2**30))
# %% replace invert_pose
def invert_pose(a_T_b):
    _spawn(500, 1)
    time.sleep(1)
    return np.eye(4)
