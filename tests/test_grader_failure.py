"""The grader's own failure is never a student's score (issue 29, item 5).

The failure injected is the one met on machines where the sandbox cannot start the
interpreter: bubblewrap runs, but the worker's view lacks the Python it must exec
("bwrap: execvp ...: No such file or directory"). It is real bubblewrap failing, not a
mocked exception, so the path from the sandbox to the gradebook is the one a course meets.
"""

from __future__ import annotations

import threading

import course_kit as kit
import pytest
from nbgrader.api import Gradebook, MissingEntry

from autograder import checks, sandbox
from autograder.pipeline import execute, worker
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.run_submission import execute_notebook
from autograder.pipeline.worker import worker_jail
from cobotlab.cli import NOT_GRADED_EXIT, main

ASSIGNMENT = "lab0_frames"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600),
              pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="needs bubblewrap")]


@pytest.fixture(scope="module")
def released(tmp_path_factory):
    return kit.released_course(tmp_path_factory.mktemp("released"), ASSIGNMENT)


def _submit_class(course):
    solutions = kit.solution_sources(ASSIGNMENT, [s.name for s in checks.SPECS[ASSIGNMENT]])
    for student in ("ada", "broken", "cy"):   # ada is first: the run's first submission
        kit.submit(course, ASSIGNMENT, student, replace=solutions)
    kit.submit(course, ASSIGNMENT, "bo")


class BrokenSandbox:
    """worker_jail whose view lacks the interpreter for the chosen submissions: for
    ``first_start`` the first worker the run starts, for ``always`` every worker of theirs."""

    def __init__(self, monkeypatch, first_start: bool = False, always=()):
        self.real_jail, self.real_execute = worker_jail, execute_notebook
        self.first_start, self.always = first_start, set(always)
        self.lock, self.local, self.broken = threading.Lock(), threading.local(), []
        monkeypatch.setattr(worker, "worker_jail", self.jail)
        monkeypatch.setattr(execute, "execute_notebook", self.execute)

    def execute(self, paths, problems, *args, **kwargs):
        self.local.student = problems.student_id
        return self.real_execute(paths, problems, *args, **kwargs)

    def jail(self, limits):
        jail = self.real_jail(limits)
        student = getattr(self.local, "student", None)
        with self.lock:
            breaks = student in self.always or (self.first_start and not self.broken)
            if breaks:
                self.broken.append(student)
        if not breaks:
            return jail
        # No interpreter in the view: bubblewrap itself fails to exec it.
        return sandbox.Jail(ro=(), scratch_mb=jail.scratch_mb, chdir=jail.chdir,
                            env=jail.env)


def _cobotlab_cells(course, student):
    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        try:
            sub = gb.find_submission(ASSIGNMENT, student)
        except MissingEntry:
            return None
        return {g.name: g.auto_score for nb in sub.notebooks for g in nb.grades}


