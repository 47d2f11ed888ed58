"""The home side of shard jobs: their problems drawn here, their executions scored here.

A class past one machine is graded in shards, each job on its own copy of the course
(docs/instructors.md), and no job holds the grading secret (:mod:`autograder.shard_job`
says how a job runs without it):

- :func:`write_job` draws the hidden problems of the job's students from HOME's secret and
  writes their inputs, never a truth or a tolerance, into the job's copy;
- the job executes (``cobotlab grade JOB ASSIGNMENT --students @FILE``) and keeps what
  each student's code did, as a grade run keeps it for ``--rescore``;
- :func:`merge_shard` (``cobotlab merge``) brings those executions home and rescores them
  here: the problems drawn again from the secret, each execution checked to be the
  submission HOME holds, run on the inputs HOME drew, with one outcome per problem, then
  scored and recorded by ``grade_course(..., rescore=True)``.

A job's files are data. Nothing it returns sets a score: its grades.csv, gradebook and
feedback pages are never read, and a returned value earns what it earns against the truth
drawn here. A returned execution that fails a check refuses the whole merge, naming each,
and nothing is written. What is copied besides: the autograded notebooks of nbgrader's run
(for formgrader), read without following links; the files nbgrader's release_feedback
reads beside them come from HOME's own submission.
"""

from __future__ import annotations

import fnmatch
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from autograder import executions, freeze, gradebook, record, safe_files
from autograder.feedback_release import write_exchange_files
from autograder.freeze import freeze_course
from autograder.pipeline.begin import GradeRun, course_and_secret, private_dir
from autograder.pipeline.draw import draw
from autograder.pipeline.execute import Executed, submission_digest
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import KernelTrials, draw_problems
from autograder.pipeline.rescore import kept_bytes, kept_path, use_kept
from autograder.pipeline.worker import Limits
from autograder.secret import PRIVATE_DIR, SECRET_FILE
from autograder.shard_job import FORMAT, bundle_path

__all__ = ["write_job", "merge_shard"]

_CAP_BYTES = 64 * 2**20  # one autograded notebook, or one kept execution


def _submitted_ids(home: Path, assignment: str) -> list[str]:
    """The ids of HOME's submitted folders of ``assignment`` that are safe folder names."""
    try:
        with safe_files.open_folder(home, "submitted") as top:
            names = sorted(e.name for e in top.entries())
    except safe_files.Refused as exc:
        raise ValueError(f"no submissions to write problems for: {exc}") from None
    return [n for n in names if freeze.student_id_problem(n) is None
            and (home / "submitted" / n / assignment).is_dir()]


def write_job(home, assignment: str, job, students=None) -> list[str]:
    """At home: write the inputs of the hidden problems of ``assignment`` of each of
    ``students`` (default: every student with a submission in HOME) into the job's copy of
    the course at ``job``: the course's fixed problems, drawn from HOME's secret, as
    :func:`autograder.executions.problems_to_wire` carries them to a Dask worker. Returns
    the student ids written.

    Refuses (ValueError) a job folder that is the course itself or that holds the secret,
    and a student id that is no safe folder name."""
    home, job = Path(home).resolve(), Path(job).resolve()
    if home == job:
        raise ValueError("the job folder is the course itself: pass the job's copy of it")
    root, secret = course_and_secret(home, assignment)
    students = list(dict.fromkeys(_submitted_ids(root, assignment) if students is None
                                  else students))
    if not students:
        raise ValueError(f"students: none to write problems of {assignment} for: collect the "
                         "submissions first, or name the shard's students")
    for sid in students:
        problem = freeze.student_id_problem(sid)
        if problem:
            raise ValueError(f"students: {freeze.printable(sid, 80)!r} is {problem}")
    held = job / PRIVATE_DIR / SECRET_FILE
    if os.path.lexists(held):   # the job's copy must not carry the secret out
        raise ValueError(f"the job's copy holds the grading secret ({held}): delete it; a "
                         "shard job needs none")
    kernel = KernelTrials(assignment)
    for sid in students:
        problems = draw_problems(assignment, sid, secret, None, kernel)
        data = {"format": FORMAT, "assignment": assignment, "student_id": sid,
                "nonce": None, "problems": executions.problems_to_wire(problems)}
        record.write_file(job / PRIVATE_DIR, bundle_path(assignment, sid),
                          json.dumps(data).encode("utf-8"))
    return students


def _copy_autograded(home: Path, shard: Path, assignment: str, sub: freeze.Frozen,
                     notes: list[str]) -> None:
    """The student's autograded notebooks from the job (for formgrader; data, regular files
    only), and beside them the exchange files from HOME's own frozen submission."""
    relative = f"autograded/{sub.student_id}/{assignment}"
    try:
        base = safe_files.open_folder(shard, relative)
    except safe_files.Refused as exc:
        if exc.why is not safe_files.Why.MISSING:
            notes.append(f"{sub.student_id}: {relative} not copied: {freeze.printable(exc)}")
        return
    copied = 0
    with base:
        for entry in base.entries():
            if not fnmatch.fnmatchcase(entry.name, "*.ipynb"):
                continue
            try:
                record.write_file(home, f"{relative}/{entry.name}",
                                  base.read(entry.name, _CAP_BYTES))
                copied += 1
            except (OSError, ValueError) as exc:   # safe_files.Refused is a ValueError
                notes.append(f"{sub.student_id}: {freeze.printable(entry.name)} not copied: "
                             f"{freeze.printable(exc)}")
    if copied:   # what nbgrader's release_feedback reads beside them
        write_exchange_files(home, assignment, sub)


