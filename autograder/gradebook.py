"""nbgrader's gradebook (``gradebook.db``): the one module that opens it.

Every read and write of a gradebook, the course's own or a throwaway one, goes through a
function here, either nbgrader's API (:class:`nbgrader.api.Gradebook`) or plain read-only
SQL; no other module of ``autograder``, ``cobotlab`` or ``benchmarks`` imports nbgrader's
``Gradebook`` or calls ``sqlite3.connect`` (tests/test_gradebook_module.py holds them to it).
Scores are points as nbgrader counts them (a cell's ``auto_score`` of its ``max_score``), a
late penalty is points taken off the total, times are nbgrader's (naive UTC ``datetime``).

* The course's gradebook kept whole: :func:`problem` (an integrity check), :func:`backup`
  before every run and :func:`restore` of that copy when the check fails afterwards;
  :func:`create` makes the empty one of a new course.
* Read from it: :func:`duedate`, :func:`results` (each student's cells, names, timestamp and
  penalty), :func:`require_assignment`,
  :func:`net_scores` and :func:`cells_and_comments` (what the benchmarks compare),
  :func:`class_scores` (each submission's total, penalty and manual cells: the LMS export
  and the class report).
* Written to it from the trusted process: :func:`write_nbgrader_cells` (nbgrader's validated
  cell scores), :func:`write_cobotlab` (cobotlab's scores and findings; an instructor's
  manual score or comment is never touched, so it wins on every regrade),
  :func:`withdraw_scores` (a submission the grader could not grade keeps no automatic
  score), :func:`remove_assignment` (`cobotlab labs remove`). The late penalty is computed
  here, from the course's own rule.
* The throwaway gradebooks of :mod:`autograder.scratch`: :func:`set_duedate` and
  :func:`template_cells` on the template cobotlab makes itself, :func:`read_scratch_scores`
  on one written next to student code (plain read-only SQL, validated values only).
"""

from __future__ import annotations

import math
import os
import shutil
import sqlite3
import stat
import warnings
from dataclasses import dataclass
from pathlib import Path

from autograder.freeze import printable

__all__ = ["CellScore", "problem", "backup", "restore", "create", "duedate", "results",
           "require_assignment", "net_score", "net_scores", "cells_and_comments",
           "write_nbgrader_cells", "write_cobotlab", "withdraw_scores", "set_duedate",
           "template_cells", "read_scratch_scores", "class_scores",
           "remove_assignment"]


@dataclass(frozen=True)
class CellScore:
    """One graded cell's score: ``score`` points of its ``max_score``, in ``notebook``."""

    notebook: str
    cell: str
    score: float
    max_score: float


# --------------------------------------------------------------------------- kept whole


def problem(db: Path) -> str | None:
    """Why ``db`` is not a healthy nbgrader gradebook, or None (a missing one is healthy).

    Read-only (sqlite's ``mode=ro``, 10 s busy timeout): not a regular file (a link is not
    followed), a failed ``PRAGMA integrity_check``, no ``assignment`` table, a negative auto
    or manual score, or any sqlite error, each as a short printable reason."""
    if not os.path.lexists(db):
        return None
    if not stat.S_ISREG(os.lstat(db).st_mode):
        return "gradebook.db is not a regular file"
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
        try:
            verdict = con.execute("PRAGMA integrity_check").fetchone()[0]
            if verdict != "ok":
                return f"sqlite integrity check: {printable(verdict, 200)}"
            con.execute("SELECT count(*) FROM assignment").fetchone()
            bad = con.execute("SELECT count(*) FROM grade WHERE auto_score < 0 OR "
                              "manual_score < 0").fetchone()[0]
            if bad:
                return f"{bad} negative scores"
        finally:
            con.close()
    except sqlite3.Error as exc:
        return f"{type(exc).__name__}: {printable(exc, 200)}"
    return None


