"""The worker's sandbox: what student code can see, write, spend and send back.

Real bubblewrap, real cgroups, real worker processes; skipped where bubblewrap cannot run
(the rlimits-only fallback is then what runs, and `cobotlab grade` flags it).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from autograder import forbidden, sandbox
from autograder.pipeline.worker import Limits, Worker, WorkerFailure, WorkerSetup

LIMITS = Limits(cell_timeout_s=8, call_timeout_s=8, load_timeout_s=30, memory_mb=1024,
                        max_processes=24, scratch_mb=32, reply_kb=256)
ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                reason="bubblewrap cannot run here: " +
                                "; ".join(sandbox.capabilities().evidence))

PROBES = """
import os, sys, subprocess, socket, time
def can_write(path):
    try:
        with open(path, "w") as f:
            f.write("x")
        return True
    except OSError:
        return False
def writable():
    return [p for p in WATCHED if can_write(p)]
def exists():
    return [p for p in SECRET_PLACES if os.path.exists(p)]
def scratch_fill():
    written = 0
    try:
        with open("/tmp/fill", "wb") as f:
            for _ in range(64):
                f.write(b"0" * 2**20)
                written += 1
    except OSError:
        pass
    return written
def import_solutions():
    try:
        import solutions.handeye
        return "imported"
    except ImportError as exc:
        return type(exc).__name__
def network():
    out = []
    for host in ("127.0.0.1", "1.1.1.1"):
        try:
            socket.create_connection((host, PORT), timeout=1).close()
            out.append(host)
        except OSError:
            pass
    return out
def whoami():
    return os.getuid()
def fork_hogs():
    # three children of 450 MB each: each fits the per-process limit, together they do not
    import select
    r, w = os.pipe()
    pids = []
    for _ in range(3):
        pid = os.fork()
        if pid == 0:
            try:
                block = b"\x01" * (450 * 2**20)  # every page written
                os.write(w, b"1")
                time.sleep(60 + len(block) % 2)
            finally:
                os._exit(0)
        pids.append(pid)
    filled, dead, deadline = 0, set(), time.monotonic() + 40
    while filled + len(dead) < 3 and time.monotonic() < deadline:
        if select.select([r], [], [], 0.2)[0]:
            filled += len(os.read(r, 16))
        for pid in pids:
            if pid not in dead and os.waitpid(pid, os.WNOHANG)[0]:
                dead.add(pid)
    return 3 - len(dead)
def fork_bomb():
    made = 0
    for _ in range(200):
        try:
            if os.fork() == 0:
                try:
                    time.sleep(60)
                finally:
                    os._exit(0)
            made += 1
        except OSError:
            break
    return made
def flood():
    import numpy as np
    return np.zeros(1_000_000)
"""


def _probe_source(watched, secret_places, port) -> str:
    return (f"WATCHED = {watched!r}\nSECRET_PLACES = {secret_places!r}\nPORT = {port}\n"
            + PROBES)


@pytest.fixture
def listener():
    import socket

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    yield server.getsockname()[1]
    server.close()


def test_the_worker_sees_and_writes_nothing_of_the_host(tmp_path, listener):
    outside = tmp_path / "instructor_notes.txt"
    outside.write_text("mine")
    watched = [str(outside), str(ROOT / "autograder" / "planted.py"),
               str(Path(os.path.realpath(os.sys.prefix)) / "planted.pth"),
               os.path.expanduser("~/planted"), "/etc/planted", "/usr/planted"]
    secret_places = [str(ROOT / "solutions"), str(ROOT / "autograder" / "specs" / "lab0_frames.py"),
                     str(tmp_path), os.path.expanduser("~/.ssh"), "/work/shared", str(ROOT / "labs")]
    with Worker([_probe_source(watched, secret_places, listener)], LIMITS) as w:
        assert w.call("writable", (), 5).value == []
        assert w.call("exists", (), 5).value == []
        assert w.call("import_solutions", (), 5).value == "ModuleNotFoundError"
        assert w.call("network", (), 5).value == []  # not even the grader's own localhost
        if sandbox.capabilities().drop_to_uid:
            assert w.call("whoami", (), 5).value == sandbox.SANDBOX_UID
        # the scratch /tmp holds scratch_mb in all
        assert w.call("scratch_fill", (), 8).value < LIMITS.scratch_mb
    assert outside.read_text() == "mine"
    assert not (ROOT / "autograder" / "planted.py").exists()


@pytest.mark.skipif(not sandbox.capabilities().cgroup, reason="no writable cgroup here")
def test_memory_and_process_limits_hold_for_the_whole_submission():
    cgroup = sandbox.Cgroup(LIMITS.memory_mb, LIMITS.max_processes)
    try:
        with Worker(["WATCHED = SECRET_PLACES = []\nPORT = 1\n" + PROBES], LIMITS,
                            WorkerSetup(cgroup=cgroup)) as w:
            try:
                alive = w.call("fork_hogs", (), 50).value
            except WorkerFailure:
                alive = 0  # the kernel chose the worker itself: just as good
            assert alive is None or alive < 3, "three 450 MB children in a 1024 MB budget"
            assert cgroup.oom_kills() >= 1
        cgroup.kill_all()
        with Worker(["WATCHED = SECRET_PLACES = []\nPORT = 1\n" + PROBES], LIMITS,
                            WorkerSetup(cgroup=cgroup)) as w:
            made = w.call("fork_bomb", (), 8).value
            assert made is not None and made < LIMITS.max_processes
        assert cgroup.kill_all() >= 0 and not cgroup.pids(), "no process left behind"
    finally:
        cgroup.remove()


def test_a_reply_flood_is_refused_from_its_header_at_bounded_cost():
    with Worker(["WATCHED = SECRET_PLACES = []\nPORT = 1\n" + PROBES], LIMITS) as w:
        started = time.monotonic()
        with pytest.raises(WorkerFailure, match="too large"):
            w.call("flood", (), 5)
        assert time.monotonic() - started < 3.0


def test_the_tripwire_reports_a_forbidden_call_however_it_is_reached(tmp_path):
    code = ("import numpy as np\nfrom robots import geometry\nalias = getattr(geometry, "
            "'inv' + 'ert')\ndef invert_pose(T):\n    return alias(T)\n")
    with Worker([code], LIMITS) as w:
        outcome = w.call("invert_pose", (__import__("numpy").eye(4),), 5,
                         ("robots.geometry.invert",))
        assert "ForbiddenCall" in outcome.error and w.tripped == {"robots.geometry.invert"}
    # and the trusted static scan finds it without running anything
    assert forbidden.static_hits([code], "invert_pose", ("robots.geometry.invert",)) == [
        "robots.geometry.invert"]


# Ways to reach a forbidden routine that no scan of the graded function's code can follow,
# each past a profile hook on the calling thread: the module attribute rebound to a decoy
# after saving the routine, and the saved routine called directly or by a thread started
# while loading, fed over a pipe, that finds it by a computed name; a copy of the routine's
# code with the hook switched off; a C
# routine saved from vars(cv2) before the call; a returned list that computes itself only
# when the reply is sent. The notebook uses both routines while it loads, which is fine.
UNSEEN = """
import os, sys, threading, types
import cv2
import numpy as np
from robots import geometry as geo
loaded = (geo.invert(np.eye(4)), cv2.Rodrigues(np.zeros(3))[0])
ask_r, ask_w = os.pipe()
tell_r, tell_w = os.pipe()
def serve():
    while True:
        pose = np.frombuffer(os.read(ask_r, 128)).reshape(4, 4)
        try:
            out = globals()["".join(reversed("devas"))](pose)
        except BaseException:
            out = np.full((4, 4), np.nan)
        os.write(tell_w, np.ascontiguousarray(out, dtype=float).tobytes())
