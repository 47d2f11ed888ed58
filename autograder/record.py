"""The trusted side of grading: write into the instructor's course without losing anything.

* :func:`backup_gradebook` / :func:`gradebook_problem` / :func:`restore_gradebook`: a copy
  of ``gradebook.db`` before every run, an integrity check after, the copy put back (and
  the run flagged) when the check fails. A run interrupted half-way leaves a marker that the
  next run sees and acts on.
* :func:`record_nbgrader` puts validated cell scores into the real gradebook through
  nbgrader's API; the penalty is computed here, from the course's own late-submission rule.
* :func:`record_cobotlab` puts cobotlab's per-function scores in the same cells (scaled to
  each cell's points), and its findings in the auto comments formgrader shows; an
  instructor's manual score or comment is never touched, so it wins on every regrade.
* :func:`withdraw_scores` empties the automatic scores of a submission cobotlab could not
  grade, so nbgrader's gradebook and export hold no score that cobotlab did not give (an
  earlier, trusting ``nbgrader autograde`` may have scored a notebook built to fool it).
* :func:`write_file` writes atomically (temp file + rename in the same folder) and never
  follows a symlink on the way (its folders are opened by :mod:`autograder.safe_files`,
  which every read of the trusted side goes through too); :func:`write_csv` escapes cells
  a spreadsheet would run, :func:`update_csv` replaces only the rows of this run and keeps
  the others (read through :mod:`autograder.safe_files` too).
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import sqlite3
import stat
import time
import warnings
from pathlib import Path

from autograder import safe_files
from autograder.freeze import printable

__all__ = ["backup_gradebook", "gradebook_problem", "restore_gradebook", "record_nbgrader",
           "record_cobotlab", "withdraw_scores", "write_file", "remove_file", "write_csv",
           "update_csv", "csv_cell", "RUN_MARKER"]

RUN_MARKER = "grading-in-progress"
_CSV_CAP = 256 * 2**20   # grades.csv: about a million rows


# --------------------------------------------------------------------------- safe writing


def write_file(root: Path, relative: str, data: bytes) -> Path:
    """Write ``root/relative`` atomically, without following any symlink below ``root``.

    A symlink at the target itself is replaced (rename does not follow it); a directory
    there is moved aside to ``<name>.moved-<time>`` so the run still ends with the file.
    """
    parts = relative.split("/")
    name = parts[-1]
    if name in ("", ".", "..") or "\0" in name:
        raise ValueError(f"refusing to write {printable(relative)!r}: not a file name")
    folder = safe_files.open_folder(Path(root), parts[:-1], create=True)
    fd = folder.fd
    try:
        try:
            info = os.stat(name, dir_fd=fd, follow_symlinks=False)
            if stat.S_ISDIR(info.st_mode):
                os.rename(name, f"{name}.moved-{int(time.time())}", src_dir_fd=fd, dst_dir_fd=fd)
        except FileNotFoundError:
            pass
        temp = f".{name}.tmp-{os.getpid()}"
        out = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o644,
                      dir_fd=fd)
        with os.fdopen(out, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.rename(temp, name, src_dir_fd=fd, dst_dir_fd=fd)
    finally:
        folder.close()
    return Path(root) / relative


def remove_file(root: Path, relative: str) -> bool:
    """Remove ``root/relative`` if it is there (a link is removed, never followed), without
    following any symlink below ``root`` on the way. Returns whether something was removed;
    a folder there is left alone."""
    parts = relative.split("/")
    try:
        folder = safe_files.open_folder(Path(root), parts[:-1])
    except (OSError, ValueError):   # safe_files.Refused is a ValueError
        return False
    try:
        os.unlink(parts[-1], dir_fd=folder.fd)
        return True
    except (FileNotFoundError, IsADirectoryError, PermissionError):
        return False
    finally:
        folder.close()


def csv_cell(value):
    """A CSV cell a spreadsheet shows as text: ``= + - @`` (and tab, CR) at the start get a
    leading apostrophe; control characters are escaped. Numbers pass unchanged."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return value
    text = printable(value, 2000)
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def write_csv(root: Path, relative: str, columns: list[str], rows: list[dict]) -> Path:
    """Write ``rows`` (dicts; missing keys empty) as ``root/relative``, atomically, every cell
    through :func:`csv_cell`."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: csv_cell(row.get(k, "")) for k in columns})
    return write_file(root, relative, buffer.getvalue().encode("utf-8"))


def update_csv(root: Path, relative: str, columns: list[str], rows: list[dict],
               key: tuple[str, ...]) -> list[dict]:
    """Merge ``rows`` into the CSV at ``root/relative`` and write it back atomically.

    A row already there with the same ``key`` columns is replaced; every other row is kept
    as it was (columns it lacks stay empty, columns not in ``columns`` are dropped). Rows are
    sorted by ``key``. Anything but a regular file there (a symlink, say) is not read, and
    replaced as :func:`write_file` does; a regular file that is not readable CSV is moved
    aside to ``<name>.unreadable-<time>`` rather than lost. Returns every row written.
    """
    def ident(row: dict) -> tuple:  # compared as written: old rows were escaped already
        return tuple(str(csv_cell(row.get(k, ""))) for k in key)

    kept: dict[tuple, dict] = {}
    data = None
    try:
        data = safe_files.read_file(root, relative, _CSV_CAP)
    except safe_files.Refused as exc:
        # Missing, or not a regular file (replaced below, never followed): nothing to keep.
        # Too big or unreadable: kept aside, as a file that is not CSV is.
        if exc.why in (safe_files.Why.TOO_BIG, safe_files.Why.UNREADABLE):
            safe_files.move_aside(root, relative, f".unreadable-{int(time.time())}")
    if data is not None:
        try:
            reader = csv.DictReader(io.StringIO(data.decode("utf-8"), newline=""))
            if reader.fieldnames is not None and not set(key) <= set(reader.fieldnames):
                raise ValueError(f"no {'/'.join(key)} columns")  # None: an empty file
            for row in reader:
                kept[ident(row)] = {k: row.get(k) or "" for k in columns}
        except (ValueError, UnicodeDecodeError, csv.Error):
            safe_files.move_aside(root, relative, f".unreadable-{int(time.time())}")
            kept = {}
    for row in rows:
        kept[ident(row)] = row
    merged = [kept[k] for k in sorted(kept)]
    write_csv(root, relative, columns, merged)
    return merged


# --------------------------------------------------------------------------- the gradebook


def gradebook_problem(db: Path) -> str | None:
    """Why ``db`` is not a healthy nbgrader gradebook, or None (a missing one is healthy)."""
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


def backup_gradebook(root: Path, private: Path) -> Path | None:
    """Copy ``root/gradebook.db`` to ``private/gradebook.backup.db`` (atomically)."""
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
    backup = private / "gradebook.backup.db"
    os.replace(temp, backup)
    return backup


def restore_gradebook(root: Path, backup: Path) -> None:
    temp = root / ".gradebook.restore.tmp"
    shutil.copyfile(backup, temp)
    os.replace(temp, root / "gradebook.db")


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


def _open_gradebook(root: Path):
    from nbgrader.api import Gradebook

    return Gradebook(f"sqlite:///{root / 'gradebook.db'}", "cobotlab")


def record_nbgrader(root: Path, assignment: str, student: str, timestamp: str,
                    cells, notebooks_present: set[str]) -> None:
    """Put one student's validated cell scores (``scratch.CellScore``) in the real gradebook.

    Only numbers are imported: the student id is the validated folder name, no name or
    email comes from the run, and the late penalty is computed here.
    """
    from sqlalchemy.exc import SAWarning

    by_key = {(c.notebook, c.cell): c for c in cells}
    with warnings.catch_warnings(), _open_gradebook(root) as gb:
        # nbgrader's own autograde raises the same SQLAlchemy autoflush warnings: noise here
        warnings.simplefilter("ignore", SAWarning)
        submission = _submission(gb, assignment, student, timestamp)
        for notebook in submission.notebooks:
            total = 0.0
            for grade in notebook.grades:
                cell = by_key.get((notebook.name, grade.name))
                value = cell.score if cell is not None and notebook.name in notebooks_present \
                    else 0.0
                grade.auto_score = min(max(value, 0.0), float(grade.max_score or 0.0))
                grade.needs_manual_grade = grade.manual_score is not None
                total += grade.auto_score
            notebook.late_submission_penalty = _late_penalty(
                root, student, total, float(submission.total_seconds_late or 0.0)) or None
        gb.db.commit()


def record_cobotlab(root: Path, assignment: str, student: str, timestamp: str,
                    fractions: dict[str, float],
                    comments: dict[str, str]) -> dict[str, tuple[float | None, float]]:
    """Put cobotlab's scores of one student in the gradebook, where formgrader and
    ``nbgrader export`` read them.

    ``fractions`` maps the grade id of an autograder cell to the fraction (0..1) of its
    function's points the isolated grader gave; the cell's ``auto_score`` becomes that
    fraction of the cell's own points. ``comments`` maps the grade id of a solution cell to
    the text of its ``auto_comment``. ``manual_score`` and ``manual_comment`` are left alone
    (nbgrader shows them instead, so an instructor's override survives every regrade); a
    cell with a manual score is marked for review when its automatic score changes. The
    late penalty is computed again from the course's rule. Returns ``(previous, written)``
    ``auto_score`` of each written cell (previous: the gradebook's, e.g. nbgrader's own, or
    None). Raises ValueError on a
    fraction outside [0, 1] (nothing is written then) and nbgrader's MissingEntry when the
    assignment is not in the gradebook (``nbgrader generate_assignment`` makes it).
    """
    from sqlalchemy.exc import SAWarning

    for grade_id, fraction in fractions.items():
        if not isinstance(fraction, (int, float)) or not 0.0 <= fraction <= 1.0:
            raise ValueError(f"refusing to record {fraction!r} as the score fraction of cell "
                             f"{printable(grade_id)!r}: it must be a number in [0, 1]")
    written: dict[str, tuple[float | None, float]] = {}
    with warnings.catch_warnings(), _open_gradebook(root) as gb:
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
    ``comment`` as the auto comment of every comment cell. A manual score an instructor
    gave stays, and wins, as everywhere. Returns how many scores were emptied; nothing is
    made for a student or submission the gradebook does not hold."""
    from nbgrader.api import MissingEntry
    from sqlalchemy.exc import SAWarning

    emptied = 0
    with warnings.catch_warnings(), _open_gradebook(root) as gb:
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