def backup(root: Path, private: Path) -> Path | None:
    """Copy ``root/gradebook.db`` to ``private/gradebook.backup.db`` (atomically: sqlite's
    online backup into ``private/.gradebook.backup.tmp``, then a rename) and return the
    copy's path. None, and nothing written, when there is no gradebook or it is a link."""
    db = root / "gradebook.db"
    if not db.is_file() or db.is_symlink():
        return None
    temp = private / ".gradebook.backup.tmp"
    src = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
    dst = sqlite3.connect(temp)
    try:
        src.backup(dst)  # a consistent copy even if a writer is mid-transaction
    finally:
        src.close()
        dst.close()
    copy = private / "gradebook.backup.db"
    os.replace(temp, copy)
    return copy


def restore(root: Path, backup: Path) -> None:
    """Put the copy ``backup`` (made by :func:`backup`) back as ``root/gradebook.db``,
    atomically (a copy into ``root/.gradebook.restore.tmp``, then a rename)."""
    temp = root / ".gradebook.restore.tmp"
    shutil.copyfile(backup, temp)
    os.replace(temp, root / "gradebook.db")


def create(root: Path, course_id: str) -> None:
    """Make ``root/gradebook.db`` through nbgrader's API, for ``course_id`` (an existing one
    is opened as nbgrader opens it, and left as it is)."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{root / 'gradebook.db'}", course_id=course_id):
        pass


# --------------------------------------------------------------------------- read


def duedate(root: Path, assignment: str):
    """The due date of ``assignment`` in ``root/gradebook.db`` (nbgrader's naive UTC
    ``datetime``), or None: no gradebook, no such assignment, or none set."""
    db = root / "gradebook.db"
    if not db.is_file():
        return None
    from nbgrader.api import Gradebook, MissingEntry

    with Gradebook(f"sqlite:///{db}") as gb:
        try:
            return gb.find_assignment(assignment).duedate
        except MissingEntry:
            return None


def results(root: Path, assignment: str, students: list[str]) -> dict:
    """{student: {"cells": {grade_id: (auto score, max)}, "student": {...}, "timestamp",
    "penalty", "duedate"}} as the gradebook holds them now.

    Points as floats (a missing auto score is 0); ``penalty`` is the submission's late
    penalty in points; ``student`` holds ``last_name``, ``first_name`` and ``email`` ("" when
    unset). A student with no submission gets only ``duedate`` and empty ``cells``. Empty
    when there is no gradebook, nbgrader is not installed, or the assignment is missing."""
    db = root / "gradebook.db"
    out: dict = {}
    if not db.exists():
        return out
    try:
        from nbgrader.api import Gradebook, MissingEntry
    except ImportError:
        return out
    with Gradebook(f"sqlite:///{db}") as gb:
        try:
            due = gb.find_assignment(assignment).duedate
        except MissingEntry:
            return out
        for sid in students:
            entry: dict = {"duedate": due, "cells": {}}
            try:
                st = gb.find_student(sid)
                entry["student"] = {"last_name": st.last_name or "", "first_name":
                                    st.first_name or "", "email": st.email or ""}
                sub = gb.find_submission(assignment, sid)
            except MissingEntry:
                out[sid] = entry
                continue
            entry["timestamp"] = sub.timestamp
            entry["penalty"] = float(sub.late_submission_penalty or 0.0)
            for nb in sub.notebooks:
                for g in nb.grades:
                    entry["cells"][g.name] = (float(g.auto_score or 0.0),
                                              float(g.max_score or 0.0))
            out[sid] = entry
    return out


def require_assignment(root: Path, assignment: str) -> None:
    """Raise ValueError unless ``root/gradebook.db`` holds ``assignment`` (``nbgrader
    generate_assignment`` puts it there). Reads only."""
    from nbgrader.api import Gradebook, MissingEntry

    with Gradebook(f"sqlite:///{root / 'gradebook.db'}") as gb:
        try:
            gb.find_assignment(assignment)
        except MissingEntry:
            raise ValueError(f"{root}'s gradebook has no assignment {assignment!r}: run "
                             f"`nbgrader generate_assignment {assignment}` there first") from None


def net_score(raw: float, penalty: float) -> float:
    """A submission's score: ``raw`` points less the late ``penalty`` (points), rounded to
    0.01 and never below 0 (a penalty takes off at most what was earned, as nbgrader's
    late-submission plugin rules). The one place a net score is computed."""
    return max(0.0, round(float(raw) - float(penalty or 0.0), 2))


def net_scores(root: Path, assignment: str) -> dict[str, float]:
    """{student: :func:`net_score`} of every
    submission of ``assignment`` in ``root/gradebook.db``, as nbgrader's API computes the
    total (a manual score counts over the automatic one). nbgrader's errors pass through."""
    from nbgrader.api import Gradebook

    out = {}
    with Gradebook(f"sqlite:///{root / 'gradebook.db'}") as gb:
        for sub in gb.assignment_submissions(assignment):
            out[sub.student.id] = net_score(sub.score, sub.late_submission_penalty)
    return out


