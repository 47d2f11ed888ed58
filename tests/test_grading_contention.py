"""A busy machine is the grader's problem, never the student's (issue 37, item 2).

Each submission's processes share one cgroup with the CPU weight of one busy process
(``cpu.shares`` / ``cpu.weight``), so a submission running thirty busy processes takes no
more of the machine from the one graded beside it than one busy process would; and a cell
or call stopped by the wall clock while under its CPU limit, having waited for a CPU most
of that time, is the grader's failure (GraderError: graded again in a fresh sandbox), while
one that sleeps past the wall clock is still the student's time-out. The wall clock counts
only the time the worker could run (the seconds it waited for a CPU are added back, up to
three times the limit), so a cell that is only slowed by a busy machine is simply graded.

Contention is made real by pinning the grader, and so every sandbox it starts, to one core
beside the busy processes, whatever else the machine runs. Real bubblewrap, real cgroups,
real template forks.
"""

from __future__ import annotations

import contextlib
import os
import signal

import course_kit as kit
import numpy as np
import pytest

from autograder import sandbox
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.worker import GraderError, Limits, Worker, WorkerSetup
from autograder.template import Template

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                 reason="bubblewrap cannot run here")]

BURN = """\
import time
def burn(cpu_s):
    start = time.process_time()
    while time.process_time() - start < cpu_s:
        pass
def slow():
    burn(0.4)
    return 1
def sleeper():
    time.sleep(100)
"""
# 0.5 s of CPU a cell or call, 1 s of wall clock (3 s with the waits added back): a burn of
# 0.4 s needs 40 % of a core, and beside HOGS busy processes on its core the worker gets
# about 1 / (HOGS + 1). Every busy process spins while a cell or call runs out its clock, so
# the limits are short; the proportions (the burn to its limit, the wall clock to the CPU
# limit) are what each claim rests on, not the seconds.
LIMITS = Limits(cell_timeout_s=0.5, call_timeout_s=0.5, load_timeout_s=30, wall_factor=2)
WALL_S = LIMITS.wall_factor * LIMITS.call_timeout_s   # a cell's or call's wall clock
HOGS = 8


def _spin(core: int) -> None:
    # A session of its own (the kernel's autogroups share the CPU between sessions) on the
    # grader's core: the machine busy with other work, outside any submission's cgroup.
    os.setsid()
    os.sched_setaffinity(0, {core})
    while True:
        pass


@contextlib.contextmanager
def _one_core():
    """This thread (and what it starts from now on) pinned to one core; yields it."""
    cpus = os.sched_getaffinity(0)
    core = min(cpus)
    os.sched_setaffinity(0, {core})
    try:
        yield core
    finally:
        os.sched_setaffinity(0, cpus)


@contextlib.contextmanager
def _busy(core: int, n: int):
    """``n`` busy processes on ``core`` while a worker runs cells and calls, killed on the
    way out. They are held stopped (SIGSTOP) from the start of each worker until it says it
    is ready, and again from when it closes: each test's claims are about cells and calls
    beside them, and a cold interpreter starting at a ninth of a core kept the hogs
    spinning a whole core for seconds that no assertion looks at."""
    import multiprocessing

    context = multiprocessing.get_context("fork")
    hogs = [context.Process(target=_spin, args=(core,), daemon=True) for _ in range(n)]
    for hog in hogs:
        hog.start()

    def send(signum: int) -> None:
        for hog in hogs:
            os.kill(hog.pid, signum)

    send(signal.SIGSTOP)
    ready, close = Worker._wait_ready, Worker.close

    def ready_then_busy(worker, first):
        ready(worker, first)
        send(signal.SIGCONT)

    def idle_then_close(worker):
        send(signal.SIGSTOP)
        close(worker)

    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(Worker, "_wait_ready", ready_then_busy)
            patch.setattr(Worker, "close", idle_then_close)
            yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.join()


def _cgroup(forked: bool):
    """A fork's CPU is read from its cgroup (where there is one), a cold worker's from its
    processes: both ways of judging are used."""
    if forked and sandbox.capabilities().cgroup:
        return sandbox.Cgroup(LIMITS.memory_mb, LIMITS.max_processes)
    return None


