"""`cobotlab grade --rescore` (issue 39, item 5): after a change to a lab's tolerance, every
submission is scored again from what its code did in the last grade run, without running
any student code, and recorded as a grade run records it; a change to the problems'
inputs, or a submission handed in again, is refused by name.

One course with an instructor's own lab (the `labs new` skeleton, whose private spec an
author edits), graded for real once (sandbox, nbgrader's converter); the rescores run with
every way of starting student code made to fail the test.
"""

from __future__ import annotations

import json

import course_kit as kit
import numpy as np
import pytest

from autograder import checks, registry, sandbox, scratch, template
from autograder.course import init_course
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import draw_problems
from autograder.pipeline.worker import Worker
from autograder.secret import load_secret
from cobotlab.authoring import new_lab
from cobotlab.cli import main

LAB = "gauge"
BIAS_M = 0.0005   # added to each axis of the mean: within some problems' tolerance, not all


@pytest.fixture(autouse=True)
def _no_course_left():
    yield
    registry.use_course(None)


def _reference(measured, commanded):
    return np.mean(np.asarray(measured, float) - np.asarray(commanded, float), axis=0)


def _biased(measured, commanded):
    return _reference(measured, commanded) + BIAS_M


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """A course whose class (the reference, a biased mean, a blank) was graded once."""
    course = tmp_path_factory.mktemp("rescore") / "course"
    new_lab(LAB, course)
    init_course(course)
    kit.nbgrader(course, "generate_assignment", LAB)
    source = (course / "source" / LAB / f"{LAB}.ipynb").read_text()
    solution = "return np.mean(measured - commanded, axis=0)"
    assert source.count(solution) == 1
    biased = source.replace(solution, f"{solution} + {BIAS_M}")
    released = (course / "release" / LAB / f"{LAB}.ipynb").read_text()
    for student, text in (("ref", source), ("biased", biased), ("blank", released)):
        folder = course / "submitted" / student / LAB
        folder.mkdir(parents=True)
        (folder / f"{LAB}.ipynb").write_text(text)
        (folder / "timestamp.txt").write_text("2026-11-20 10:00:00.000000 UTC")
    rows = grade_course(course, LAB, quiet=True, run_nbgrader=True)
    yield course, {r["student_id"]: r for r in rows}
    registry.use_course(None)


def _no_student_code(monkeypatch) -> None:
    """Every way the grader starts student code (a worker, a template, nbgrader's run, a
    sandboxed command) fails the test."""
    def refuse(*args, **kwargs):
        raise AssertionError("a rescore started student code")

    monkeypatch.setattr(Worker, "__init__", refuse)
    monkeypatch.setattr(template.Template, "__init__", refuse)
    monkeypatch.setattr(scratch, "autograde_in_worker", refuse)
    monkeypatch.setattr(scratch, "autograde_one", refuse)
    monkeypatch.setattr(sandbox, "command", refuse)


def _edit_spec(course, old: str, new: str) -> str:
    path = course / ".cobotlab" / "specs" / f"{LAB}.py"
    before = path.read_text()
    assert before.count(old) == 1
    path.write_text(before.replace(old, new))
    registry.use_course(None)   # the next use loads the edited spec
    registry.use_course(course)
    return before


def _expected_points(course, student: str, student_fn) -> float:
    """The points ``student_fn`` earns on ``student``'s problems under the spec as the
    course has it now, scored here (no sandbox) by the grader's scoring function."""
    registry.use_course(course)
    problems = draw_problems(LAB, student, load_secret(course), None)
    (spec,) = checks.SPECS[LAB]
    trials = problems.trials[spec.name]
    outcomes = [checks.TrialOutcome(value=student_fn(*t.args)) for t in trials]
    return checks.score_function(spec, trials, outcomes).points