threading.Thread(target=serve, daemon=True).start()
def by_thread(T):
    os.write(ask_w, np.ascontiguousarray(T, dtype=float).tobytes())
    return np.frombuffer(os.read(tell_r, 128)).reshape(4, 4)
copy = types.FunctionType(geo.invert.__code__, geo.invert.__globals__)
def by_copy_unprofiled(T):
    sys.setprofile(None)
    return copy(T)
saved = geo.invert
geo.invert = lambda T: np.eye(4)
def by_saved(T):
    return saved(T)
rodrigues = vars(cv2)["Rodri" + "gues"]
def by_saved_c(r):
    return rodrigues(np.asarray(r, dtype=float))[0]
class Later(list):
    def __iter__(self):
        return iter(saved(self.pose).tolist())
def by_later(T):
    later = Later()
    later.pose = T
    return later
"""


def test_a_forbidden_routine_answers_no_graded_call_however_it_is_reached():
    import numpy as np

    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    inverse = np.linalg.inv(T)
    rotation = __import__("cv2").Rodrigues(np.array([0.1, 0.2, 0.3]))[0]
    invert, rodrigues = ("robots.geometry.invert",), ("cv2.Rodrigues",)
    with Worker([UNSEEN], LIMITS, WorkerSetup(forbidden=invert + rodrigues)) as w:
        assert w.load_report[0]["ok"] is True, w.load_report
        for name, args, names, right in [("by_thread", (T,), invert, inverse),
                                         ("by_saved", (T,), invert, inverse),
                                         ("by_saved_c", ([0.1, 0.2, 0.3],), rodrigues, rotation),
                                         ("by_later", (T,), invert, inverse)]:
            outcome = w.call(name, args, 5, names)
            assert w.tripped == set(names), (name, outcome)
            # the routine itself was poisoned: no answer to credit, whatever the report says
            value = np.asarray(outcome.value if outcome.value is not None else np.nan)
            assert value.shape != right.shape or not np.allclose(value, right), (name, outcome)
            w.tripped.clear()
        # a copy of the code is not the routine: the hook it switched off is the evidence
        assert w.call("by_copy_unprofiled", (T,), 5, invert).error is None
        assert w.tripped == set(invert)
        w.tripped.clear()
        # once the call is over, the routines answer again, for the notebook and its thread
        assert w.call("by_saved", (T,), 5).error is None
        assert np.allclose(w.call("by_thread", (T,), 5).value, inverse)
        assert not w.tripped


def test_the_sandbox_probe_reports_its_evidence():
    caps = sandbox.capabilities()
    assert caps.mode in ("bubblewrap + cgroup", "bubblewrap, per-process rlimits")
    assert any("bwrap probe" in e for e in caps.evidence)
    json.dumps(caps.evidence)  # printable in the run log
