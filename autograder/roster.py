"""The class roster: one CSV format, one reader, for every command that takes a roster.

The format (docs/instructors.md, *The roster*) is the file ``nbgrader db student import``
takes: UTF-8 text (a spreadsheet's byte-order mark is fine), a header line, then one row
per enrolled student. The student's id, their nbgrader id and Unix user name (the folder
name under ``submitted/``), is in the column ``id``; ``student_id``, the name grades.csv
and the exports give that column, is read as the same column. Any other column
(``first_name``, ``last_name``, ``email``, an LMS's identity columns) is carried along
for the command that needs it. Header names and cells are read with surrounding spaces
removed; an empty or repeated id is refused by line.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

__all__ = ["ID", "read_roster", "roster_ids"]

ID = "id"
_ID_NAMES = (ID, "student_id")   # nbgrader's import name, and grades.csv's


def _header(path: Path, fieldnames) -> tuple[list[str], str]:
    """(the header's names, stripped; the one that holds the id)."""
    header = [(h or "").strip() for h in (fieldnames or [])]
    named = [h for h in _ID_NAMES if h in header]
    if not named:
        raise ValueError(f"the roster {path} has no id column (its header: {header}): a "
                         "roster is a CSV file whose first line names an `id` column (or "
                         "`student_id`), one student's nbgrader id (Unix user name) a row")
    if len(named) > 1:
        raise ValueError(f"the roster {path} has both an `id` and a `student_id` column: "
                         "they name the same thing; keep one")
    return header, named[0]


def read_roster(path) -> list[dict[str, str]]:
    """The rows of the roster at ``path`` (see the module docstring), in order, each a dict
    by column name whose ``"id"`` is the student's id. Raises ValueError naming the file,
    the line and the fix: unreadable, no id column, an empty or repeated id, no student."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the roster {path}: {exc} (a roster is UTF-8 CSV "
                         "text)") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    header, column = _header(path, reader.fieldnames)
    rows, seen = [], {}
    for n, raw in enumerate(reader, start=2):
        row = {(k or "").strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        sid = row.pop(column, "")
        if not sid:
            raise ValueError(f"the roster {path}, line {n}: an empty id; fill it in or remove "
                             "the row")
        if sid in seen:
            raise ValueError(f"the roster {path}, line {n}: {sid!r} is listed again (line "
                             f"{seen[sid]}); one row per student")
        seen[sid] = n
        rows.append({ID: sid, **row})
    if not rows:
        raise ValueError(f"the roster {path} lists no student: one row per student after "
                         "the header")
    return rows


def roster_ids(path) -> list[str]:
    """The student ids of the roster at ``path``, in order (see :func:`read_roster`)."""
    return [row[ID] for row in read_roster(path)]
