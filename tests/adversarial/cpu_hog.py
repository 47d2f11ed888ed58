"""Starves the submissions graded beside it: twenty busy processes, each in a session of its
own (the kernel's autogroups share the CPU between sessions), each spinning for at most a
minute, then waits in its own cell and in a function past their wall clocks. Its cgroup has
the CPU weight of one busy process whatever it runs; what it started dies with its sandbox.
tests/test_grading_contention.py grades it beside a correct notebook on one core.

earned: 0
layer: host
"""
# %% extra
import os, time
def _crowd(n, seconds):
    for _ in range(n):
        try:
            if os.fork() == 0:
                try:
                    os.setsid()
                    stop = time.monotonic() + seconds
                    while time.monotonic() < stop:
                        pass
                finally:
                    os._exit(0)
        except OSError:
            break
_crowd(20, 60)
time.sleep(600)
# %% replace invert_pose
def invert_pose(a_T_b):
    time.sleep(600)