def cells_and_comments(root: Path, assignment: str) -> dict:
    """{student: {cell: [auto score, max score, auto comment]}} of ``assignment`` in
    ``root/gradebook.db``, students and cells sorted, so that two runs compare as text
    (None where a cell has no such value)."""
    from nbgrader.api import Gradebook

    out: dict = {}
    with Gradebook(f"sqlite:///{root / 'gradebook.db'}") as gb:
        for sub in gb.assignment_submissions(assignment):
            cells: dict = {}
            for nb in sub.notebooks:
                for g in nb.grades:
                    cells.setdefault(g.name, [None, None, None])[:2] = [g.auto_score,
                                                                        g.max_score]
                for c in nb.comments:
                    cells.setdefault(c.name, [None, None, None])[2] = c.auto_comment
            out[sub.student.id] = dict(sorted(cells.items()))
    return dict(sorted(out.items()))


# --------------------------------------------------------------------------- write


def _late_penalty(root: Path, student: str, score: float, seconds_late: float) -> float:
    """The course's late-submission rule (nbgrader's LateSubmissionPlugin in its config)."""
    if seconds_late <= 0:
        return 0.0
    from nbgrader.plugins import LateSubmissionPlugin
    from traitlets.config.loader import PyFileConfigLoader

    config = PyFileConfigLoader("nbgrader_config.py", path=str(root)).load_config()
    penalty = LateSubmissionPlugin(config=config).late_submission_penalty(
        student, score, seconds_late)
    return max(0.0, min(float(penalty or 0.0), score))


def _submission(gb, assignment: str, student: str, timestamp: str):
    """The gradebook's submission of ``student`` (made, with the student, if missing)."""
    from nbgrader.utils import parse_utc

    gb.update_or_create_student(student)
    try:
        stamp = parse_utc(timestamp) if timestamp else None
    except (ValueError, OverflowError, TypeError):
        stamp = None
    return (gb.update_or_create_submission(assignment, student, timestamp=stamp)
            if stamp is not None else gb.update_or_create_submission(assignment, student))


def _open(root: Path):
    """The course's gradebook, through nbgrader's API, for writing."""
    from nbgrader.api import Gradebook

    return Gradebook(f"sqlite:///{root / 'gradebook.db'}", "cobotlab")


