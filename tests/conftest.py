"""Shared pytest settings: one BLAS and OpenCV thread per process, a deterministic
hypothesis profile (reproducible CI runs), slow test files collected first, and one folder
per run for what is built once and shared."""
import os
import sys
import warnings

import pytest
from hypothesis import HealthCheck, settings

# ``make test`` runs three pytest workers on two cores, and each starts kernels, graders and
# command lines of its own: the machine is saturated for the whole run. A multi-threaded
# BLAS there makes every numpy call wait for its threads, one of which is always descheduled
# (OpenBLAS's threads spin until all are done): a simulation test took 34 s of wall clock
# and 17.5 s of CPU with OpenBLAS's default two threads beside another busy process, 17 s and
# 12.6 s with one. Set before anything imports numpy (which reads them once), inherited by
# every process a test starts; a variable already set is left as it is.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
              "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_name, "1")
if "numpy" in sys.modules:   # a plugin imported it first: this process keeps its threads
    warnings.warn("numpy was imported before tests/conftest.py set one BLAS thread: this "
                  "pytest process runs its BLAS multi-threaded", stacklevel=1)

settings.register_profile(
    "cobotlab", max_examples=200, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("cobotlab")


# The longest files of a full run, longest first (wall seconds under ``make test``, from
# ``--durations``: issue 51). Each runs on one worker whole, so the longest must start first
# (largest first is what keeps a greedy schedule's tail short); the hub term, mostly waiting
# on its servers and Chromium, then overlaps the busiest minutes instead of a quiet end.
LONGEST_FIRST = (
    "test_hub_term.py",             # ~195 s
    "test_course_install.py",       # ~175 s
    "test_adversarial_labs.py",     # ~145 s
    "test_corpus_batch_a.py",       # ~115 s
    "test_grading_contention.py",   # ~115 s
    "test_student_install.py",      # ~100 s
    "test_instructor_docs.py",      # ~90 s
    "test_answer_free.py",          # ~85 s
    "test_cli.py",                  # ~55 s
)


def _start_rank(path, slow_files) -> int:
    """0.. for LONGEST_FIRST, then files with slow tests, then the rest."""
    if path.name in LONGEST_FIRST:
        return LONGEST_FIRST.index(path.name)
    return len(LONGEST_FIRST) + (path not in slow_files)


def pytest_collection_modifyitems(session, config, items):
    """The longest files first (LONGEST_FIRST), then the other files with slow tests (in
    their usual order), then the rest.

    ``make test`` hands whole files to its workers in collection order (``--dist loadfile``),
    so a long file collected late becomes the run's tail: a one-minute grading file that
    starts in the last minute finishes alone. Starting the long ones first lets the short
    ones fill in around them."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    # stable: a file's tests keep their order
    items.sort(key=lambda item: _start_rank(item.path, slow_files))


@pytest.fixture(autouse=True)
def _no_course_left_behind():
    """The course commands set $COBOTLAB_COURSE for their child processes (as the CLI wants);
    in a test process that would make the next test's subprocesses load another course."""
    before = os.environ.get("COBOTLAB_COURSE")
    yield
    if os.environ.get("COBOTLAB_COURSE") != before:
        from autograder import registry

        registry.use_course(before)


@pytest.fixture(scope="session", autouse=True)
def _built_once_for_the_whole_run(tmp_path_factory):
    """What tests/course_kit.built_once builds (a released course, a wheel) goes in this
    run's temporary folder, the one all xdist workers share (each worker's own folder is in
    it), so it is built once per run and removed with pytest's old temporary folders.

    So does the practice-problem cache (autograder/practice_cache.py), inherited by every
    process a test starts: every `course init`, `labs student` and instructor's kernel of
    the run drew the six labs' practice problems again (about 10 s of CPU each). One the
    caller set is kept (a warm cache to measure with)."""
    import course_kit

    from autograder import practice_cache

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    course_kit.BUILT_ONCE_DIR = shared / "built-once"
    os.environ.setdefault(practice_cache.ENV, str(shared / "practice-cache"))


def _kernels_under(pid: int) -> list[int]:
    """The Jupyter kernels among ``pid``'s descendants."""
    import course_kit

    from autograder import sandbox

    return [p for p in sandbox._descendants(pid)
            if "ipykernel_launcher" in course_kit.cmdline(p)]


@pytest.fixture(scope="module", autouse=True)
def _no_kernel_outlives_its_file():
    """A kernel a test file started is stopped by the end of that file: a leaked one (a
    NotebookClient given its own kernel manager does not stop it) kept spending CPU for
    the rest of the run, slowing every later test."""
    import signal
    import time

    yield
    deadline = time.monotonic() + 10   # a kernel asked to stop may take a moment
    while (left := _kernels_under(os.getpid())) and time.monotonic() < deadline:
        time.sleep(0.2)
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert not left, f"this file's tests left {len(left)} Jupyter kernel(s) running"
