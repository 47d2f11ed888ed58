"""Grading from a template: what one submission does never reaches the next.

A template (autograder.template) runs the lab's leading read-only cells once and forks one
sandboxed worker per submission. Real bubblewrap, real namespaces, real cgroups; skipped
where bubblewrap cannot run (no template is built there: every worker starts cold).
"""

from __future__ import annotations

import os
import time

import course_kit as kit
import pytest
from test_grading_sandbox import LIMITS, PROBES, ROOT, _probe_source

from autograder import sandbox
from autograder.pipeline.run_submission import grade_notebook
from autograder.pipeline.worker import Limits, Worker, WorkerSetup
from autograder.template import Template, leading_cells

pytestmark = pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                reason="bubblewrap cannot run here: " +
                                "; ".join(sandbox.capabilities().evidence))

SHARED = "import os, sys, threading, time\nimport numpy as np\nSHARED_STATE = {'runs': 0}\n"

# A submission that leaves everything it can behind: numpy and a builtin patched, the
# shared cells' state changed, files in every writable place, a thread, a daemon that
# outlives it (double fork, its own session), an environment variable, another directory.
HOSTILE = """
import builtins, subprocess
np.linalg.inv = lambda a: np.zeros_like(a)
np.eye = lambda *a, **k: np.ones((3, 3))
builtins.round = lambda *a, **k: 42
SHARED_STATE["runs"] += 1
sys.modules["json"] = None
os.environ["LEFT_BEHIND"] = "1"
for place in ("/tmp/left_behind", "/dev/shm/left_behind"):
    with open(place, "w") as f:
        f.write("x")
threading.Thread(target=lambda: time.sleep(600), daemon=False).start()
if os.fork() == 0:
    os.setsid()
    if os.fork() == 0:
        time.sleep(600)
    os._exit(0)
os.chdir("/")
def observe():
    return "hostile"
"""

# What a later submission can see of all that.
OBSERVER = """
def observe():
    import json
    places = {p: sorted(os.listdir(p)) for p in ("/tmp", "/dev/shm")}
    return {"inv_ok": bool(np.allclose(np.linalg.inv(2 * np.eye(3)), 0.5 * np.eye(3))),
            "round": round(2.4), "runs": SHARED_STATE["runs"], "json": json is not None,
            "env": os.environ.get("LEFT_BEHIND"), "places": places, "cwd": os.getcwd(),
            "threads": threading.active_count(), "tasks": len(os.listdir("/proc/self/task")),
            "processes": sum(p.isdigit() for p in os.listdir("/proc")),
            "reach": reach(), "pid": os.getpid()}
def reach():
    # the processes its /proc may list (the template's, where the kernel refused a /proc
    # of its own) are not in its PID namespace: no signal gets to them
    reached = []
    for pid in range(2, 64):
        try:
            os.kill(pid, 0)
            reached.append(pid)
        except ProcessLookupError:
            pass
    return reached
"""


@pytest.fixture(scope="module")
def template():
    made = Template([SHARED], LIMITS, cpu_s=120)
    yield made
    made.close()


def _observed(template, cells) -> dict:
    with Worker(cells, LIMITS, WorkerSetup(template=template)) as worker:
        assert worker.shared == 1 and worker.load_report[0]["ok"] is True
        return worker.call("observe", (), 10).value


def test_nothing_a_submission_does_reaches_the_next(template):
    before = _observed(template, [SHARED, OBSERVER])
    assert before["inv_ok"] and before["round"] == 2 and before["runs"] == 0
    assert before["json"] and before["env"] is None and before["cwd"] == "/tmp"
    assert before["places"] == {"/tmp": [], "/dev/shm": []}
    assert before["threads"] == 1 and before["tasks"] == 1
    assert before["pid"] == 1 and before["reach"] == []   # process 1 of a PID namespace

    with Worker([SHARED, HOSTILE], LIMITS, WorkerSetup(template=template)) as hostile:
        assert all(r["ok"] for r in hostile.load_report), hostile.load_report
        assert hostile.call("observe", (), 5).value == "hostile"
        fork = hostile.proc.pid
        left = sandbox._descendants(fork)
        assert len(left) >= 2, "the daemon and the submission itself run"
    time.sleep(0.2)
    assert not any(sandbox.process_alive(p) for p in left), "nothing it started survives it"

    assert _observed(template, [SHARED, OBSERVER]) == before