def write_nbgrader_cells(root: Path, assignment: str, student: str, timestamp: str,
                         cells, notebooks_present: set[str]) -> None:
    """Put one student's validated cell scores (:class:`CellScore`) in the real gradebook.

    Every grade cell of the submission (made, with the student, if missing; ``timestamp``
    ISO text, ignored if unparseable) gets its score clamped to 0..its points, 0 when the
    cell or its notebook (``notebooks_present``: names without ``.ipynb``) is missing; a cell
    with a manual score is marked for review. Only numbers are imported: the student id is
    the validated folder name, no name or email comes from the run, and the late penalty is
    computed here. One transaction.
    """
    from sqlalchemy.exc import SAWarning

    by_key = {(c.notebook, c.cell): c for c in cells}
    with warnings.catch_warnings(), _open(root) as gb:
        # nbgrader's own autograde raises the same SQLAlchemy autoflush warnings: noise here
        warnings.simplefilter("ignore", SAWarning)
        submission = _submission(gb, assignment, student, timestamp)
        for notebook in submission.notebooks:
            total = 0.0
            for grade in notebook.grades:
                cell = by_key.get((notebook.name, grade.name))
                value = cell.score if cell is not None and notebook.name in notebooks_present \
                    else 0.0
                grade.auto_score = clamped(value, grade.max_score)
                grade.needs_manual_grade = grade.manual_score is not None
                total += grade.auto_score
            notebook.late_submission_penalty = _late_penalty(
                root, student, total, float(submission.total_seconds_late or 0.0)) or None
        gb.db.commit()


def clamped(points: float, max_score) -> float:
    """``points`` as the gradebook holds a cell's score: within 0..``max_score``."""
    return min(max(points, 0.0), float(max_score or 0.0))


def nbgrader_cell_results(cells, notebooks_present: set[str]) -> dict[str, tuple[float, float]]:
    """{grade id: (points, max points)} of one student's validated cell scores
    (:class:`CellScore`) as :func:`write_nbgrader_cells` puts them in the gradebook and
    :func:`results` reads them back: clamped to 0..the cell's points, 0 when its notebook
    (``notebooks_present``: names without ``.ipynb``) is missing."""
    return {c.cell: (clamped(c.score if c.notebook in notebooks_present else 0.0, c.max_score),
                     float(c.max_score or 0.0)) for c in cells}


def write_cobotlab(root: Path, assignment: str, student: str, timestamp: str,
                   fractions: dict[str, float],
                   comments: dict[str, str]) -> dict[str, tuple[float | None, float]]:
    """Put cobotlab's scores of one student in the gradebook, where formgrader and
    ``nbgrader export`` read them.

    ``fractions`` maps the grade id of an autograder cell to the fraction (0..1) of its
    function's points the isolated grader gave; the cell's ``auto_score`` becomes that
    fraction of the cell's own points (rounded to 4 places). ``comments`` maps the grade id
    of a solution cell to the text of its ``auto_comment``. ``manual_score`` and
    ``manual_comment`` are left alone (nbgrader shows them instead, so an instructor's
    override survives every regrade); a cell with a manual score is marked for review when
    its automatic score changes. The late penalty is computed again from the course's rule.
    Returns ``(previous, written)`` ``auto_score`` of each written cell (previous: the
    gradebook's, e.g. nbgrader's own, or None). Raises ValueError on a fraction outside
    [0, 1] (nothing is written then) and nbgrader's MissingEntry when the assignment is not
    in the gradebook (``nbgrader generate_assignment`` makes it). One transaction.
    """
    from sqlalchemy.exc import SAWarning

    for grade_id, fraction in fractions.items():
        if not isinstance(fraction, (int, float)) or not 0.0 <= fraction <= 1.0:
            raise ValueError(f"refusing to record {fraction!r} as the score fraction of cell "
                             f"{printable(grade_id)!r}: it must be a number in [0, 1]")
    written: dict[str, tuple[float | None, float]] = {}
    with warnings.catch_warnings(), _open(root) as gb:
        warnings.simplefilter("ignore", SAWarning)
        gb.find_assignment(assignment)  # MissingEntry before a student or submission is made
        submission = _submission(gb, assignment, student, timestamp)
        for notebook in submission.notebooks:
            total = 0.0
            for grade in notebook.grades:
                if grade.name in fractions:
                    points = float(grade.max_score or 0.0)
                    score = min(max(round(fractions[grade.name] * points, 4), 0.0), points)
                    before = None if grade.auto_score is None else float(grade.auto_score)
                    written[grade.name] = (before, score)
                    changed = before is None or abs(before - score) > 1e-9
                    grade.auto_score = score
                    grade.needs_manual_grade = (grade.manual_score is not None
                                                and (changed or bool(grade.needs_manual_grade)))
                value = grade.manual_score if grade.manual_score is not None else grade.auto_score
                total += float(value or 0.0)
            for comment in notebook.comments:
                if comment.name in comments:
                    comment.auto_comment = comments[comment.name]
            notebook.late_submission_penalty = _late_penalty(
                root, student, total, float(submission.total_seconds_late or 0.0)) or None
        gb.db.commit()
    return written