def test_a_tighter_tolerance_rescores_without_running_student_code(graded, monkeypatch):
    course, first = graded
    assert float(first["ref"]["score"]) == 2.0 and float(first["blank"]["score"]) == 0.0
    before_biased = float(first["biased"]["score"])
    assert before_biased == _expected_points(course, "biased", _biased) and 0 < before_biased
    # a tolerance of 2 sigma / sqrt(N): the biased mean loses more problems, and even the
    # reference loses some (P(chi_3 > 2) = 0.26)
    spec_text = _edit_spec(course, "tol_mm = 6.0 * sigma", "tol_mm = 2.0 * sigma")
    try:
        _no_student_code(monkeypatch)
        rows = {r["student_id"]: r for r in grade_course(course, LAB, quiet=True,
                                                           rescore=True)}
        after_biased = _expected_points(course, "biased", _biased)
        assert float(rows["biased"]["score"]) == after_biased < before_biased
        assert float(rows["ref"]["score"]) == _expected_points(course, "ref", _reference)
        assert float(rows["blank"]["score"]) == 0.0
        # recorded as a grade run records: grades.csv, the gradebook's cell, the feedback
        assert float(kit.read_grades(course)["biased"]["score"]) == after_biased
        from nbgrader.api import Gradebook

        with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
            cells = {g.name: g.auto_score for nb in gb.find_submission(LAB, "biased").notebooks
                     for g in nb.grades}
        assert after_biased in cells.values(), cells
        page = (course / "feedback_cobotlab" / "biased" / LAB / "feedback.html").read_text()
        assert f"{after_biased:g} / 2" in page
        runs = (course / ".cobotlab" / "runs.jsonl").read_text().splitlines()
        assert json.loads(runs[-1])["problems"] == "rescore"
    finally:
        (course / ".cobotlab" / "specs" / f"{LAB}.py").write_text(spec_text)
        registry.use_course(None)


def test_a_change_of_the_problems_inputs_is_refused_by_function(graded, monkeypatch, capsys):
    course, _ = graded
    spec_text = _edit_spec(course, "n = int(rng.integers(5, 41))", "n = int(rng.integers(6, 41))")
    try:
        _no_student_code(monkeypatch)
        before = (course / "grades.csv").read_bytes()
        assert main(["grade", str(course), LAB, "--rescore", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "altered the problems' inputs of mean_offset" in err and "biased" in err
        assert (course / "grades.csv").read_bytes() == before
    finally:
        (course / ".cobotlab" / "specs" / f"{LAB}.py").write_text(spec_text)
        registry.use_course(None)


def test_a_submission_handed_in_again_is_refused_by_name(graded, monkeypatch, capsys):
    course, _ = graded
    registry.use_course(course)
    notebook = course / "submitted" / "biased" / LAB / f"{LAB}.ipynb"
    text = notebook.read_text()
    notebook.write_text(text.replace(f" + {BIAS_M}", ""))
    try:
        _no_student_code(monkeypatch)
        assert main(["grade", str(course), LAB, "--rescore", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "biased (submitted again since it was graded)" in err
        assert "ref (" not in err and "blank (" not in err
    finally:
        notebook.write_text(text)


def test_an_execution_kept_by_an_older_cobotlab_is_refused_naming_the_fix(graded, monkeypatch,
                                                                          capsys):
    """Format 1 wrote a failure's place into its message's words: rescoring it would write
    the place in twice, and its words are not parsed back, so it is refused by name with
    what grades it again (running the student code), and nothing is recorded."""
    from autograder.pipeline.rescore import kept_path

    course, _ = graded
    registry.use_course(course)
    kept = course / ".cobotlab" / kept_path(LAB, "biased")
    text = kept.read_text()
    data = json.loads(text)
    data["format"] = data["execution"]["format"] = 1
    kept.write_text(json.dumps(data))
    try:
        _no_student_code(monkeypatch)
        before = (course / "grades.csv").read_bytes()
        assert main(["grade", str(course), LAB, "--rescore", "--no-progress"]) == 2
        err = " ".join(capsys.readouterr().err.split())
        assert "biased (an execution kept in format 1, not 2 (by an older cobotlab" in err
        assert "run the student code again with this cobotlab: `cobotlab grade` without " \
               "--rescore" in err
        assert "ref (" not in err and "blank (" not in err
        assert (course / "grades.csv").read_bytes() == before
    finally:
        kept.write_text(text)