def _returned(run: GradeRun, problems, shard: Path, frozen) -> tuple[dict, list, list]:
    """({student: the kept form, rebuilt here, of the job's execution}, [student: why
    refused], [students the job has problems of but no execution]) of HOME's submissions
    whose student the job was given problems of or kept an execution of."""
    private, assignment = shard / PRIVATE_DIR, run.assignment
    clean, refused, missing = {}, [], []
    for sub in frozen:
        sid = sub.student_id
        try:
            data = safe_files.read_file(private, kept_path(assignment, sid), _CAP_BYTES)
        except safe_files.Refused as exc:
            if exc.why is not safe_files.Why.MISSING:
                refused.append(f"{freeze.printable(sid, 80)} ({freeze.printable(exc, 200)})")
            elif os.path.lexists(private / bundle_path(assignment, sid)):
                missing.append(sid)
            continue
        if not (sub.accepted and sub.notebooks):
            refused.append(f"{freeze.printable(sid, 80)} (an execution of a submission HOME "
                           "refused or holds no notebook of)")
            continue
        done = Executed(submission=submission_digest(sub))
        why = use_kept(run, problems, sub, done, data, from_job=True)
        if why:
            refused.append(f"{freeze.printable(sid, 80)} ({why})")
        else:
            clean[sid] = kept_bytes(run, done)
    return clean, refused, missing


def merge_shard(course_dir, assignment: str, shard_dir, quiet: bool = False) -> list[dict]:
    """Score at home what one shard job executed of ``assignment`` (see the module
    docstring) and record it in ``course_dir`` as ``cobotlab grade --rescore`` does:
    gradebook.db (backed up first, checked after), grades.csv, the feedback pages, the
    kept executions. The assignment must be in HOME's gradebook (``nbgrader
    generate_assignment``), and HOME must hold the submissions the job executed.

    Returns the rows written to ``course_dir/grades.csv``, one per merged student. Raises
    ValueError, naming each, when any returned execution fails its checks (nothing is
    written then)."""
    home, shard = Path(course_dir).resolve(), Path(shard_dir).resolve()
    if home == shard:
        raise ValueError("the shard is the course itself: pass the job's copy of the course")
    root, secret = course_and_secret(home, assignment)
    gradebook.require_assignment(root, assignment)
    run = GradeRun(root, root / PRIVATE_DIR, assignment, secret, None, "merge",
                   Limits(), [], time.monotonic())
    notes: list[str] = []
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        frozen = freeze_course(root, assignment, Path(store), freeze.Caps())
        problems = draw(run, frozen)
        clean, refused, missing = _returned(run, problems, shard, frozen)
        if refused:
            raise ValueError(
                f"the shard {shard} returned executions this course cannot score, and nothing "
                "was merged: " + "; ".join(refused[:20])
                + (f"; and {len(refused) - 20} more" if len(refused) > 20 else "")
                + ". Run the job again on its students' current submissions")
        usable = {s.student_id for s in frozen if s.accepted and s.notebooks}
        zero = [sid for sid in missing if sid not in usable]   # scored zero, no code to run
        failed = [sid for sid in missing if sid in usable]
        if not clean and not zero:
            raise ValueError(f"the shard {shard} holds no execution of {assignment} of a "
                             "submission of this course: run the job first (cobotlab grade "
                             "JOB ASSIGNMENT --students @FILE)")
        private = private_dir(root)
        for sid, data in clean.items():
            record.write_file(private, kept_path(assignment, sid), data)
        rows = grade_course(root, assignment, students=[*clean, *zero], rescore=True,
                            quiet=True)
        for sub in frozen:
            if sub.student_id in clean:
                _copy_autograded(root, shard, assignment, sub, notes)
    if failed:
        notes.insert(0, "not merged, the job executed no code of theirs (a grader failure?): "
                        + ", ".join(freeze.printable(f, 80) for f in failed)
                        + ": grade them again")
    if not quiet:
        print(f"{assignment}: scored {len(rows)} student(s) of the shard {shard} in {home} "
              "(no student code ran here)")
        for note in notes:
            print(f"  note: {freeze.printable(note)}")
    return rows


def main(argv=None) -> int:
    """``python -m autograder.shards job HOME ASSIGNMENT JOB [STUDENT ...]``: write a
    shard job's problems (:func:`write_job`) before the job runs."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m autograder.shards",
        description="Write the inputs of a shard job's hidden problems into its copy of the "
                    "course (drawn here from the grading secret, which the job never gets).")
    sub = parser.add_subparsers(dest="command", required=True)
    job = sub.add_parser("job", help="write a job's problems into its copy of the course")
    job.add_argument("home", metavar="HOME", help="the home course (holds the secret)")
    job.add_argument("assignment", metavar="ASSIGNMENT")
    job.add_argument("job", metavar="JOB", help="the job's copy of the course")
    job.add_argument("students", metavar="STUDENT", nargs="*",
                     help="the job's students (default: everyone who submitted)")
    args = parser.parse_args(argv)
    try:
        written = write_job(args.home, args.assignment, args.job, args.students or None)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.assignment}: the problems of {len(written)} student(s) written into "
          f"{Path(args.job).resolve() / PRIVATE_DIR / 'job'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