def withdraw_scores(root: Path, assignment: str, student: str, comment: str) -> int:
    """Empty every automatic score of ``student``'s submission of ``assignment`` (the
    grader could not grade it): ``auto_score`` None, each cell marked for manual grading,
    ``comment`` as the auto comment of every comment cell, no late penalty. A manual score
    an instructor gave stays, and wins, as everywhere. Returns how many scores were emptied;
    nothing is made for a student or submission the gradebook does not hold. One
    transaction."""
    from nbgrader.api import MissingEntry
    from sqlalchemy.exc import SAWarning

    emptied = 0
    with warnings.catch_warnings(), _open(root) as gb:
        warnings.simplefilter("ignore", SAWarning)
        try:
            submission = gb.find_submission(assignment, student)
        except MissingEntry:
            return 0
        for notebook in submission.notebooks:
            for grade in notebook.grades:
                if grade.auto_score is not None:
                    emptied += 1
                grade.auto_score = None
                grade.needs_manual_grade = True
            for cell in notebook.comments:
                cell.auto_comment = comment
            notebook.late_submission_penalty = None
        gb.db.commit()
    return emptied


# --------------------------------------------------------------------------- scratch gradebooks


def set_duedate(db: Path, assignment: str, duedate) -> None:
    """Set ``assignment``'s due date (nbgrader's naive UTC ``datetime``) in the gradebook at
    ``db`` (the template :mod:`autograder.scratch` makes; the assignment made if missing)."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{db}") as gb:
        gb.update_or_create_assignment(assignment, duedate=duedate)


def template_cells(db: Path, assignment: str) -> dict[tuple[str, str], float]:
    """{(notebook, grade cell): max score in points} of the assignment, from the trusted
    template gradebook at ``db``. nbgrader's MissingEntry when it lacks the assignment."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{db}") as gb:
        return {(nb.name, cell.name): float(cell.max_score)
                for nb in gb.find_assignment(assignment).notebooks for cell in nb.grade_cells}


def read_scratch_scores(db: Path, assignment: str, student: str,
                        known: dict[tuple[str, str], float]
                        ) -> tuple[list[CellScore], list[str]]:
    """Cell scores of ``student`` in a gradebook written next to student code: read-only,
    with plain SQL (no ORM, no triggers), and only values that pass validation.

    ``known`` is :func:`template_cells` of the trusted template: a cell not in it is
    ignored, a score that is not a finite number in 0..its points is ignored (scored 0), a
    cell listed twice counts at its lowest, at most 10000 rows are read. Returns a score for
    every known cell (0 when absent) and notes on what was ignored; an unreadable database
    gives no scores and one note."""
    notes: list[str] = []
    scores: dict[tuple[str, str], float] = {}
    uri = f"file:{db}?mode=ro&immutable=1"
    try:
        con = sqlite3.connect(uri, uri=True, timeout=2)
        try:
            con.execute("PRAGMA trusted_schema=OFF")
            rows = con.execute(
                "SELECT notebook.name, base_cell.name, grade.auto_score FROM grade "
                "JOIN submitted_notebook ON grade.notebook_id = submitted_notebook.id "
                "JOIN submitted_assignment ON submitted_notebook.assignment_id = "
                "submitted_assignment.id "
                "JOIN assignment ON submitted_assignment.assignment_id = assignment.id "
                "JOIN notebook ON submitted_notebook.notebook_id = notebook.id "
                "JOIN base_cell ON grade.cell_id = base_cell.id "
                "WHERE submitted_assignment.student_id = ? AND assignment.name = ? "
                "LIMIT 10000", (student, assignment)).fetchall()
        finally:
            con.close()
    except sqlite3.Error as exc:
        return [], [f"nbgrader's scratch gradebook is unreadable ({type(exc).__name__}): its "
                    "cell results are ignored"]
    for nb, cell, score in rows:
        key = (str(nb), str(cell))
        if key not in known:
            notes.append(f"nbgrader result for an unknown cell {printable(key, 80)} ignored")
            continue
        top = known[key]
        if isinstance(score, (int, float)) and math.isfinite(score) and 0 <= score <= top:
            # a row planted twice counts at its lowest
            scores[key] = min(float(score), scores.get(key, math.inf))
        elif score is not None:
            notes.append(f"nbgrader score {printable(score, 40)} for {key[1]} is outside 0..{top:g}:"
                         " ignored (scored 0)")
    return [CellScore(nb, cell, scores.get((nb, cell), 0.0), top)
            for (nb, cell), top in sorted(known.items())], notes


