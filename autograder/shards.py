"""Bring the grades of shard jobs (``cobotlab grade --students``) into the home course.

A class past one machine is graded in shards, each job on its own copy of the course
(docs/instructors.md). ``merge_shard(HOME, ASSIGNMENT, SHARD)`` takes one job's copy back:
its students' cell scores and comments into HOME's ``gradebook.db`` (through nbgrader's API,
so formgrader, manual overrides and ``nbgrader export`` see them as if HOME had graded),
their rows into HOME's ``grades.csv``, their feedback pages and autograded notebooks, and the
cross-check ledger, so the next regrade at home still compares with nbgrader's own values.

The shard's files are read as data, as a submission is (through
:mod:`autograder.safe_files`: regular files only, no link followed at any depth), student
ids that are safe folder names, scores that are numbers within their cell's points, and
only for students whose row the shard's ``grades.csv`` has. A row of a refused folder
(flagged ``rejected_student_id``, keyed by :func:`autograder.freeze.student_key`) is
carried over as a row only: it has nothing in the gradebook and no files.
HOME's gradebook is backed up first and checked after, as in ``grade_course``; a late
penalty is HOME's rule again.
"""

from __future__ import annotations

import csv
import fnmatch
import io
import json
import math
import tempfile
from pathlib import Path

from autograder import (
    checks,
    course,
    feedback_release,
    freeze,
    gradebook,
    grading,
    record,
    registry,
    safe_files,
)

__all__ = ["merge_shard"]

_CAP_BYTES = 64 * 2**20  # one feedback page or autograded notebook, or grades.csv
_GRADEBOOK_CAP = 4 * 2**30


def _read(shard: Path, relative: str, what: str) -> bytes:
    try:
        return safe_files.read_file(shard, relative, _CAP_BYTES)
    except safe_files.Refused as exc:
        raise ValueError(f"{what}: {exc}") from None


def _refused_row(row: dict) -> bool:
    """Whether a grades.csv row is a refused folder's (``rejected_student_id``): a row only,
    nothing in the gradebook, no feedback."""
    return "rejected_student_id" in row.get("flags", "").split(";")


def _shard_rows(shard: Path, assignment: str) -> list[dict]:
    text = _read(shard, course.GRADES_CSV, "the shard's grades").decode("utf-8")
    rows = [r for r in csv.DictReader(io.StringIO(text)) if r.get("assignment") == assignment]
    if not rows:
        raise ValueError(f"{shard / course.GRADES_CSV} has no row of {assignment!r}: grade the "
                         "shard first (cobotlab grade SHARD ASSIGNMENT --students @FILE)")
    max_points = sum(s.points for s in checks.SPECS[assignment])
    for row in rows:
        if row.get("raw_score") == "" and "grader_error" in row.get("flags", "").split(";"):
            continue   # the shard's grader failed on it: nothing to merge (see merge_shard)
        sid = row.get("student_id", "")
        problem = freeze.student_id_problem(sid)
        if _refused_row(row):
            # its key must be one no accepted id can be (freeze.student_key), so that it can
            # never stand in for a student's real row at home
            if problem is None or freeze.printable(sid, 10**6) != sid:
                raise ValueError(f"the shard's grades.csv flags {freeze.printable(sid, 80)!r} "
                                 "as a refused folder, but that is not how a refused folder "
                                 "is named there: was the file edited?")
        elif problem:
            raise ValueError(f"the shard's grades.csv names a student id that is {problem}: "
                             f"{freeze.printable(sid, 80)!r}")
        try:
            raw, top = float(row["raw_score"]), float(row["max_score"])
        except (KeyError, ValueError):
            raise ValueError(f"the shard's row of {sid} has no numeric raw_score / max_score") \
                from None
        if _refused_row(row) and raw != 0:
            raise ValueError(f"the shard's row of the refused folder {freeze.printable(sid, 80)!r}"
                             f" scores {raw:g}: a refused folder is never graded")
        if not (math.isfinite(raw) and abs(top - max_points) < 1e-9 and 0 <= raw <= top):
            raise ValueError(
                f"the shard's row of {sid} scores {raw:g} / {top:g}, but {assignment} is out of "
                f"{max_points:g} here: was the shard graded with another version of the lab?")
    return rows


