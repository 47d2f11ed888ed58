"""Stage 5 of the grader's line, score: a pure function of the problems and the execution.

:func:`score_execution` scores an :class:`~autograder.pipeline.execution.Execution` against
the truth drawn here (:mod:`autograder.checks` on the lab's spec): no I/O, no student code.
:func:`score_submission` is the stage: a submission's :class:`SubmissionGrade` with the
freeze's, nbgrader's and the time-outs' flags and notes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from autograder import (
    checks,
    freeze,
)
from autograder.outcomes import Flag
from autograder.pipeline.cells import CellOrigin
from autograder.pipeline.execution import CellRun, Execution
from autograder.pipeline.problems import Problems, specs_of

if TYPE_CHECKING:   # the stages before; importing them would go round in a circle
    from autograder.pipeline.begin import GradeRun
    from autograder.pipeline.execute import Executed
    from autograder.pipeline.nbgrader_results import NbgraderCells


@dataclass
class SubmissionGrade:
    """One student's result: per-function scores, tamper flags, and notes for the instructor."""

    student_id: str
    assignment: str
    functions: list[checks.FunctionResult] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    # Where each code cell the worker ran (a Place's ``cell``: its index here) sits in the
    # notebook, so feedback can number cells as the student sees them.
    cell_origins: list[CellOrigin] = field(default_factory=list)
    # With ``run_tests``: what each cell did on the first load (nbgrader's view of the run),
    # and the verdict of each function's in-notebook hidden test (None: passed).
    cell_runs: list[CellRun] = field(default_factory=list)
    kernel_checks: dict[str, str | None] = field(default_factory=dict)
    # False when the grader itself failed on every attempt: no score is recorded (not 0),
    # the row says ``grader_error``, and the next run grades the submission again.
    graded: bool = True
    # Where the wall clock went (s): until the worker was ready (sandbox, interpreter,
    # imports; or the fork of a template), the template's shared cells (run once for the
    # class, not for this submission), the submission's own cells, the hidden problems and
    # tests; and the peak memory of its cgroup (MB; None without one).
    profile: dict = field(default_factory=lambda: {
        "start_s": 0.0, "shared_s": 0.0, "cells_s": 0.0, "hidden_s": 0.0, "peak_mb": None})

    @property
    def score(self) -> float:
        return round(sum(f.points for f in self.functions), 2)

    @property
    def max_score(self) -> float:
        return round(sum(f.max_points for f in self.functions), 2)


def score_execution(problems: Problems, execution: Execution) -> SubmissionGrade:
    """The grade of one submission: a pure function of its problems and of what its code
    did on them (no sandbox, no I/O, no student code). A function that reached a forbidden
    routine scores zero, flagged ``forbidden:<routine>``; each ``hidden_test(f)`` of the
    test cells gets its verdict in ``kernel_checks`` (None: passed), scored as the in-kernel
    hidden test scores it (:data:`checks.KERNEL_SEEDS`) but here."""
    specs = {s.name: s for s in specs_of(problems.assignment)}
    grade = SubmissionGrade(student_id=execution.student_id, assignment=execution.assignment,
                            notes=list(execution.notes), seconds=execution.seconds,
                            cell_origins=list(execution.cell_origins),
                            cell_runs=list(execution.cell_runs),
                            profile=dict(execution.profile))
    for run in execution.functions:
        spec = specs[run.name]
        grade.functions.append(
            checks.forbidden_result(spec, run.forbidden) if run.forbidden
            else checks.score_function(spec, problems.trials[run.name], run.outcomes))
    grade.flags = [*execution.suspicious, *(
        Flag("forbidden", name) for name in sorted({n for r in execution.functions
                                                    for n in r.forbidden})),
        *execution.sandbox_flags]
    grade.kernel_checks = kernel_verdicts(problems, execution)
    return grade


