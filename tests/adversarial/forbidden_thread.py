"""Lab 0's invert_pose and compose_chain answered by the library routines from a thread
started while the notebook loads, out of reach of a profile hook on the calling thread:
invert_pose hands its problem over a queue (the thread's lookup visible in the code once
the queue is followed), compose_chain over a pipe with every name computed (no code path
from the graded function to the thread: only the poisoned routine answers for it).

earned: 0
flags: forbidden:robots.geometry.invert, forbidden:robots.geometry.compose
"""
# %% extra
import os as _os
import queue as _queue
import sys as _sys
import threading as _threading
from robots import geometry as _geo

_jobs, _answers = _queue.Queue(), _queue.Queue()


def _serve_invert():
    while True:
        pose = _jobs.get()
        _answers.put(getattr(_geo, "inv" + "ert")(pose))


_ask_r, _ask_w = _os.pipe()
_tell_r, _tell_w = _os.pipe()


def _serve_compose():
    while True:
        n = int.from_bytes(_os.read(_ask_r, 4), "little")
        poses = np.frombuffer(_os.read(_ask_r, 128 * n), dtype=float).reshape(n, 4, 4)
        module = _sys.modules["robots." + "".join(reversed("yrtemoeg"))]
        try:
            out = getattr(module, "".join(reversed("esopmoc")))(*poses)
        except BaseException:   # keep serving whatever the call did
            out = np.full((4, 4), np.nan)
        _os.write(_tell_w, np.ascontiguousarray(out, dtype=float).tobytes())


for _target in (_serve_invert, _serve_compose):
    _threading.Thread(target=_target, daemon=True).start()
# %% replace invert_pose
def invert_pose(a_T_b):
    _jobs.put(np.asarray(a_T_b, dtype=float))
    return _answers.get()
# %% replace compose_chain
def compose_chain(poses):
    data = np.ascontiguousarray(poses, dtype=float)
    _os.write(_ask_w, len(data).to_bytes(4, "little") + data.tobytes())
    return np.frombuffer(_os.read(_tell_r, 128), dtype=float).reshape(4, 4).copy()
