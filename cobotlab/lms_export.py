"""Grades to the LMS: ``cobotlab export COURSE LAB --format canvas|moodle|csv --roster FILE``.

The score exported is what nbgrader's gradebook holds after ``cobotlab grade``: each cell's
manual score (a TA's, from formgrader) over its automatic one, less the late penalty the
course's rule gave (:func:`autograder.gradebook.class_scores`; this module opens no
gradebook itself). Student ids are mapped to the LMS's identities through a roster, a CSV
file with one row per enrolled student:

* ``student_id`` (required): the nbgrader id, the folder name under ``submitted/``;
* for Canvas, the identity columns of Canvas' own gradebook export, under the same names:
  ``Student``, ``ID``, ``SIS User ID``, ``SIS Login ID``, ``Section`` (each row needs ``ID``
  or ``SIS User ID``; Canvas matches on them);
* for Moodle, the field its CSV import maps users by: ``email``, ``idnumber`` or
  ``username`` (``--moodle-id``; every row needs it, no two the same).

Nothing is dropped or made up in silence: a submission whose student is not in the roster
is refused by name (``--skip-unrostered`` leaves them out, still named); a roster row with no
submission, or a submission the grader could not grade, gets an empty cell, never a made-up
zero, and is named on stderr; ``--missing zero`` writes 0 for the first.

The formats, as their vendors document them:

* Canvas, gradebook import (as universities' guides to it describe Canvas' own "How do I
  import grades in the Gradebook?"): a CSV with the columns Student, ID, SIS User ID, SIS
  Login ID and Section, then one column per assignment, named "Title (assignment id)" as
  Canvas' export names it (a new column makes a new assignment), and the "Points Possible"
  row under the header that the export writes:
  https://teaching.resources.osu.edu/toolsets/carmencanvas/guides/calculating-final-grades/import-csv-file-carmen-grades
  https://ts.vcu.edu/askit/teaching-and-learning/canvas/faculty/grading-faculty/gradebook-action-menu-faculty/
* Moodle, grade import from CSV: one column identifies the user, mapped in the import form
  ("Map from" the file's column "to" useremail, useridnumber or username), the others are
  mapped to grade items: https://docs.moodle.org/311/en/Grade_import
* LTI 1.3 Assignment and Grade Services, the passback this module does not do (see
  docs/instructors.md): https://www.imsglobal.org/spec/lti-ags/v2p0/
"""

from __future__ import annotations

import csv
import io
import sys
from dataclasses import dataclass, field
from pathlib import Path

from autograder import gradebook, record, roster
from autograder.freeze import printable

FORMATS = ("canvas", "moodle", "csv")
ROSTER_ID = roster.ID   # the roster's id column, as autograder.roster reads it
CANVAS_IDENTITY = ("Student", "ID", "SIS User ID", "SIS Login ID", "Section")
CANVAS_POINTS_ROW = "Points Possible"
MOODLE_IDS = ("email", "idnumber", "username")
PLAIN_COLUMNS = ("student_id", "last_name", "first_name", "email", "raw_score",
                 "late_submission_penalty", "manual_cells", "score", "max_score", "status")


@dataclass
class Exported:
    """What :func:`export_grades` wrote and whom it could not give a score."""

    path: Path
    scored: list[str] = field(default_factory=list)      # a number in the file
    missing: list[str] = field(default_factory=list)     # in the roster, no submission
    ungraded: list[str] = field(default_factory=list)    # submitted, no score to export
    unrostered: list[str] = field(default_factory=list)  # submitted, not in the roster

    def warnings(self) -> list[str]:
        """One line for each kind of student without a score in the file."""
        out = []
        if self.missing:
            out.append(f"{len(self.missing)} in the roster without a submission (empty cell "
                       f"unless --missing zero): {', '.join(self.missing)}")
        if self.ungraded:
            out.append(f"{len(self.ungraded)} submitted but not graded (empty cell; run "
                       f"`cobotlab grade` again): {', '.join(self.ungraded)}")
        if self.unrostered:
            out.append(f"{len(self.unrostered)} submitted but not in the roster, left out: "
                       f"{', '.join(self.unrostered)}")
        return out


def read_roster(path, fmt: str, moodle_id: str = "email") -> list[dict[str, str]]:
    """The roster's rows (:func:`autograder.roster.read_roster`: the one roster format, each
    row's student id in ``"id"``), checked for ``fmt``: the identity the LMS matches on in
    every row. Raises ValueError naming the row and the fix."""
    rows = roster.read_roster(path)
    needed: tuple[str, ...] = ()
    if fmt == "canvas":
        needed = CANVAS_IDENTITY
    elif fmt == "moodle":
        if moodle_id not in MOODLE_IDS:
            raise ValueError(f"--moodle-id {moodle_id!r}: use one of {', '.join(MOODLE_IDS)}")
        needed = (moodle_id,)
    absent = [c for c in needed if c not in rows[0]]
    if absent:
        raise ValueError(f"the roster {path} lacks the column(s) {absent} that {fmt} needs: "
                         "copy them from the LMS's own gradebook export (see docs/"
                         "instructors.md, Grades to the LMS)")
    seen_lms: dict[str, str] = {}
    for n, row in enumerate(rows, start=2):
        sid = row[ROSTER_ID]
        if fmt == "canvas" and not (row["ID"] or row["SIS User ID"]):
            raise ValueError(f"{path} line {n} ({sid}): neither ID nor SIS User ID is set; "
                             "Canvas needs one to find the student")
        if fmt == "moodle":
            who = row[moodle_id]
            if not who:
                raise ValueError(f"{path} line {n} ({sid}): no {moodle_id}; Moodle maps each "
                                 "row to a user by it")
            if who in seen_lms:
                raise ValueError(f"{path} line {n} ({sid}): {moodle_id} {who!r} is also "
                                 f"{seen_lms[who]}'s")
            seen_lms[who] = sid
    return rows


