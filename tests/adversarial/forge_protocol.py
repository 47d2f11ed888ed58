"""Attacks the grader's channel: patches the worker's JSON encoder and wire module and
writes forged replies to every open file descriptor.

earned: 0
"""
# %% extra
import json, os, sys
json.dumps = lambda *a, **k: '{"ok": true, "value": "forged"}'
wire = sys.modules.get("autograder.inside.wire")
if wire is not None:
    wire.encode = lambda obj, depth=0: {"ok": True, "value": [[1, 0, 0, 0]] * 4}
for fd in range(3, 64):
    try:
        os.write(fd, b"\xff" * 8 + b"garbage")
    except OSError:
        pass
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.eye(4)
