"""Temporary folders of a grading process killed before its clean-up are removed later.

A Dask worker or a grader killed by SIGKILL (the OOM killer, a preempted node) never runs
its ``finally``: its worker folders and its task's copy of a student's notebook stay in the
temporary folder. Each is named for its process (sandbox.private_folder), and the next
grading run or cluster task on the machine removes those whose process is gone;
tests/test_cluster.py checks it on a worker it kills.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

from autograder import sandbox


def _dead_pid() -> int:
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    return done.pid


def test_only_folders_of_a_gone_process_are_removed(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = _dead_pid()
    zombie = subprocess.Popen([sys.executable, "-c", "pass"])   # exited, not reaped
    try:
        os.waitid(os.P_PID, zombie.pid, os.WEXITED | os.WNOWAIT)
        left = [tmp_path / f"cobotlab-worker-{dead}-a1", tmp_path / f"cobotlab-cluster-{dead}-b2",
                tmp_path / f"cobotlab-worker-{zombie.pid}-c3"]
        kept = [sandbox.private_folder("cobotlab-worker-"),       # this process: alive
                sandbox.private_folder("cobotlab-cluster-"),
                tmp_path / "cobotlab-worker-x1b2c3d4",             # no pid: cannot tell
                tmp_path / f"cobotlab-template-{dead}-d4",         # not one of ours
                tmp_path / f"cobotlab-worker-{dead}-file"]         # not a folder
        for folder in left:
            folder.mkdir()
            (folder / "lab0_frames.ipynb").write_text("{}")
        kept[2].mkdir()
        kept[3].mkdir()
        kept[4].write_text("")
        link = tmp_path / f"cobotlab-cluster-{dead}-link"
        link.symlink_to(kept[2])                                   # never followed
        assert all(k.parent == tmp_path and f"-{os.getpid()}-" in k.name for k in kept[:2])

        assert sandbox.remove_stale_folders() == 3
        assert not any(folder.exists() for folder in left)
        assert all(k.exists() for k in kept) and link.is_symlink()
        assert sandbox.remove_stale_folders() == 0
    finally:
        zombie.wait()