# Busy processes of the submission's own, each in a session of its own, for at most 30 s.
CROWD = """\
import os
for _ in range(8):
    if os.fork() == 0:
        os.setsid()
        _stop = time.monotonic() + 30
        while time.monotonic() < _stop:
            pass
        os._exit(0)
burn(0.4)
"""
# 3 s of wall clock for its 0.5 s limit: the submission's own processes use that half second
# even when a few other busy processes (another test file's, a neighbour's) share the core.
CROWD_LIMITS = Limits(cell_timeout_s=0.5, call_timeout_s=0.5, load_timeout_s=30,
                              wall_factor=6)


@pytest.mark.parametrize("forked", [False, True], ids=["cold", "template_fork"])
def test_starved_is_the_graders_failure_asleep_or_crowded_by_itself_the_students(forked):
    with _one_core() as core:
        template = Template([BURN], LIMITS, cpu_s=60) if forked else None
        cgroup = _cgroup(forked)
        try:
            with _busy(core, HOGS):
                # a sleeping cell and a sleeping call are not runnable: their time-outs
                # stay the student's, however busy the core
                with Worker([BURN, "time.sleep(100)"], LIMITS, WorkerSetup(cgroup=cgroup,
                                    template=template)) as w:
                    assert w.load_report[1]["error"] == "timed out", w.load_report
                    slept = w.call("sleeper", (), LIMITS.call_timeout_s)
                    assert slept.error.startswith("timed out") and slept.seconds >= WALL_S
                    # a call that needs 0.4 s of its 0.5 s and gets a ninth of a core
                    with pytest.raises(GraderError, match="waited .* for a CPU"):
                        w.call("slow", (), LIMITS.call_timeout_s)
                    assert not w.alive
                # the same for a cell while loading
                with pytest.raises(GraderError, match="cell 1 was stopped"):
                    Worker([BURN, "burn(0.4)"], LIMITS, WorkerSetup(cgroup=cgroup,
                                   template=template))
            # Beside two busy processes it needs 1.2 s of wall clock for its 0.4 s: the
            # time it waited for the core is added back to its 1 s (up to three times
            # that), so it is graded, not retried nor timed out
            with _busy(core, 2):
                with Worker([BURN, "burn(0.4)"], LIMITS, WorkerSetup(cgroup=cgroup,
                                    template=template)) as w:
                    assert w.load_report[1]["ok"], w.load_report
                    outcome = w.call("slow", (), LIMITS.call_timeout_s)
                    assert outcome.value == 1 and outcome.seconds > WALL_S, outcome
                # A cell that loops for ever is its own time-out, never the grader's failure,
                # even when the cgroup's count read a moment after its CPU timer fired falls
                # a hair short of its half second
                with Worker([BURN, "while True:\n    pass"], LIMITS, WorkerSetup(cgroup=cgroup,
                                    template=template)) as w:
                    assert w.load_report[1]["error"] == "timed out", w.load_report
            # Its own eight busy processes leave its cell a ninth of what it gets: the
            # submission used its CPU, so the time-out is its own, not a retry.
            with Worker([BURN, CROWD], CROWD_LIMITS, WorkerSetup(cgroup=cgroup,
                                template=template)) as w:
                assert w.load_report[1]["error"] == "timed out", w.load_report
        finally:
            if template is not None:
                template.close()
            if cgroup is not None:
                cgroup.remove()


LAB = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
# A correct notebook whose invert_pose cell needs 0.375 s of CPU before it defines the
# function, and refuses to define it when that took more than 3.5 s of wall clock: it needs a
# tenth of the core, so a busy machine around the test does not starve it. Beside the hog's
# twenty busy processes it gets half the core with a share per submission, a twenty-first
# without: stopped, it leaves invert_pose undefined. (The grader's own wall clock would not
# tell the two apart: the seconds a cell waited for a CPU are added back to it.) A cell
# before it waits until the hog's crowd is running.
WAIT_FOR_THE_HOG = "import time\ntime.sleep(2.0)\n"
NEEDS_CPU = """\
_wall, _cpu = time.monotonic(), time.process_time()
while time.process_time() - _cpu < 0.375:
    pass
_wall = time.monotonic() - _wall
if _wall > 3.5:
    raise RuntimeError(f"starved: 0.375 s of CPU took {_wall:.1f} s of wall clock")
"""


@pytest.mark.timeout(600)
@pytest.mark.skipif(sandbox.capabilities().cpu_share is None,
                    reason="no cpu controller for a submission's cgroup here")