def kernel_verdicts(problems: Problems, execution: Execution) -> dict[str, str | None]:
    """The verdict of each ``hidden_test(f)`` of the test cells, in order (None: passed,
    else why not), scored as the in-kernel hidden test scores it but here."""
    specs = {s.name: s for s in specs_of(problems.assignment)}
    banned = {r.name: r.forbidden for r in execution.functions if r.forbidden}
    return {name: _kernel_verdict(name, specs, banned, problems, execution)
            for name in execution.kernel_tests}


def _kernel_verdict(name: str, specs: dict, banned: dict, problems: Problems,
                    execution: Execution) -> str | None:
    """The verdict of ``hidden_test(name)`` (None: passed, else why not)."""
    spec = specs.get(name)
    if spec is None:
        return f"no graded function is named {name!r}"
    if name in banned:
        return checks.forbidden_result(spec, banned[name]).summary()
    run = execution.kernel_runs[name]
    result = (checks.forbidden_result(spec, run.forbidden) if run.forbidden else
              checks.score_function(spec, problems.kernel_trials(name), run.outcomes))
    return None if result.fraction >= 1.0 else result.summary()


def score_submission(run: GradeRun, sub: freeze.Frozen, done: Executed) -> SubmissionGrade:
    """The grade of one submission from its execution (:func:`score_execution`),
    with the freeze's flags and notes first and nbgrader's, the time-outs' and the
    cross-check's with nbgrader's own cell results (``done.nbgrader_cells``) after; a
    refused submission, or one without a notebook, scores zero; one the grader failed on
    every time is not graded."""
    if not sub.accepted or not sub.notebooks:
        grade = _zero_grade(sub, run.assignment)
    elif done.execution is None:
        grade = _ungraded(sub, run.assignment, done.grader_errors)
    else:
        grade = score_execution(done.problems, done.execution)
        if done.grader_errors:
            grade.notes.append(f"graded after {len(done.grader_errors)} grader error(s), each "
                               f"retried in a fresh sandbox: {'; '.join(done.grader_errors)}")
    grade.flags[:0] = sub.flags
    grade.notes[:0] = sub.notes
    if sub.accepted and grade.graded:
        if done.nbgrader is not None:
            grade.notes += done.nbgrader.notes
            grade.flags += done.nbgrader.flags
        grade.flags += _timeout_flags(grade)
        if sub.notebooks and done.nbgrader_cells is not None:
            grade.flags += _cross_check(grade, done.nbgrader_cells)
    return grade


def _cross_check(grade: SubmissionGrade, nb: NbgraderCells) -> list[Flag]:
    """The flags of functions nbgrader's kernel passed but the independent grader failed,
    of its hidden-test cells missing, or of no nbgrader result at all."""
    if not nb.scores:
        return [Flag("nbgrader_no_result")]
    flags = []
    by_function = {f.name: f for f in grade.functions}
    for grade_id, function in nb.functions.items():
        if grade_id not in nb.scores:
            flags.append(Flag("nbgrader_missing_cell", function, function=function))
            continue
        score, max_score = nb.scores[grade_id]
        ours = by_function.get(function)
        if ours is not None and max_score > 0 and score >= max_score and ours.fraction < 0.5:
            flags.append(Flag("nbgrader_passed_but_grader_failed", function,
                              function=function))
    return flags


def _ungraded(sub: freeze.Frozen, assignment: str, errors: list[str]):
    grade = _zero_grade(sub, assignment, ["grader_error"], [
        f"not graded: the grader failed on each of {len(errors)} attempts ("
        + "; ".join(errors) + "); no score is recorded, and the next `cobotlab grade` of "
        "this assignment grades it again"])
    grade.graded = False
    return grade


def _zero_grade(sub: freeze.Frozen, assignment: str, flags=(), notes=()):
    grade = SubmissionGrade(sub.student_id, assignment, flags=list(flags),
                                    notes=list(notes))
    grade.functions = [checks.score_function(s, [], []) for s in checks.SPECS[assignment]]
    return grade


def _timeout_flags(grade: SubmissionGrade) -> list[str]:
    """``timed_out:<function>`` for each function that lost problems to a time limit (a hang
    would otherwise show only as failed checks)."""
    return [Flag("timed_out", f.name, function=f.name) for f in grade.functions
            if f.lost_to_time]
