"""nbgrader's cross-check from the grader's own run of the notebook.

`cobotlab grade` runs nbgrader's autograde converter with the cells executed once, by the
isolated grader's worker (autograder.scratch.autograde_in_worker), instead of a second,
kernel-based run. These tests hold it to nbgrader's own kernel: the same cell scores on
correct, blank and wrong code, on code that prints or writes to stderr; and where the two
must differ, the worker's side is the one that cannot be fooled. Lab 0 (the cheapest lab).
"""

from __future__ import annotations

import json
from pathlib import Path

import course_kit as kit
import pytest

from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.worker import Limits
from autograder.secret import PRIVATE_DIR

LAB0 = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
LIMITS = Limits(cell_timeout_s=5, call_timeout_s=2, load_timeout_s=60)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), LAB0)


def _submissions() -> dict[str, dict[str, str]]:
    code = kit.solution_sources(LAB0, FUNCTIONS)
    return {
        "ref": code,
        "blank": {},
        # multiplies in the wrong order: the visible asserts pass (they commute), the hidden
        # test's chains of 3+ poses do not
        "reversed": dict(code, compose_chain=code["compose_chain"].replace("out @ T", "T @ out")),
        # prints while it works: output is not an error
        "chatty": dict(code, invert_pose=code["invert_pose"].replace(
            "    R = a_T_b", "    print('inverting a pose')\n    R = a_T_b")),
        # writes to stderr in its test cell: nbgrader's rule scores that cell 0
        "stderr": dict(code, invert_pose=code["invert_pose"].replace(
            "    R = a_T_b", "    import sys\n    sys.stderr.write('careful\\n')\n    R = a_T_b")),
    }