def test_a_correct_submission_beside_a_cpu_hog_scores_full_marks(tmp_path):
    """tests/adversarial/cpu_hog.py (a bounded crowd of busy processes) and a correct
    notebook graded at once, ``--workers 2`` on one core, with a notebook whose function
    sleeps (charged its time-out as ever). Without a CPU share per submission the correct
    notebook gets a twenty-first of the core, its cell refuses to define invert_pose and
    the function scores 0 (checked by running this test with the share switched off)."""
    course = kit.released_course(tmp_path, LAB)
    reference = kit.solution_sources(LAB, FUNCTIONS)
    kit.submit(course, LAB, "correct",
               replace=dict(reference, invert_pose=NEEDS_CPU + reference["invert_pose"]),
               extra=WAIT_FOR_THE_HOG)
    hog = kit.corpus(LAB)["cpu_hog"]
    kit.submit_case(course, LAB, "cpu_hog", hog)
    sleeps = reference["invert_pose"].replace("    R = ", "    time.sleep(100)\n    R = ", 1)
    assert sleeps != reference["invert_pose"]
    kit.submit(course, LAB, "sleeper", replace=dict(reference, invert_pose=sleeps),
               extra="import time\n")
    # 2 s of CPU a cell (4 s of wall clock): the sleeper's three test cells and the hog's
    # sleeping cells each wait that long, so the hog's crowd spins that long too. (With the
    # share switched off this test still fails: correct, grader_error, no score.)
    limits = Limits(cell_timeout_s=2, call_timeout_s=1, load_timeout_s=60,
                            wall_factor=2)
    with _one_core():
        rows = grading_rows(course, limits)
    # nbgrader is not run here (its flag says so): the grader's own flags are the point
    assert rows["correct"]["score"] == 10.0, rows["correct"]
    assert rows["correct"]["flags"] == "nbgrader_no_result", rows["correct"]
    assert rows["cpu_hog"]["score"] <= hog["earned"], rows["cpu_hog"]
    assert "grader_error" not in rows["cpu_hog"]["flags"], rows["cpu_hog"]
    assert "timed_out:invert_pose" in rows["sleeper"]["flags"], rows["sleeper"]
    assert "grader_error" not in rows["sleeper"]["flags"], rows["sleeper"]
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert "cpu share: " in log and "grader error" not in log, log[:3000]
    correct = next(line for line in log.splitlines() if line.startswith("correct: "))
    assert "timed out" not in correct, correct


def grading_rows(course, limits) -> dict[str, dict]:

    return {r["student_id"]: r for r in grade_course(course, LAB, workers=2, limits=limits,
                                                       quiet=True)}


# A reference invert_pose, the notebook's last cell.
INVERT_POSE = """
import numpy as np
def invert_pose(T):
    out = np.eye(4); out[:3, :3] = T[:3, :3].T; out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
"""


def test_time_limits_count_cpu_seconds_so_a_busy_machine_grades_the_same():
    """A cell needing 0.75 s of CPU under a 1 s limit, on a core it shares with a busy process
    (so over 1 s of wall clock), runs as on a quiet laptop; a busy loop is still stopped by
    its CPU timer, a sleeper by the wall-clock backstop. In this file with the other tests
    that pin to the grader's core, so no two of them crowd that core at once."""
    import time

    limits = Limits(cell_timeout_s=1, call_timeout_s=1, load_timeout_s=30,
                            wall_factor=3)
    cells = [BURN, "burn(0.75)", "while True:\n    pass", "time.sleep(1000)", INVERT_POSE]
    with _one_core() as core, _busy(core, 1):
        started = time.monotonic()
        with Worker(cells, limits, WorkerSetup(cpu_s=60)) as worker:
            report = {r["index"]: r for r in worker.load_report}
            result = worker.call("invert_pose", (np.eye(4),), limits.call_timeout_s)
        elapsed = time.monotonic() - started
    assert report[1]["ok"], report[1]
    assert report[1]["seconds"] > limits.cell_timeout_s, \
        "the hog did not load the core: the test proves nothing"
    assert report[2]["error"] == "timed out" and report[3]["error"] == "timed out"
    # the busy loop's own CPU timer stopped it (the grader then never judges it starved),
    # the sleeper's wall clock
    assert report[2].get("limit") == "cpu" and "limit" not in report[3], (report[2], report[3])
    assert 2.5 < report[3]["seconds"] < 4.0, report[3]   # the 3 x 1 s wall-clock backstop
    assert np.allclose(result.value, np.eye(4))
    assert elapsed < 30
