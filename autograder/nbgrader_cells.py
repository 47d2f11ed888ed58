"""nbgrader's metadata of a notebook cell: the one reader.

nbgrader marks a cell's role in ``cell["metadata"]["nbgrader"]``: ``grade_id``, ``grade``
(it has points), ``solution`` (the student writes in it), ``locked`` (read-only), and for a
graded cell its ``points``. Every module that asks what a cell is asks here, so a notebook
whose metadata is missing or malformed (a student can edit it: a list, a string, a number
where nbgrader writes a dict or a boolean) reads the same everywhere: as no role at all,
never as an exception in one reader and a role in another. Standard library only: nbgrader
imports :mod:`autograder.nbgrader_hooks`, which uses this, in its own process.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CellRole", "nbgrader_metadata", "cell_role"]


def nbgrader_metadata(cell) -> dict:
    """The cell's nbgrader metadata, the dict itself (a preprocessor may edit it in
    place); ``{}`` when the cell, its metadata or that entry is not a dict."""
    meta = cell.get("metadata") if isinstance(cell, dict) else None
    meta = meta.get("nbgrader") if isinstance(meta, dict) else None
    return meta if isinstance(meta, dict) else {}


@dataclass(frozen=True)
class CellRole:
    """What nbgrader's metadata says a cell is. The flags are true only for a JSON ``true``
    (as nbgrader writes them); ``grade_id`` is "" when absent or not a string."""

    grade_id: str = ""
    grade: bool = False
    solution: bool = False
    locked: bool = False

    @property
    def autograder_test(self) -> bool:
        """A graded cell that is not a solution: nbgrader's autograder-test cell."""
        return self.grade and not self.solution

    @property
    def read_only(self) -> bool:
        """Locked and neither graded nor a solution: the instructor's given code."""
        return self.locked and not self.grade and not self.solution


def cell_role(cell) -> CellRole:
    """The :class:`CellRole` of a notebook cell (a dict as in the notebook's JSON)."""
    meta = nbgrader_metadata(cell)
    grade_id = meta.get("grade_id")
    return CellRole(grade_id=grade_id if isinstance(grade_id, str) else "",
                    grade=meta.get("grade") is True, solution=meta.get("solution") is True,
                    locked=meta.get("locked") is True)