def _shard_gradebook(shard: Path, assignment: str, students: list[str]) -> dict:
    """{student: (timestamp, {(notebook, grade id): (score, points)}, {comment: text})}
    from the shard's gradebook, scores checked against their cells' points."""
    with tempfile.TemporaryDirectory(prefix="cobotlab-shard-") as private:
        copy = Path(private) / "gradebook.db"   # nbgrader opens a path: a private copy's
        try:
            safe_files.copy_file(shard, "gradebook.db", copy, _GRADEBOOK_CAP)
        except safe_files.Refused as exc:
            raise ValueError(f"the shard's gradebook: {exc}") from None
        return gradebook.read_submissions(copy, shard / "gradebook.db", assignment, students)


def _copy_outputs(home: Path, shard: Path, assignment: str, sid: str, notes: list[str]) -> None:
    """The student's feedback page and section, autograded notebooks and the exchange files
    nbgrader's release_feedback reads beside them, regular files only."""
    exchange = freeze.EXCHANGE_FILES
    for folder, patterns in (("feedback_cobotlab", ("feedback.html", feedback_release.SECTION)),
                             ("autograded", ("*.ipynb", *exchange))):
        relative = f"{folder}/{sid}/{assignment}"
        try:
            base = safe_files.open_folder(shard, relative)
        except safe_files.Refused as exc:
            if exc.why is not safe_files.Why.MISSING:
                notes.append(f"{sid}: {relative} not copied: {freeze.printable(exc)}")
            continue
        with base:
            for entry in base.entries():
                if not any(fnmatch.fnmatchcase(entry.name, p) for p in patterns):
                    continue
                try:
                    data = base.read(entry.name, _CAP_BYTES)
                    problem = freeze.exchange_file_problem(entry.name, data) \
                        if entry.name in exchange else None
                    if problem:
                        raise ValueError(problem)
                    record.write_file(home, f"{relative}/{entry.name}", data)
                except (OSError, ValueError) as exc:   # safe_files.Refused is a ValueError
                    notes.append(f"{sid}: {folder}/{freeze.printable(entry.name)} not copied: "
                                 f"{freeze.printable(exc)}")


def _write(home, shard, private, assignment, students, cells, theirs, notes) -> None:
    """The shard's students into HOME: gradebook cells and comments, ledger, files."""
    ledger = course._load_ledger(private)
    mine = ledger.setdefault(assignment, {})
    for sid in students:
        timestamp, scores, comments = cells[sid]
        # nbgrader's cell results first (every cell, a notebook's missing ones at 0), then the
        # comments with cobotlab's findings: the same two writes `cobotlab grade` makes.
        gradebook.write_nbgrader_cells(
            home, assignment, sid, timestamp,
            [gradebook.CellScore(nb, gid, value, top)
             for (nb, gid), (value, top) in scores.items()],
            {nb for nb, _ in scores})
        gradebook.write_cobotlab(home, assignment, sid, timestamp, {}, comments)
        entry = theirs.get(sid)
        if isinstance(entry, dict) and isinstance(entry.get("cells"), dict):
            mine[sid] = {"timestamp": entry.get("timestamp"), "cells": entry["cells"]}
        else:
            mine.pop(sid, None)
        _copy_outputs(home, shard, assignment, sid, notes)
        _copy_kept_execution(shard, private, assignment, sid, notes)
    record.write_file(private, course._LEDGER, json.dumps(ledger).encode("utf-8"))


def _copy_kept_execution(shard: Path, private: Path, assignment: str, sid: str,
                         notes: list[str]) -> None:
    """What the student's code did in the shard's run, so that ``cobotlab grade --rescore``
    works at home (read without following links; checked again when it is used)."""
    relative = course.kept_path(assignment, sid)
    try:
        data = safe_files.read_file(shard / grading.PRIVATE_DIR, relative, _CAP_BYTES)
    except safe_files.Refused as exc:
        if exc.why is not safe_files.Why.MISSING:
            notes.append(f"{sid}: its kept execution not copied: {freeze.printable(exc)}")
        return
    record.write_file(private, relative, data)