def _number(x: float) -> str:
    return f"{round(float(x), 2):g}"


def export_grades(course_dir, assignment: str, fmt: str, roster, out=None, *,
                  title: str | None = None, canvas_id: str | None = None,
                  moodle_id: str = "email", missing: str = "blank",
                  skip_unrostered: bool = False) -> Exported:
    """Write the grades of ``assignment`` in ``course_dir`` as ``fmt`` (:data:`FORMATS`) for
    the students of ``roster`` (see the module's doc) to ``out`` (default
    ``course_dir/exports/<assignment>_<fmt>.csv``); returns what was written.

    ``title``: the grade column's name (default the assignment's); Canvas' column is
    ``"title (canvas_id)"`` when ``canvas_id`` (the Canvas assignment's id) is given.
    ``missing``: ``blank`` or ``zero`` for a roster row with no submission. Raises ValueError
    for a student who submitted but is not in the roster, unless ``skip_unrostered``."""
    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt!r}: use one of {', '.join(FORMATS)}")
    if missing not in ("blank", "zero"):
        raise ValueError(f"--missing {missing!r}: use blank or zero")
    if canvas_id is not None and not (fmt == "canvas" and canvas_id.strip().isdigit()):
        raise ValueError(f"--canvas-id {canvas_id!r}: a Canvas assignment's number, with "
                         "--format canvas")
    root = Path(course_dir).resolve()
    scores = gradebook.class_scores(root, assignment)
    rows = read_roster(roster, fmt, moodle_id)
    rostered = {r[ROSTER_ID] for r in rows}
    done = Exported(Path(out) if out is not None else
                    root / "exports" / f"{assignment}_{fmt}.csv")
    done.unrostered = [s for s in scores if s not in rostered]
    if done.unrostered and not skip_unrostered:
        raise ValueError(
            f"{len(done.unrostered)} student(s) submitted {assignment} but are not in the "
            f"roster {roster}: {', '.join(printable(s, 80) for s in done.unrostered)}. Add "
            "their rows (or fix the ids), or pass --skip-unrostered to export the others")
    points = max((e["max_score"] for e in scores.values()), default=0.0)
    column = title or assignment
    if canvas_id is not None:
        column = f"{column} ({canvas_id.strip()})"
    table: list[list[str]] = []
    for row in rows:
        sid = row[ROSTER_ID]
        entry = scores.get(sid)
        if entry is None:
            done.missing.append(sid)
            cell, status = ("0" if missing == "zero" else ""), "missing"
        elif entry["score"] is None:
            done.ungraded.append(sid)
            cell, status = "", "ungraded"
        else:
            done.scored.append(sid)
            cell, status = _number(entry["score"]), "graded"
        if fmt == "canvas":
            table.append([*(row[c] for c in CANVAS_IDENTITY), cell])
        elif fmt == "moodle":
            table.append([row[moodle_id], cell])
        else:
            e = entry or {}
            table.append([sid, e.get("last_name", ""), e.get("first_name", ""),
                          e.get("email", ""),
                          "" if entry is None else _number(e["raw_score"]),
                          "" if entry is None else _number(e["penalty"]),
                          ";".join(e.get("manual", [])), cell,
                          _number(e.get("max_score", points)), status])
    if fmt == "canvas":
        header = [*CANVAS_IDENTITY, column]
        table.insert(0, [CANVAS_POINTS_ROW, "", "", "", "", _number(points)])
    elif fmt == "moodle":
        header = [moodle_id, column]
    else:
        header = list(PLAIN_COLUMNS)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\r\n")   # RFC 4180, as both LMSs read it
    writer.writerow(header)
    writer.writerows(table)
    data = text.getvalue().encode("utf-8")
    if out is None:
        record.write_file(root, f"exports/{assignment}_{fmt}.csv", data)
    else:
        done.path.parent.mkdir(parents=True, exist_ok=True)
        done.path.write_bytes(data)
    return done


def run_export(args) -> None:
    """``cobotlab export``: write the file, say where, and name every student without a
    score in it (stderr)."""
    done = export_grades(args.course_dir, args.assignment, args.format, args.roster,
                         args.out, title=args.title, canvas_id=args.canvas_id,
                         moodle_id=args.moodle_id, missing=args.missing,
                         skip_unrostered=args.skip_unrostered)
    print(f"wrote {done.path}: {len(done.scored)} score(s) for {args.format}")
    for line in done.warnings():
        print(f"warning: {line}", file=sys.stderr)
