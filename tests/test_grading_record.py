"""Grades an instructor can defend: reproducible, kept per assignment, in nbgrader's gradebook.

The same submission gets the same problems and score on every regrade (fresh problems only on
request, replayable); grades.csv keeps every assignment; cobotlab's per-function score is what
formgrader, `nbgrader export` and nbgrader's feedback show, with nbgrader's own result kept
as the cross-check and an instructor's manual score surviving a regrade; nbgrader's feedback
holds no hidden test; a hang is flagged. Lab 0 throughout (the cheapest lab).
"""

from __future__ import annotations

import csv
import html
import json
import re
from dataclasses import replace
from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import record
from autograder.nbgrader_hooks import strip_hidden
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import problem_rng
from autograder.pipeline.worker import Limits
from autograder.secret import PRIVATE_DIR

LAB0, LAB1 = "lab0_frames", "lab1_flange"
LAB0_FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
LIMITS = Limits(cell_timeout_s=5, call_timeout_s=2, load_timeout_s=60)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    """A course with lab 0 generated (released) once; tests copy it."""
    return kit.released_course(tmp_path_factory.mktemp("course"), LAB0)


def _submit_blank_from_source(course: Path, assignment: str, student: str) -> None:
    """A submission of an assignment nbgrader never generated: the source notebook with
    every solution cell emptied (cheaper than generating it, and not in the gradebook)."""
    nb = json.loads((course / "source" / assignment / f"{assignment}.ipynb").read_text())
    for cell in nb["cells"]:
        if cell["metadata"].get("nbgrader", {}).get("solution"):
            cell["source"] = "# YOUR CODE HERE"
    out = course / "submitted" / student / assignment
    out.mkdir(parents=True)
    (out / f"{assignment}.ipynb").write_text(json.dumps(nb))


def _solutions() -> dict[str, str]:
    return kit.solution_sources(LAB0, LAB0_FUNCTIONS)


def _side_dependent() -> dict[str, str]:
    """A lab 0 submission whose score depends on the problems drawn: invert_pose clamps the
    translation's z to be non-negative ("the frame is above the table"), so it is right only
    on the poses whose t_z >= 0."""
    code = _solutions()
    code["invert_pose"] = code["invert_pose"].replace(
        "-R.T @ t", "-R.T @ np.array([t[0], t[1], abs(t[2])])")
    assert code["invert_pose"] != _solutions()["invert_pose"]
    return code


def _scores(course: Path, assignment: str = LAB0) -> dict[str, str]:
    with open(course / "grades.csv") as f:
        return {r["student_id"]: r["score"] for r in csv.DictReader(f)
                if r["assignment"] == assignment}