def merge_shard(course_dir, assignment: str, shard_dir, quiet: bool = False) -> list[dict]:
    """Merge one shard job's grades of ``assignment`` into ``course_dir`` (see the module
    docstring). The students must be in HOME's gradebook's class or are added to it (their
    names stay HOME's); the assignment must exist there (``nbgrader generate_assignment``).

    Returns the rows written to ``course_dir/grades.csv`` (one per student of the shard).
    """
    home, shard = Path(course_dir).resolve(), Path(shard_dir).resolve()
    if home == shard:
        raise ValueError("the shard is the course itself: pass the job's copy of the course")
    registry.use_course(home)   # an instructor's lab is found in the home course's folders
    if assignment not in checks.SPECS:
        raise ValueError(f"no graded functions are registered for assignment {assignment!r}")
    rows = _shard_rows(shard, assignment)
    ungraded = [r["student_id"] for r in rows if r.get("raw_score") == ""]
    rows = [r for r in rows if r.get("raw_score") != ""]
    refused = [r for r in rows if _refused_row(r)]   # rows only: no gradebook entry, no files
    rows = [r for r in rows if not _refused_row(r)]
    if not rows and not refused:
        raise ValueError(f"the shard {shard} graded none of its students (grader errors: "
                         f"{', '.join(ungraded)}): grade the shard again")
    students = [r["student_id"] for r in rows]
    cells = _shard_gradebook(shard, assignment, students)
    theirs = course._load_ledger(shard / grading.PRIVATE_DIR).get(assignment, {})

    gradebook.require_assignment(home, assignment)

    private = course._private_dir(home)
    notes = course._begin_run(home, private)
    try:
        _write(home, shard, private, assignment, students, cells, theirs, notes)
    except BaseException:
        # Nothing half-merged: the gradebook as it was before, and no run left marked.
        gradebook.restore(home, private / "gradebook.backup.db")
        (private / record.RUN_MARKER).unlink(missing_ok=True)
        raise
    damaged = course._check_gradebook(home, private, notes)

    now = {} if damaged else gradebook.results(home, assignment, students)
    merged = []
    for row in rows:
        nb = now.get(row["student_id"], {})
        theirs_cells = {gid for _, gid in cells[row["student_id"]][1]}
        if not damaged and set(nb.get("cells", {})) != theirs_cells:
            notes.append(f"{row['student_id']}: the shard's gradebook has cells "
                         f"{sorted(theirs_cells)}, this course's {sorted(nb.get('cells', {}))}: "
                         "were both made from the same source notebook?")
        flags = ";".join(f for f in (row.get("flags", ""),
                                     "gradebook_restored" if damaged else "") if f)
        nb = {**nb, "duedate": nb.get("duedate") or row.get("duedate", "")}
        merged.append(course.grade_row(assignment, row["student_id"], nb,
                                       float(row["raw_score"]), float(row["max_score"]), flags,
                                       row.get("timestamp", "")))
    for row in refused:
        merged.append(course.grade_row(assignment, row["student_id"],
                                       {"duedate": row.get("duedate", "")},
                                       float(row["raw_score"]), float(row["max_score"]),
                                       row.get("flags", ""), row.get("timestamp", "")))
    record.update_csv(home, course.GRADES_CSV, course.GRADE_COLUMNS, merged,
                      key=("assignment", "student_id"))
    notes.append(f"merged {len(merged)} student(s) from the shard {shard}")
    if ungraded:
        notes.insert(0, f"not merged, the shard's grader failed on them (no score): "
                        f"{', '.join(ungraded)}: grade them again")
    course._end_run(course.GradeRun(home, private, assignment, "", None, "merged",
                                    grading.Limits(), notes, 0.0), merged, [], {})
    if not quiet:
        print(f"{assignment}: merged {len(merged)} student(s) from {shard} into {home}")
        for note in notes[:-1]:
            print(f"  note: {freeze.printable(note)}")
    return merged
