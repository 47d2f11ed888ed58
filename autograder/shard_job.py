"""A shard job holds no secret: its problems are drawn at home, it only executes.

A class past one machine is graded in shards, each a job on its own copy of the course
(docs/instructors.md). The hidden problems come from the grading secret, which must stay
on the instructor's machine: a job node where a sandbox was escaped could otherwise draw
every student's problems, truth included, and forge any score. So, as the Dask path does
(:mod:`autograder.cluster`), the job gets the inputs of its students' problems and never
the secret, a truth or a tolerance:

1. at home, :func:`autograder.shards.write_job` draws each of the shard's students' problems (the course's
   fixed ones) and writes their inputs (:func:`autograder.executions.problems_to_wire`)
   into the job's copy, ``.cobotlab/job/<assignment>/<key>.json``;
2. in the job, ``cobotlab grade JOB ASSIGNMENT --students @FILE`` finds that folder and
   runs only freeze and execute (:class:`BundledProblems` stands in for the drawing), keeps
   each execution as a grade run does, and scores and records nothing; it refuses to run
   where a secret is within reach (:func:`refuse_secret`);
3. at home, ``cobotlab merge`` (:mod:`autograder.shards`) takes the returned executions as
   data and rescores them against the truth drawn again from the secret.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from autograder import executions, safe_files
from autograder.freeze import printable
from autograder.pipeline.problems import KernelTrials, Problems
from autograder.secret import PRIVATE_DIR, SECRET_ENV, SECRET_FILE

__all__ = ["JOB_DIR", "FORMAT", "bundle_path", "is_job", "refuse_secret", "BundledProblems"]

JOB_DIR = "job"   # below the course's private folder (PRIVATE_DIR)
FORMAT = 1
_CAP_BYTES = 256 * 2**20   # one student's problems' inputs (a lab of images is large)


def bundle_path(assignment: str, student_id: str) -> str:
    """Where, below a job's private folder, a student's problems' inputs are."""
    return f"{JOB_DIR}/{assignment}/{executions.file_key(student_id)}.json"


def is_job(root: Path, assignment: str) -> bool:
    """Whether the course at ``root`` is a shard job's copy for ``assignment`` (it holds
    problems written by :func:`autograder.shards.write_job`)."""
    return os.path.lexists(Path(root) / PRIVATE_DIR / JOB_DIR / assignment)


def refuse_secret(root: Path) -> None:
    """ValueError when a grading secret is within the job's reach: a job needs none, and
    one on a job node is one an escaped sandbox could read."""
    where = [f"${SECRET_ENV}"] if os.environ.get(SECRET_ENV, "").strip() \
        else []
    if os.path.lexists(Path(root) / PRIVATE_DIR / SECRET_FILE):
        where.append(str(Path(root) / PRIVATE_DIR / SECRET_FILE))
    if where:
        raise ValueError(
            f"this course is a shard job's copy (it holds {PRIVATE_DIR}/{JOB_DIR}/), "
            f"and a grading secret is within its reach ({' and '.join(where)}): a shard job "
            "needs none and must not hold one. Remove it from the job and run again; the "
            "home course scores what the job returns (`cobotlab merge`)")


class BundledProblems:
    """In the job: each student's problems as home wrote them (inputs only, no truth to
    score with, no tolerance), which the draw stage reads, every student's before any code
    runs, into a :class:`autograder.pipeline.problems.DrawnProblems` as it would have drawn them."""

    def __init__(self, root: Path, assignment: str):
        self.root, self.assignment = Path(root), assignment
        self.kernel = KernelTrials(assignment)

    def missing(self, student_ids) -> list[str]:
        """The students of ``student_ids`` whose problems home did not write."""
        folder = self.root / PRIVATE_DIR
        return [sid for sid in student_ids
                if not os.path.lexists(folder / bundle_path(self.assignment, sid))]

    def of(self, student_id: str) -> Problems:
        """The student's problems' inputs; ValueError when they are missing or malformed."""
        try:
            data = json.loads(safe_files.read_file(
                self.root / PRIVATE_DIR, bundle_path(self.assignment, student_id),
                _CAP_BYTES))
        except (ValueError, UnicodeDecodeError) as exc:   # safe_files.Refused too
            raise ValueError(f"the problems home wrote for {printable(student_id, 80)}: "
                             f"{printable(exc, 200)}") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT \
                or data.get("nonce") is not None:
            raise ValueError(f"the problems home wrote for {printable(student_id, 80)} are "
                             "of another format: write them again with this cobotlab")
        problems = executions.problems_from_wire(data.get("problems"), self.assignment,
                                                 student_id)
        return dataclasses.replace(problems, kernel=self.kernel)