# --------------------------------------------------------------------------- the class's totals


def class_scores(root: Path, assignment: str) -> dict:
    """{student: {...}} of every submission of ``assignment`` in ``root/gradebook.db``, as an
    LMS export or the class report needs them (read through nbgrader's API, nothing written).

    Each entry: ``score`` (the total less the late penalty, rounded to 0.01, never below 0;
    None when the submission is *ungraded*: some cell has neither an automatic nor a manual
    score, as :func:`withdraw_scores` leaves it), ``raw_score`` (nbgrader's total, a manual
    score counting over the automatic one), ``penalty``, ``max_score``, ``manual`` (the grade
    ids with a manual score), ``timestamp`` and ``duedate`` (naive UTC ``datetime`` or None),
    ``seconds_late`` (0 when on time), and ``first_name``, ``last_name``, ``email`` ("" when
    unset). Raises ValueError when there is no gradebook or it lacks the assignment."""
    db = root / "gradebook.db"
    if not db.is_file():
        raise ValueError(f"{root} has no gradebook.db: is it a course made by `cobotlab course "
                         "init`, graded with `cobotlab grade`?")
    from nbgrader.api import Gradebook, MissingEntry

    out: dict = {}
    with Gradebook(f"sqlite:///{db}") as gb:
        try:
            gb.find_assignment(assignment)
        except MissingEntry:
            raise ValueError(f"{root}'s gradebook has no assignment {assignment!r}: check the "
                             "name, or run `nbgrader generate_assignment` and `cobotlab grade`"
                             ) from None
        for sub in gb.assignment_submissions(assignment):
            grades = [g for nb in sub.notebooks for g in nb.grades]
            ungraded = any(g.auto_score is None and g.manual_score is None for g in grades)
            raw = float(sub.score or 0.0)
            penalty = float(sub.late_submission_penalty or 0.0)
            st = sub.student
            out[sub.student.id] = {
                "score": None if ungraded else net_score(raw, penalty),
                "raw_score": raw, "penalty": penalty, "max_score": float(sub.max_score or 0.0),
                "manual": sorted(g.name for g in grades if g.manual_score is not None),
                "timestamp": sub.timestamp, "duedate": sub.duedate,
                "seconds_late": float(sub.total_seconds_late or 0.0),
                "first_name": st.first_name or "", "last_name": st.last_name or "",
                "email": st.email or ""}
    return dict(sorted(out.items()))


# --------------------------------------------------------------------------- a lab removed


def remove_assignment(root: Path, assignment: str) -> bool:
    """Delete ``assignment`` from ``root/gradebook.db`` with every submission of it and
    their scores and comments, through nbgrader's API (``Gradebook.remove_assignment``, one
    transaction). Returns whether it was there."""
    from nbgrader.api import MissingEntry

    if not (root / "gradebook.db").is_file():
        return False
    with _open(root) as gb:
        try:
            gb.remove_assignment(assignment)
        except MissingEntry:
            return False
    return True

