"""Stage 3 of the grader's line, draw: every usable submission's hidden problems, all of
them before any code runs (:func:`draw`), from the secret, or, in a shard job, the inputs
home wrote for it (:mod:`autograder.shard_job`)."""

from __future__ import annotations

from autograder import shard_job
from autograder.freeze import printable
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.problems import DrawnProblems, draw_all


def draw(run: GradeRun, frozen) -> DrawnProblems:
    """Every usable submission's hidden problems, all of them now, before any code runs:
    drawn from the secret here, or, in a shard job, the inputs home wrote for each (refused,
    naming them, when some are missing)."""
    usable = [s.student_id for s in frozen if s.accepted and s.notebooks]
    if run.problems != "job":
        return draw_all(run.assignment, run.secret, run.nonce, usable)
    problems = shard_job.BundledProblems(run.root, run.assignment)
    missing = problems.missing(usable)
    if missing:
        raise ValueError(
            f"this shard job holds no problems of {run.assignment} for "
            f"{', '.join(printable(m, 80) for m in missing[:20])}: write them at home "
            "(`cobotlab shard HOME ASSIGNMENT JOB STUDENT...`), or "
            "leave them out of --students")
    return DrawnProblems(run.assignment, {sid: problems.of(sid) for sid in usable},
                                 problems.kernel)