def test_a_fork_sees_and_writes_nothing_of_the_host(tmp_path):
    outside = tmp_path / "instructor_notes.txt"
    outside.write_text("mine")
    root = ROOT
    watched = [str(outside), str(root / "autograder" / "planted.py"), "/etc/planted",
               os.path.expanduser("~/planted")]
    secret_places = [str(root / "solutions"), str(root / "autograder" / "specs"),
                     str(tmp_path), str(root / "labs")]
    probes = _probe_source(watched, secret_places, 9)
    made = Template([probes], LIMITS, cpu_s=120)
    try:
        with Worker([probes, "def capabilities():\n    return [l for l in open("
                             "'/proc/self/status') if l.startswith(('CapEff', 'CapBnd', "
                             "'NoNewPrivs'))]\ndef new_userns():\n    import ctypes\n    return ctypes."
                             "CDLL(None).unshare(0x10000000)\n"], LIMITS,
                            WorkerSetup(template=made)) as w:
            assert w.call("writable", (), 5).value == []
            assert w.call("exists", (), 5).value == []
            assert w.call("import_solutions", (), 5).value == "ModuleNotFoundError"
            assert w.call("network", (), 5).value == []
            assert w.call("scratch_fill", (), 8).value < LIMITS.scratch_mb
            assert w.call("capabilities", (), 5).value == [
                "CapEff:\t0000000000000000\n", "CapBnd:\t0000000000000000\n",
                "NoNewPrivs:\t1\n"]
            assert w.call("new_userns", (), 5).value == -1, "no user namespace of its own"
            if sandbox.capabilities().drop_to_uid:
                assert w.call("whoami", (), 5).value == sandbox.SANDBOX_UID
    finally:
        made.close()
    assert outside.read_text() == "mine"


@pytest.mark.skipif(not sandbox.capabilities().cgroup, reason="no writable cgroup here")
def test_a_fork_is_charged_to_its_own_cgroup():
    source = "WATCHED = SECRET_PLACES = []\nPORT = 1\n" + PROBES
    made = Template([source], LIMITS, cpu_s=120)
    try:
        cgroup = sandbox.Cgroup(LIMITS.memory_mb, LIMITS.max_processes)
        try:
            with Worker([source], LIMITS, WorkerSetup(cgroup=cgroup, template=made)) as w:
                assert w.proc.pid in cgroup.pids()
                made_procs = w.call("fork_bomb", (), 8).value
                assert made_procs is not None and made_procs < LIMITS.max_processes
            assert cgroup.kill_all() >= 0 and not cgroup.pids()
        finally:
            cgroup.remove()
    finally:
        made.close()


LAB = "lab0_frames"


@pytest.mark.slow
def test_a_clean_submission_scores_as_alone_after_a_hostile_one(tmp_path_factory, tmp_path):
    course = kit.released_course(tmp_path_factory.mktemp("course"), LAB)
    reference = kit.solution_sources(LAB, ("invert_pose", "compose_chain", "pose_from_rotvec"))
    kit.submit(course, LAB, "clean", replace=reference)
    kit.submit(course, LAB, "hostile", replace=reference,
               extra=HOSTILE.replace("SHARED_STATE[\"runs\"] += 1\n", ""))
    paths = {s: [course / "submitted" / s / LAB / f"{LAB}.ipynb"] for s in ("clean", "hostile")}
    shared = leading_cells(course / "release" / LAB / f"{LAB}.ipynb")
    assert shared, "lab 0 begins with read-only cells"

    def grade(student, template=None):
        g = grade_notebook(paths[student], LAB, "clean", "a-secret", None,
                                   template=template)
        return [(f.name, f.points, f.n_failed, [(c.name, c.credit, c.n_full, c.worst_error, c.median_error) for c in f.checks])
                for f in g.functions], g

    alone, cold = grade("clean")
    made = Template(shared, Limits(), cpu_s=300)
    try:
        forked, first = grade("clean", made)
        _, attacked = grade("hostile", made)
        assert attacked.profile["start_s"] < 5 and "started cold" not in str(attacked.notes)
        after, second = grade("clean", made)
    finally:
        made.close()
    assert alone == forked == after
    assert sum(f[1] for f in alone) == cold.max_score
    assert first.profile["shared_s"] > 0 and cold.profile["shared_s"] == 0


# A lab's leading cells open the simulator (MuJoCo renders through EGL on Mesa's software
# renderer): the template must still be one thread when it forks, or every submission of
# every lab that opens it grades cold (issue 51: lab 1's class took 77 s instead of 43 s).
SIMULATOR = ("import robots\n"
             "cell = robots.connect('sim', arm='ur5e', mount='eye_to_hand', seed=0, "
             "width=64, height=48)\n"
             "frame = cell.camera.capture()\n")


def test_a_template_that_opened_the_simulator_still_forks():
    made = Template([SHARED + SIMULATOR], LIMITS, cpu_s=120)
    try:
        with Worker([SHARED + SIMULATOR, "def tasks():\n    return len(os.listdir("
                     "'/proc/self/task'))\n"], LIMITS, WorkerSetup(template=made)) as worker:
            assert worker.shared == 1 and worker.load_report[0]["ok"] is True
            assert worker.call("tasks", (), 10).value == 1
    finally:
        made.close()