def _cell_scores(course: Path, students) -> dict[str, dict[str, float]]:
    """{student: {grade cell: nbgrader's auto score}} from the gradebook."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        return {s: {g.name: g.auto_score for nb in gb.find_submission(LAB0, s).notebooks
                    for g in nb.grades}
                for s in students}


def _nbgrader_own(course: Path) -> dict[str, dict[str, float]]:
    """nbgrader's own cell scores of the last `cobotlab grade` (the gradebook then holds
    cobotlab's; the cross-check keeps nbgrader's in its ledger)."""
    ledger = json.loads((course / PRIVATE_DIR / "nbgrader_cells.json").read_text())
    return {s: {cell: pair[1] for cell, pair in entry["cells"].items()}
            for s, entry in ledger[LAB0].items()}


def _outputs(course: Path, student: str, grade_id: str) -> list[dict]:
    nb = json.loads((course / "autograded" / student / LAB0 / f"{LAB0}.ipynb").read_text())
    return next(c["outputs"] for c in nb["cells"]
                if c["metadata"].get("nbgrader", {}).get("grade_id") == grade_id)


# A notebook that patches the hidden test in its own process: nbgrader's kernel runs the
# patched one, the worker's cells run against the grader's own checks.
PATCH_HIDDEN_TEST = ("import autograder.checks as _checks\n"
                     "_checks.hidden_test = lambda *args, **kwargs: None")


@pytest.fixture(scope="module")
def graded(released, tmp_path_factory) -> tuple[Path, Path, dict[str, dict]]:
    """(kernel course, worker course, the worker course's rows): every submission of both
    tests in two copies of lab 0, one autograded by nbgrader as it comes (one run, its
    kernels), one graded by `cobotlab grade` with nbgrader's run of the cells in the worker.
    One run each for both tests: nbgrader's start, the template and nbgrader's scratch
    course are paid once."""
    root = tmp_path_factory.mktemp("graded")
    subs = dict(_submissions())
    kernel_course = kit.fresh_course(released, root / "kernel")
    worker_course = kit.fresh_course(released, root / "worker")
    for course in (kernel_course, worker_course):
        for student, code in subs.items():
            kit.submit(course, LAB0, student, replace=code)
        kit.submit(course, LAB0, "patcher", replace=subs["reversed"], extra=PATCH_HIDDEN_TEST)

    kit.nbgrader(kernel_course, "autograde", LAB0)   # nbgrader as it comes: one run, kernels
    rows = {r["student_id"]: r for r in grade_course(
        worker_course, LAB0, limits=LIMITS, run_nbgrader=True, quiet=True)}
    return kernel_course, worker_course, rows


def test_cell_scores_match_nbgrader_with_its_own_kernel(graded):
    kernel_course, worker_course, rows = graded
    subs = _submissions()
    kernel = _cell_scores(kernel_course, subs)
    worker = {s: cells for s, cells in _nbgrader_own(worker_course).items() if s in subs}

    assert worker == kernel
    # the expected verdicts, so that agreement is not agreement on nothing
    assert kernel["ref"] == kernel["chatty"] == {"test_invert_pose": 3.0,
                                                 "test_compose_chain": 3.0,
                                                 "test_pose_from_rotvec": 4.0}
    assert set(kernel["blank"].values()) == {0.0}
    assert kernel["reversed"]["test_compose_chain"] == 0.0
    assert kernel["stderr"]["test_invert_pose"] == 0.0
    assert rows["stderr"]["score"] == rows["ref"]["score"] == 10.0   # the grader's own rule

    # the autograded notebook shows what the cells did in the worker
    chatty = _outputs(worker_course, "chatty", "test_invert_pose")
    assert any(o["output_type"] == "stream" and "inverting a pose" in "".join(o["text"])
               for o in chatty)
    failed = _outputs(worker_course, "reversed", "test_compose_chain")
    assert [o["ename"] for o in failed if o["output_type"] == "error"] == ["AssertionError"]
    assert "compose_chain" in failed[-1]["evalue"]
    blank = _outputs(worker_course, "blank", "test_invert_pose")
    assert blank[-1]["ename"] == "NotImplementedError" and "In [" in blank[-1]["evalue"]
    # one run of the notebook served both: nothing of nbgrader's kernel ran
    log = (worker_course / PRIVATE_DIR / "last_run.log").read_text()
    assert "its cells run by the grader" in log


def test_a_patched_hidden_test_fools_the_kernel_but_not_the_worker(graded):
    kernel_course, worker_course, worker_rows = graded
    assert _cell_scores(kernel_course, ["patcher"])["patcher"]["test_compose_chain"] == 3.0
    rows = grade_course(kernel_course, LAB0, limits=LIMITS, quiet=True, students=["patcher"])
    assert [r["student_id"] for r in rows] == ["patcher"]
    assert "nbgrader_passed_but_grader_failed:compose_chain" in rows[0]["flags"].split(";")

    assert _nbgrader_own(worker_course)["patcher"]["test_compose_chain"] == 0.0
    patcher = worker_rows["patcher"]
    assert patcher["score"] < 10 and "suspicious_grader_patch" in patcher["flags"].split(";")


def test_two_conversions_at_once_share_nbgrader_s_environment_variable():
    """nbgrader's setenv deletes NBGRADER_EXECUTION when each conversion ends: with
    `--workers 2` the second to end raised KeyError and lost its autograded notebook."""
    import os
    import threading

    import nbgrader.utils

    from autograder import scratch

    scratch._autograde_class()  # installs the shared setenv, as a grading run does
    inside, leave, errors = threading.Barrier(2), threading.Event(), []

    def conversion(first: bool):
        try:
            with nbgrader.utils.setenv(NBGRADER_EXECUTION="autograde"):
                inside.wait(timeout=10)
                if not first:
                    leave.wait(timeout=10)   # the first one has ended; this one is inside
                    assert os.environ["NBGRADER_EXECUTION"] == "autograde"
            if first:
                leave.set()
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    assert "NBGRADER_EXECUTION" not in os.environ
    threads = [threading.Thread(target=conversion, args=(k == 0,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=20)
    assert errors == [] and "NBGRADER_EXECUTION" not in os.environ
