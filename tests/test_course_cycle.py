"""The full nbgrader cycle on lab 0 with real nbgrader.

generate_assignment -> student submissions -> grade_course with nbgrader's autograde (its cells
run by the grader's worker, as `cobotlab grade` runs it), then the gradebook, feedback and
release are inspected. Runs in about a minute on 2 cores. The lab 0
adversarial corpus, graded in one batch, is in tests/test_corpus_batch_*.py.
"""

from __future__ import annotations

import html
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import course_kit as kit
import pytest

from autograder.pipeline.pipeline import grade_course
from autograder.secret import SECRET_ENV, load_secret

ASSIGNMENT = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    """A course with lab 0 generated (released) once; tests copy it."""
    return kit.released_course(tmp_path_factory.mktemp("course"), ASSIGNMENT)


def _fresh_course(released: Path, tmp_path: Path) -> Path:
    return kit.fresh_course(released, tmp_path)


def _solution_sources() -> dict[str, str]:
    return kit.solution_sources(ASSIGNMENT, FUNCTIONS)


def _submit(course: Path, student: str, replace=None, extra=None, mangle=False) -> None:
    kit.submit(course, ASSIGNMENT, student, replace=replace, extra=extra, mangle=mangle)


_read_grades = kit.read_grades
_nbgrader = kit.nbgrader


# --------------------------------------------------------------------------- notebooks


def test_source_notebook_runs_with_solutions_and_hidden_tests():
    nb = kit.execute_source(ASSIGNMENT, timeout_s=60)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)


def test_release_has_no_solution_hidden_tests_or_secret(released):
    kit.assert_release_clean(released, ASSIGNMENT, len(FUNCTIONS), (
        "-R.T @ t",
        "out = out @ T",
        "np.sin(theta) * K",
    ))


# --------------------------------------------------------------------------- full cycle


def test_full_cycle_reference_blank_and_subtly_wrong(released, tmp_path):
    course = _fresh_course(released, tmp_path)
    solutions = _solution_sources()
    _submit(course, "ref", replace=solutions)
    _submit(course, "blank")
    wrong = {
        # forgets to rotate the translation: rotation right, translation wrong
        "invert_pose": solutions["invert_pose"].replace("-R.T @ t", "-t"),
        # multiplies in the wrong order: right only for one-pose chains
        "compose_chain": solutions["compose_chain"].replace("out @ T", "T @ out"),
        # no guard for the zero rotation vector: 0/0 on that problem only
        "pose_from_rotvec": solutions["pose_from_rotvec"].replace("theta > 1e-12", "True"),
    }
    _submit(course, "wrong", replace=wrong)
    # `cobotlab grade`'s way: nbgrader's autograde with its cells run by the grader's worker,
    # so the cross-check below compares the grader with the hidden tests' own verdicts. A
    # separate `nbgrader autograde` first (its own kernel: a second run of every notebook,
    # about 6 s of CPU here) met the same hidden-test cells; that nbgrader's own kernel
    # scores them alike is test_nbgrader_in_worker's, and that its results in the gradebook
    # raise no flag on an honest notebook test_grading_record's.
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    assert [r["student_id"] for r in rows] == ["blank", "ref", "wrong"]
    grades = _read_grades(course)
    assert list(next(iter(grades.values())).keys())[:11] == [
        "assignment", "duedate", "timestamp", "student_id", "last_name", "first_name", "email",
        "raw_score", "late_submission_penalty", "score", "max_score"]
    assert float(grades["ref"]["score"]) == 10.0 and float(grades["ref"]["max_score"]) == 10.0
    assert float(grades["blank"]["score"]) == 0.0
    # 1.5 (rotation of the inverse) + 0 (right only on the one-pose chains, edge cases that
    # count only when a longer chain is right too) + 3.5 (21 of 24 rotvecs: 3 are zero
    # rotations)
    assert float(grades["wrong"]["score"]) == pytest.approx(5.0)
    assert all(grades[s]["flags"] == "" for s in grades), grades
    assert grades["ref"]["timestamp"]

    feedback = (course / "feedback_cobotlab" / "wrong" / ASSIGNMENT / "feedback.html").read_text()
    # -t for the translation is one of the spec's code mistakes: the page names it
    assert "classic mistake: its translation is -t, not -R^T t" in feedback
    assert " mm" in feedback and " deg" in feedback
    secret = load_secret(course)
    for path in (course / "feedback_cobotlab").rglob("*.html"):
        text = path.read_text()
        assert "hidden_test" not in text and "HIDDEN" not in text and secret not in text
    assert secret not in (course / "grades.csv").read_text()


