"""nbgrader's own result of each graded cell of a submission, for the cross-check in score.

After the execute stage (or the kept executions of a rescore), and before score: each
submission's :class:`NbgraderCells`, carried in its :class:`~autograder.pipeline.execute.Executed`.
For a submission nbgrader ran on in this run, its cell scores as the gradebook will hold
them (:func:`autograder.gradebook.nbgrader_cell_results`, the gradebook's own clamping);
for the others, as the gradebook holds them now, except where a cell still holds the score
cobotlab wrote there for the same submission: there it is the value cobotlab replaced
(the ledger, ``.cobotlab/nbgrader_cells.json``, which the record stage keeps).
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from autograder import checks, gradebook
from autograder.nbgrader_cells import cell_role
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.cells import HIDDEN_MARK
from autograder.pipeline.execute import Executed
from autograder.record import read_private

# nbgrader's own value of each cell cobotlab overwrote, so the cross-check still has it on
# the next run: {assignment: {student: {"timestamp", "cells": {grade_id: [ours, nbgrader's]}}}}
LEDGER = "nbgrader_cells.json"


@dataclass(frozen=True)
class NbgraderCells:
    """nbgrader's own result of one submission: ``scores`` {grade id: (points, max points)}
    of its graded cells (empty: nbgrader has no result of it), and ``functions`` {grade id of
    a hidden-test cell: the graded function it tests}."""

    scores: Mapping[str, tuple[float, float]]
    functions: Mapping[str, str]


def with_nbgrader_cells(run: GradeRun, frozen, executed: dict[str, Executed]
                        ) -> dict[str, Executed]:
    """``executed`` with each accepted, graded submission's :class:`NbgraderCells` (new
    values; ``executed`` is not changed). Reads the gradebook and the ledger only."""
    functions = cell_to_function(run.root, run.assignment)
    just_run = {sid: d.nbgrader for sid, d in executed.items()
                if d.nbgrader is not None and run.problems != "rescore"}
    graded = [sub for sub in frozen if sub.accepted
              and (not sub.notebooks or executed[sub.student_id].execution is not None)]
    held = nbgrader_own(
        gradebook.results(run.root, run.assignment,
                          [s.student_id for s in graded if s.student_id not in just_run]),
        load_ledger(run.private).get(run.assignment, {}),
        {sub.student_id: sub.timestamp for sub in graded})
    out = dict(executed)
    for sub in graded:
        sid = sub.student_id
        if sid in just_run:
            scores = gradebook.nbgrader_cell_results(just_run[sid].cells,
                                                     {p.stem for p in sub.notebooks})
        else:
            scores = held.get(sid, {}).get("cells", {})
        out[sid] = dataclasses.replace(executed[sid],
                                       nbgrader_cells=NbgraderCells(scores, functions))
    return out


def source_cells(root: Path, assignment: str):
    """(:class:`~autograder.nbgrader_cells.CellRole`, source) of every cell of the source
    notebooks."""
    for path in sorted((root / "source" / assignment).glob("*.ipynb")):
        for cell in json.loads(path.read_text()).get("cells", []):
            yield cell_role(cell), "".join(cell.get("source", ""))


def cell_to_function(root: Path, assignment: str) -> dict[str, str]:
    """grade_id of each hidden-test cell in the source notebooks -> graded function name.

    The labs name a function's test cell ``test_<function>``; a cell named otherwise goes to
    the last graded function it calls.
    """
    names = [s.name for s in checks.SPECS.get(assignment, ())]
    mapping = {}
    for role, source in source_cells(root, assignment):
        grade_id = role.grade_id
        if not (role.grade and HIDDEN_MARK in source):
            continue
        called = [n for n in names if re.search(rf"\b{re.escape(n)}\s*\(", source)]
        by_name = [n for n in names if grade_id == f"test_{n}"]
        if by_name or called:
            mapping[grade_id] = (by_name or called)[-1]
    return mapping


def load_ledger(private: Path) -> dict:
    """The ledger (see :data:`LEDGER`); {} when missing or unreadable."""
    data = read_private(private, LEDGER)
    try:
        ledger = json.loads(data) if data is not None else {}
    except (ValueError, UnicodeDecodeError):
        ledger = {}
    return ledger if isinstance(ledger, dict) else {}


def nbgrader_own(nb_results: dict, ledger: dict, timestamps: dict) -> dict:
    """nbgrader's own cell results: the gradebook's, except in cells that still hold the
    score cobotlab wrote there for the same submission, where it is the value cobotlab
    replaced (a cell nbgrader never graded is left out)."""
    for sid, entry in nb_results.items():
        mine = ledger.get(sid)
        if not isinstance(mine, dict) or mine.get("timestamp") != timestamps.get(sid):
            continue  # nothing of ours in the gradebook
        wrote = mine.get("cells") if isinstance(mine.get("cells"), dict) else {}
        cells = {}
        for grade_id, (score, max_score) in entry.get("cells", {}).items():
            ours = wrote.get(grade_id)
            if isinstance(ours, list) and len(ours) == 2 and isinstance(ours[0], (int, float)) \
                    and abs(score - ours[0]) < 1e-6:
                if not isinstance(ours[1], (int, float)):
                    continue
                score = float(ours[1])
            cells[grade_id] = (score, max_score)
        entry["cells"] = cells
    return nb_results
