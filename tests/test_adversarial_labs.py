"""The adversarial corpus on Labs 3, 4 and 5: no attack scores more than the blank.

The cases in tests/adversarial/ are written for lab 0 (see its README.md). Their attacks on
the grader sit in the ``extra`` cell and do not care which lab they run in; the few graded
functions they replace are retargeted to this lab's functions, their bodies kept as they are
(a lab-0 body that reads its lab-0 arguments just fails here, which is worth nothing too).
Every submission keeps the released blanks otherwise, so none may score above the blank.
The cases built around correct lab-0 answers (``mangled``: full marks by name) have nothing
to say about a blank and are left to tests/test_course_cycle.py.

nbgrader is not run: the flags checked are those of the independent grader's own scan.

Each case runs on one of the three labs (in turn, by name), so every attack meets a lab
other than lab 0 once per suite run (tests/test_course_cycle.py runs them all on lab 0);
``COBOTLAB_FULL_CORPUS=1`` runs every case on every lab.
"""

from __future__ import annotations

import os
import re

import course_kit as kit
import pytest

from autograder import grading
from autograder.course import grade_course

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
# Short limits skip the lab's simulator cells (they need the blanks anyway) and make the
# hangs cheap (about 85 s for labs 3 and 4 on 2 cores, against 130 s with 3 s / 2 s limits;
# lab 5 takes its third of the cases, so the file costs about the same with three labs);
# no score here depends on them, every one must be the blank's zero.
# Sleepers are cut at 2x their limit: the attack is tested here, not the clock.
LIMITS = grading.Limits(cell_timeout_s=2, call_timeout_s=1, load_timeout_s=60,
                        wall_factor=2)


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
    if os.environ.get("COBOTLAB_FULL_CORPUS") != "1":   # this lab's half of the cases
        share = sorted(LABS).index(assignment)
        cases = {n: c for i, (n, c) in enumerate(sorted(cases.items()))
                 if i % len(LABS) == share}
    for name, case in cases.items():
        kit.submit(course, assignment, name, replace=_retarget(case, functions),
                   extra=case["extra"], mangle=case["mangle"])
    kit.submit(course, assignment, "blank")

    rows = grade_course(course, assignment, workers=2, run_nbgrader=False, limits=LIMITS,
                        quiet=True)
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
    secret = grading.load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        assert secret not in path.read_text(), path