# --------------------------------------------------------------------------- feedback


def test_feedback_reaches_the_student_through_the_exchange(released, tmp_path):
    """The term's last step as nbgrader runs it: a student fetches and submits through the
    exchange, the instructor collects and runs `cobotlab grade`, then nbgrader's
    generate_feedback and release_feedback; the student's fetch_feedback brings back
    nbgrader's page with cobotlab's feedback on top, and nothing that is not theirs."""
    course = _fresh_course(released, tmp_path)
    exchange = course / "exchange"
    instructor, student = tmp_path / "instructor", tmp_path / "student"
    work = student / "work"
    for folder in (instructor, work, student / ".jupyter"):
        folder.mkdir(parents=True)
    # the student's own config names the course's exchange, as on a hub
    (student / ".jupyter" / "nbgrader_config.py").write_text(
        f"c = get_config()  # noqa: F821\nc.Exchange.root = {str(exchange)!r}\n"
        "c.CourseDirectory.course_id = 'cobotlab'\n")
    _nbgrader(course, "release_assignment", ASSIGNMENT, home=instructor)
    _nbgrader(work, "fetch_assignment", ASSIGNMENT, home=student)

    # a classic mistake (-t for the inverse's translation), and a cell the grader flags
    fetched = work / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    nb = json.loads(fetched.read_text())
    solutions = _solution_sources()
    answers = dict(solutions, invert_pose=solutions["invert_pose"].replace("-R.T @ t", "-t"))
    for cell in nb["cells"]:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if gid in answers:
            cell["source"] = answers[gid]
    nb["cells"].append({"cell_type": "code", "metadata": {}, "execution_count": None,
                        "outputs": [], "source": "import os\nwhere = os.environ.get('HOME')"})
    fetched.write_text(json.dumps(nb))
    _nbgrader(work, "submit", ASSIGNMENT, home=student)
    _nbgrader(course, "collect", ASSIGNMENT, home=instructor)
    [sid] = [p.name for p in (course / "submitted").iterdir()]

    env = {k: v for k, v in os.environ.items() if k != SECRET_ENV}
    env["HOME"] = str(instructor)
    done = subprocess.run([sys.executable, "-m", "cobotlab.cli", "grade", str(course),
                           ASSIGNMENT, "--no-template"], env=env, capture_output=True,
                          text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    row = _read_grades(course)[sid]
    assert float(row["score"]) == 8.5   # 1.5 of invert_pose's 3 points: its rotation only
    assert "suspicious_secret_probe" in row["flags"].split(";")

    _nbgrader(course, "generate_feedback", ASSIGNMENT, home=instructor)
    _nbgrader(course, "release_feedback", ASSIGNMENT, home=instructor)
    _nbgrader(work, "fetch_feedback", ASSIGNMENT, home=student)
    [page] = (work / ASSIGNMENT / "feedback").glob(f"*/{ASSIGNMENT}.html")
    raw = html.unescape(page.read_text())
    text = html.unescape(re.sub(r"<[^>]+>", "", page.read_text()))   # as the browser shows it
    # cobotlab's own feedback, on top of nbgrader's page
    assert "Score: 8.5 / 10<" in raw   # cobotlab's; nbgrader's heading says "8.5 / 10.0)"
    assert "classic mistake: its translation is -t, not -R^T t" in text
    assert text.index("classic mistake") < text.index("def invert_pose")
    # nothing the student must not see: flags, the cross-check, hidden tests, secrets
    submission_secret = (course / "submitted" / sid / ASSIGNMENT / "submission_secret.txt")
    for needle in ("suspicious_", "Flags", "nbgrader's own", "cross-check", "BEGIN HIDDEN",
                   "hidden_test(", load_secret(course), submission_secret.read_text()):
        assert needle not in text and needle not in raw, needle