def _runs(course: Path) -> list[dict]:
    lines = (course / PRIVATE_DIR / "runs.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


# --------------------------------------------------------------------------- reproducible


def test_problems_depend_on_the_names_only_unless_a_nonce_is_given():
    def draw(nonce, student="alice", function="invert_pose"):
        return problem_rng("s" * 32, nonce, LAB0, student, function).random(4)

    assert np.array_equal(draw(None), draw(None)) and np.array_equal(draw(None), draw(""))
    assert not np.array_equal(draw(None), draw(None, student="bob"))
    assert not np.array_equal(draw(None), draw(None, function="compose_chain"))
    assert not np.array_equal(draw(None), draw("ab" * 16))
    assert np.array_equal(draw("ab" * 16), draw("ab" * 16))


def test_regrade_reproduces_every_score_and_a_fresh_run_replays(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    # Three students with the same draw-dependent bug: on per-run problems their scores
    # change between runs (all three equal by chance about once in a hundred).
    for student in ("ana", "ben", "cy"):
        kit.submit(course, LAB0, student, replace=_side_dependent())
    grade_course(course, LAB0, workers=2, limits=LIMITS, quiet=True)
    first = _scores(course)
    assert all(0 < float(s) < 10 for s in first.values()), first  # partial credit
    grade_course(course, LAB0, workers=2, limits=LIMITS, quiet=True)
    assert _scores(course) == first
    assert [r["problems"] for r in _runs(course)] == ["fixed", "fixed"]
    assert all(r["nonce"] is None for r in _runs(course))

    fresh = grade_course(course, LAB0, limits=LIMITS, quiet=True, fresh=True, students=["ana"])
    run = _runs(course)[-1]
    assert run["problems"] == "fresh" and len(run["nonce"]) == 32
    replay = grade_course(course, LAB0, limits=LIMITS, quiet=True, nonce=run["nonce"],
                          students=["ana"])
    assert [r["score"] for r in replay] == [r["score"] for r in fresh]
    assert _runs(course)[-1]["problems"] == "replay"
    with pytest.raises(ValueError, match="one of them"):
        grade_course(course, LAB0, quiet=True, fresh=True, nonce=run["nonce"])
    with pytest.raises(ValueError, match="runs.jsonl"):
        grade_course(course, LAB0, quiet=True, nonce="not a nonce")


# --------------------------------------------------------------------------- grades.csv


def test_grades_csv_keeps_every_assignment_and_replaces_a_regraded_row(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    kit.submit(course, LAB0, "ana", replace=_solutions())
    kit.submit(course, LAB0, "=ben")  # a name a spreadsheet would run: refused
    _submit_blank_from_source(course, LAB1, "ana")
    grade_course(course, LAB0, limits=LIMITS, quiet=True)
    grade_course(course, LAB1, limits=LIMITS, quiet=True)
    # keyed by freeze.student_key: no formula, and not the accepted id "'=ben"
    assert _scores(course, LAB0) == {"ana": "10.0", "\\x3dben": "0.0"}
    assert _scores(course, LAB1) == {"ana": "0.0"}

    # ana hands in lab 0 again, blank this time; only she is regraded
    kit.submit(course, LAB0, "ana")
    grade_course(course, LAB0, limits=LIMITS, quiet=True, students=["ana"])
    with open(course / "grades.csv") as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["assignment"], r["student_id"], r["score"]) for r in rows) == [
        (LAB0, "\\x3dben", "0.0"), (LAB0, "ana", "0.0"), (LAB1, "ana", "0.0")]
    assert (course / "grades.csv").read_text().count("assignment,duedate,") == 1


def test_update_csv_moves_an_unreadable_file_aside(tmp_path):
    (tmp_path / "grades.csv").write_bytes(b"\xff\xfe not csv")
    rows = record.update_csv(tmp_path, "grades.csv", ["assignment", "student_id", "score"],
                             [{"assignment": "a", "student_id": "s", "score": 1.0}],
                             key=("assignment", "student_id"))
    assert rows == [{"assignment": "a", "student_id": "s", "score": 1.0}]
    assert (tmp_path / "grades.csv").read_text().splitlines() == [
        "assignment,student_id,score", "a,s,1.0"]
    assert len(list(tmp_path.glob("grades.csv.unreadable-*"))) == 1


# --------------------------------------------------------------------------- a hang


def test_a_function_that_hangs_is_flagged_timed_out(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    code = _solutions()
    code["invert_pose"] = "def invert_pose(a_T_b):\n    while True:\n        pass\n"
    kit.submit(course, LAB0, "hangs", replace=code)
    kit.submit(course, LAB0, "fine", replace=_solutions())
    # the three test cells that call the hanging function time out too: 2 s of CPU each
    # (lab 0's imports cell needs about 1.1 s in a fresh interpreter) rather than the
    # file's 5; the grader's call of it 1 s (lab 0's calls take milliseconds), not 2
    limits = replace(LIMITS, cell_timeout_s=2, call_timeout_s=1)
    rows = {r["student_id"]: r for r in grade_course(course, LAB0, workers=2, limits=limits,
                                                     quiet=True)}
    flags = rows["hangs"]["flags"].split(";")
    assert "timed_out:invert_pose" in flags, flags
    assert not [f for f in flags if f.startswith("timed_out:") and f != "timed_out:invert_pose"]
    assert rows["hangs"]["score"] == 7.0  # the other two functions keep their credit
    assert "timed_out" not in rows["fine"]["flags"]
    assert "timed_out:invert_pose" in kit.read_grades(course)["hangs"]["flags"]


# --------------------------------------------------------------------------- nbgrader


def test_strip_hidden_tolerates_stray_and_unclosed_markers():
    text = "a\n### BEGIN HIDDEN TESTS\nsecret()\n### END HIDDEN TESTS\nb"
    assert strip_hidden(text) == ("a\nb", True)
    assert strip_hidden("a\n### BEGIN HIDDEN TESTS\nsecret()") == ("a", True)
    assert strip_hidden("a\n### END HIDDEN TESTS\nb")[1] is False  # a stray end hides nothing


def _gradebook(course: Path, student: str) -> dict:
    """{cell: (auto_score, manual_score, max_score)} and {cell: (auto, manual comment)}."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        sub = gb.find_submission(LAB0, student)
        grades = {g.name: (g.auto_score, g.manual_score, g.max_score)
                  for nb in sub.notebooks for g in nb.grades}
        comments = {c.name: (c.auto_comment, c.manual_comment)
                    for nb in sub.notebooks for c in nb.comments}
    return {"grades": grades, "comments": comments}


def _exported(course: Path) -> dict[str, float]:
    """Lab 0's scores in nbgrader's own export (nbgrader_grades.csv, the course's config)."""
    with open(course / "nbgrader_grades.csv") as f:
        return {r["student_id"]: float(r["score"]) for r in csv.DictReader(f)
                if r["assignment"] == LAB0}


@pytest.mark.timeout(600)
def test_cobotlab_scores_are_what_nbgrader_shows_and_its_feedback_hides_the_tests(
        released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    code = _solutions()
    wrong = dict(code, invert_pose=code["invert_pose"].replace("-R.T @ t", "-t"))
    case = kit.corpus(LAB0)["sys_modules"]  # fools nbgrader's kernel into passing it all
    kit.submit(course, LAB0, "ref", replace=code)
    kit.submit(course, LAB0, "wrong", replace=wrong)
    kit.submit(course, LAB0, "fools", replace=case["replace"], extra=case["extra"])
    kit.nbgrader(course, "autograde", LAB0)
    nb_own = _gradebook(course, "fools")["grades"]
    assert all(auto == top for auto, _, top in nb_own.values()), nb_own  # nbgrader: 10/10

    rows = {r["student_id"]: r for r in grade_course(course, LAB0, limits=LIMITS, quiet=True)}
    assert rows["ref"]["score"] == 10.0 and rows["fools"]["score"] == 0.0
    # nbgrader's own results agree with cobotlab's on an honest notebook: no flag at all
    assert rows["ref"]["flags"] == "", rows["ref"]
    assert 0 < rows["wrong"]["score"] < 10
    fooled = "nbgrader_passed_but_grader_failed:invert_pose"
    assert fooled in rows["fools"]["flags"].split(";")

    # cobotlab's per-function score is in each function's autograder cell
    wrong_book = _gradebook(course, "wrong")
    points = {f"test_{name}": wrong_book["grades"][f"test_{name}"][2] for name in LAB0_FUNCTIONS}
    assert sum(points.values()) == 10
    assert sum(a for a, _, _ in wrong_book["grades"].values()) == pytest.approx(
        rows["wrong"]["raw_score"], abs=0.02)
    assert wrong_book["grades"]["test_invert_pose"][0] < points["test_invert_pose"]
    assert all(a == 0 for a, _, _ in _gradebook(course, "fools")["grades"].values())
    comment = _gradebook(course, "fools")["comments"]["invert_pose"][0]
    assert comment.startswith("cobotlab: 0 / 3 points") and fooled in comment
    assert "nbgrader's own hidden-test cell: 3 / 3" in comment

    # an instructor's manual grade survives a regrade (of the two it is about; ref's
    # gradebook entries stay the first run's); the cross-check keeps nbgrader's own result
    # although the gradebook now holds cobotlab's
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        gb.find_grade("test_invert_pose", LAB0, LAB0, "wrong").manual_score = 2.5
        gb.find_comment("invert_pose", LAB0, LAB0, "wrong").manual_comment = "see me"
        gb.db.commit()
    again = {r["student_id"]: r for r in grade_course(course, LAB0, limits=LIMITS, quiet=True,
                                                      students=["wrong", "fools"])}
    assert again["wrong"]["raw_score"] == rows["wrong"]["raw_score"]  # cobotlab's own
    assert fooled in again["fools"]["flags"].split(";")
    book = _gradebook(course, "wrong")
    assert book["grades"]["test_invert_pose"][1] == 2.5
    assert book["comments"]["invert_pose"][1] == "see me"

    # `nbgrader export` (one run, after the regrade) shows cobotlab's scores, in a file of
    # its own: ref's and fools' as cobotlab gave them, wrong's with every cell cobotlab's
    # automatic score but the one the instructor overrode
    ours = (course / "grades.csv").read_text()
    kit.nbgrader(course, "export")
    assert (course / "grades.csv").read_text() == ours
    exported = _exported(course)
    assert set(exported) == set(rows)
    assert exported["ref"] == pytest.approx(rows["ref"]["score"], abs=0.02)
    assert exported["fools"] == pytest.approx(rows["fools"]["score"], abs=0.02)
    assert exported["wrong"] == pytest.approx(
        rows["wrong"]["score"] - book["grades"]["test_invert_pose"][0] + 2.5, abs=0.02)

    # nbgrader's own feedback: cobotlab's scores and comments, no hidden test
    # (the autograded notebooks it reads hold them; "fools" names hidden_test in its own code)
    hidden = ("HIDDEN TESTS", "import hidden_test", *(f"hidden_test({n})" for n in LAB0_FUNCTIONS))
    autograded = (course / "autograded" / "ref" / LAB0 / f"{LAB0}.ipynb").read_text()
    assert all(needle in autograded for needle in hidden)
    kit.nbgrader(course, "generate_feedback", LAB0)
    pages = sorted((course / "feedback").rglob("*.html"))
    assert len(pages) == 3
    for page in pages:
        text = html.unescape(re.sub(r"<[^>]+>", "", page.read_text()))  # code as displayed
        assert "def invert_pose" in text
        for needle in hidden:
            assert needle not in text, (page, needle)
    fools_page = (course / "feedback" / "fools" / LAB0 / f"{LAB0}.html").read_text()
    assert "cobotlab: 0 / 3 points" in fools_page
    assert "Output of the hidden tests removed" in fools_page
    # the flags and the cross-check are the instructor's (formgrader shows them), not feedback
    assert fooled not in fools_page and "nbgrader&#39;s own" not in fools_page
    assert "nbgrader's own" not in html.unescape(fools_page)
    # after nbgrader's own autograde too, cobotlab's feedback is on top of each page
    section = fools_page[fools_page.index("cobotlab-feedback"):]
    assert "Score: 0 / 10<" in section and "suspicious_" not in fools_page
