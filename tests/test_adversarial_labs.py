"""The adversarial corpus on Labs 3, 4 and 5: no attack scores more than the blank.

The cases in tests/adversarial/ are written for lab 0 (see its README.md). Their attacks on
the grader sit in the ``extra`` cell and do not care which lab they run in; the few graded
functions they replace are retargeted to this lab's functions, their bodies kept as they are
(a lab-0 body that reads its lab-0 arguments just fails here, which is worth nothing too).
Every submission keeps the released blanks otherwise, so none may score above the blank.
The cases built around correct lab-0 answers (``mangled``: full marks by name) have nothing
to say about a blank and are left to tests/test_course_cycle.py.

nbgrader is not run: the flags checked are those of the independent grader's own scan.

A suite run grades the attacks whose grading depends on the lab (LAB_SLICE), each on one of
the three labs, by name; every case meets lab 0 in tests/test_corpus_batch_*.py.
``COBOTLAB_FULL_CORPUS=1`` (benchmarks/adversarial_corpus.py) runs every case on every lab.
"""

from __future__ import annotations

import re

import course_kit as kit
import pytest

from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.worker import Limits
from autograder.secret import load_secret

pytestmark = pytest.mark.slow

# Lab 0's graded functions, in the order their replacements are moved onto a lab's.
LAB0_FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
LABS = {
    "lab3_servoing": ("interaction_matrix", "ibvs_velocity", "piece_position"),
    "lab4_stereo": ("frame_from_three_points", "reproject", "hand_to_eye_from_three_points",
                    "per_axis_rmse"),
    "lab5_depth": ("backproject", "fit_plane_ransac", "fit_flange_circle",
                   "base_T_cam_from_flanges", "rectangle_pose"),
}
CORRECT_ANSWERS_ONLY = {"mangled"}
# What a lab changes about an attack: hostile values and replaced bodies meet the lab's own
# checks and scoring (huge_values, nan_and_shapes, raises, forbidden_alias), patched modules
# meet the libraries the lab's checks call (numpy_patch, sys_modules), the jail hides the
# lab's own source notebook and solutions (reader_source_notebook, import_solutions), and
# the lab's replies cross the pipe the forger writes to (forge_protocol). The other attacks
# act on the grader the same way whatever the lab. Each is graded on one lab, three a lab.
# Lab 4's shared cells outlast these limits' 2 s a cell, so it has no template and every
# submission there starts cold and waits out that cell again: reader_source_notebook, whose
# search starts over after every call it loses to its time limit, cost 11 s of CPU there
# against about 3 on lab 5, where it forks from the template.
LAB_SLICE = {
    "lab3_servoing": ("forbidden_alias", "import_solutions", "raises"),
    "lab4_stereo": ("forge_protocol", "nan_and_shapes", "sys_modules"),
    "lab5_depth": ("huge_values", "numpy_patch", "reader_source_notebook"),
}
# Short limits skip the lab's simulator cells (they need the blanks anyway) and make the
# hangs cheap (a third of the corpus on labs 3 and 4 took about 85 s on 2 cores, against
# 130 s with 3 s / 2 s limits); no score here depends on them, every one must be the
# blank's zero.
# Sleepers are cut at 2x their limit: the attack is tested here, not the clock.
LIMITS = Limits(cell_timeout_s=2, call_timeout_s=1, load_timeout_s=60,
                        wall_factor=2)
# The labs whose shared cells outlast LIMITS (lab 4's stereo captures): a template could not
# load them, so their submissions are started cold from the first (`--no-template`) rather
# than after a template's attempt that times out on the same cell (about 4 s of CPU spent
# for nothing). The others fork from their template, and the test checks that they do.
STARTED_COLD = {"lab4_stereo"}


def _retarget(case: dict, functions: tuple[str, ...]) -> dict[str, str]:
    """The case's replaced cells moved from lab 0's functions onto ``functions``: the same
    body under the lab's name, taking whatever arguments the grader passes (a name bound
    by an assignment, not a def, is bound to the same value under the lab's name)."""
    moved = {}
    for lab0_name, name in zip(LAB0_FUNCTIONS, functions):
        if lab0_name in case["replace"]:
            source, n = re.subn(rf"def {lab0_name}\([^)]*\):", f"def {name}(*args, **kwargs):",
                                case["replace"][lab0_name], count=1)
            if n == 0:
                source, n = re.subn(rf"^{lab0_name}(\s*=)", rf"{name}\1", source, count=1,
                                    flags=re.MULTILINE)
            assert n == 1, (lab0_name, case["replace"][lab0_name])
            moved[name] = source
    return moved


def _scan_flags(case: dict) -> list[str]:
    """The flags the case declares that the grader's own scan raises (not nbgrader's)."""
    return [f for f in case["flags"] if f.startswith("suspicious_")]


@pytest.mark.parametrize("assignment", sorted(LABS))
def test_adversarial_corpus_scores_no_more_than_the_blank(assignment, tmp_path):
    functions = LABS[assignment]
    course = kit.released_course(tmp_path, assignment)
    cases = {n: c for n, c in kit.corpus().items()
             if n not in CORRECT_ANSWERS_ONLY and c["layer"] == "notebook"}
    assert len(cases) >= 12 and sum(len(_scan_flags(c)) for c in cases.values()) >= 7
    assert set(LAB_SLICE) == set(LABS), "a lab without its share of the slice"
    assert {n for names in LAB_SLICE.values() for n in names} <= set(cases), \
        "a renamed case: update LAB_SLICE"
    if not kit.full_corpus():   # this lab's third of the slice
        cases = {n: cases[n] for n in LAB_SLICE[assignment]}
    for name, case in cases.items():
        kit.submit(course, assignment, name, replace=_retarget(case, functions),
                   extra=case["extra"], mangle=case["mangle"])
    kit.submit(course, assignment, "blank")

    rows = grade_course(course, assignment, workers=2, run_nbgrader=False, limits=LIMITS,
                        quiet=True, template=assignment not in STARTED_COLD)
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert ("template: the interpreter" in log) == (assignment not in STARTED_COLD), log[:2000]
    grades = {r["student_id"]: r for r in rows}
    assert set(grades) == set(cases) | {"blank"}, "every submission gets a row"
    blank = grades["blank"]
    assert blank["score"] == 0.0 and blank["max_score"] == 10.0, \
        (blank, kit.log_lines(course, "blank"))
    assert not any(f.startswith("suspicious") for f in blank["flags"].split(";")), blank
    for name, case in cases.items():
        row = grades[name]
        assert row["max_score"] == blank["max_score"], (name, row)
        assert row["score"] != "", ("graded: no grader error", name, row,
                                    kit.log_lines(course, name))
        assert row["score"] <= blank["score"], (name, row)
        flags = row["flags"].split(";")
        for wanted in _scan_flags(case):
            assert any(f.startswith(wanted) for f in flags), (name, wanted, row["flags"])
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        assert secret not in path.read_text(), path