def test_the_probe_runs_once_under_threads_and_never_collides():
    sandbox.forget_capabilities()
    barrier, results = threading.Barrier(8), []

    def probe():
        barrier.wait()
        results.append(sandbox.capabilities())

    threads = [threading.Thread(target=probe) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len({id(r) for r in results}) == 1, "the probe ran more than once"
    assert not any("File exists" in e for e in results[0].evidence), results[0].evidence


def test_a_grader_failure_is_retried_and_never_scores(released, tmp_path, monkeypatch, capsys):
    course = kit.fresh_course(released, tmp_path)
    _submit_class(course)
    probes = []
    real_probe = sandbox._probe
    monkeypatch.setattr(sandbox, "_probe", lambda: probes.append(1) or real_probe())
    sandbox.forget_capabilities()
    fault = BrokenSandbox(monkeypatch, first_start=True, always={"broken"})
    # What a trusting `nbgrader autograde` left for a notebook built to fool its kernel:
    # full marks in every cell, which cobotlab never gave.
    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        gb.update_or_create_student("broken")
        for nb in gb.update_or_create_submission(ASSIGNMENT, "broken").notebooks:
            for g in nb.grades:
                g.auto_score, g.needs_manual_grade = g.max_score, False
        gb.db.commit()
    assert all(v for v in _cobotlab_cells(course, "broken").values())

    # Each worker a new interpreter in a new sandbox (a template's forks use no worker_jail:
    # its own failure is the next test's); through the command, whose exit status tells a
    # script that a submission is left ungraded
    status = main(["grade", str(course), ASSIGNMENT, "--workers", "2", "--no-template",
                   "--no-progress"])
    assert status == NOT_GRADED_EXIT == 3
    rows = kit.read_grades(course)
    out = capsys.readouterr().out
    assert len(probes) == 1, "the sandbox was probed more than once in one run"
    first = fault.broken[0]
    assert first in ("ada", "bo"), fault.broken   # one of the two submissions started first

    full = sum(s.points for s in checks.SPECS[ASSIGNMENT])
    # The first submission's sandbox failed once: retried in a fresh one, graded as usual.
    assert float(rows["ada"]["score"]) == full and float(rows["bo"]["score"]) == 0.0, rows
    assert float(rows["cy"]["score"]) == full
    assert not any("grader_error" in rows[s]["flags"] for s in ("ada", "bo", "cy")), rows
    # Failed on every attempt: no score anywhere (not 0), named in grades.csv and the summary.
    assert rows["broken"]["score"] == "" and rows["broken"]["raw_score"] == "", rows["broken"]
    assert "grader_error" in rows["broken"]["flags"].split(";")
    assert kit.read_grades(course)["broken"]["score"] == ""
    # ... and none in the gradebook either: nbgrader's export and formgrader show no score
    # cobotlab did not give, and formgrader asks for a look.
    assert set(_cobotlab_cells(course, "broken").values()) == {None}
    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        sub = gb.find_submission(ASSIGNMENT, "broken")
        assert sub.score == 0 and sub.needs_manual_grade
        assert all("not graded" in c.auto_comment for nb in sub.notebooks
                   for c in nb.comments)
    assert _cobotlab_cells(course, "ada") and all(
        v is not None for v in _cobotlab_cells(course, "ada").values())
    assert "NOT GRADED (1): broken" in out, out
    assert not (course / "feedback_cobotlab" / "broken").exists()
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert "broken" in log and "did not start" in log, log[-2000:]
    assert fault.broken.count("broken") == 2   # two attempts, each in a fresh sandbox

    # The next run, with the machine fixed, grades it like the others (only it: the others'
    # grades are the first run's, checked above; regrading them would prove nothing more).
    monkeypatch.setattr(worker, "worker_jail", fault.real_jail)
    rows = {r["student_id"]: r for r in grade_course(
        course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True, template=False,
        students=["broken"])}
    assert set(rows) == {"broken"}
    assert float(rows["broken"]["score"]) == full, rows["broken"]
    assert "grader_error" not in rows["broken"]["flags"]
    assert all(v is not None for v in _cobotlab_cells(course, "broken").values())


def test_a_template_that_cannot_start_costs_time_never_a_grade(released, tmp_path,
                                                              monkeypatch):
    course = kit.fresh_course(released, tmp_path)
    _submit_class(course)
    fault = BrokenSandbox(monkeypatch, first_start=True)   # the run's first sandbox: the template
    rows = {r["student_id"]: r for r in grade_course(
        course, ASSIGNMENT, workers=1, run_nbgrader=True, quiet=True)}
    assert fault.broken == [None], "the template, built before any submission, was the first"
    full = sum(s.points for s in checks.SPECS[ASSIGNMENT])
    assert {s: float(r["score"]) for s, r in rows.items()} == {
        "ada": full, "broken": full, "cy": full, "bo": 0.0}
    assert not any(r["flags"] for r in rows.values()), rows
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert "no template, every submission started cold: the template did not load" in log


def test_a_row_whose_isolation_differs_from_the_probe_says_so(released, tmp_path, monkeypatch):
    if not sandbox.capabilities().cgroup:
        pytest.skip("no writable cgroup here: nothing differs from the probe")
    course = kit.fresh_course(released, tmp_path)
    solutions = kit.solution_sources(ASSIGNMENT, [s.name for s in checks.SPECS[ASSIGNMENT]])
    kit.submit(course, ASSIGNMENT, "ada", replace=solutions)
    kit.submit(course, ASSIGNMENT, "cy", replace=solutions)
    real = sandbox.Cgroup.__init__
    calls = []

    def refuse_first(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise OSError(17, "File exists")
        real(self, *args, **kwargs)

    monkeypatch.setattr(sandbox.Cgroup, "__init__", refuse_first)
    rows = grade_course(course, ASSIGNMENT, workers=1, quiet=True)
    flagged = [r for r in rows if "sandbox:no_cgroup" in r["flags"].split(";")]
    assert len(flagged) == 1, rows
    full = sum(s.points for s in checks.SPECS[ASSIGNMENT])
    assert all(float(r["score"]) == full for r in rows)   # graded all the same
