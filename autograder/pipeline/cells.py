"""A submitted notebook's code as the grader reads it: JSON only, nothing run.

Every code cell is kept in order, except hidden-test cells and IPython magics; each kept cell
knows where it sits in the notebook (:class:`CellOrigin`), so feedback numbers cells as the
student sees them. The static scan for tampering with the grader is here too.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from autograder.nbgrader_cells import cell_role
from autograder.outcomes import Note

HIDDEN_MARK = "BEGIN HIDDEN TESTS"


def cell_source(cell) -> str:
    """A notebook cell's source as one string ("" for anything that is not one)."""
    source = cell.get("source", "") if isinstance(cell, dict) else ""
    if isinstance(source, list):
        source = "".join(s for s in source if isinstance(s, str))
    return source if isinstance(source, str) else ""


def _strip_magics(source: str) -> str | None:
    """Drop IPython-only lines (``%...``, ``!...``); None for a cell magic (``%%...``) cell."""
    if source.lstrip().startswith("%%"):
        return None
    return "\n".join("pass  # magic removed" if line.lstrip().startswith(("%", "!")) else line
                     for line in source.splitlines())


@dataclass(frozen=True)
class CellOrigin:
    """Where an extracted code cell sits in the student's notebook: ``position`` counts every
    cell from 1 (markdown too); ``prompt`` is its ``In [n]`` after Restart and Run All (code
    cells with code in them, counted from 1; an empty cell does not advance the counter)."""

    notebook: str
    position: int
    prompt: int


def _is_test_cell(cell: dict) -> bool:
    """An nbgrader autograder-test cell (graded, not a solution), by its metadata."""
    return cell_role(cell).autograder_test


def extract_code(notebook_paths, with_origins: bool = False, tests: set[int] | None = None):
    """(code cells in order, notes) from one or more notebooks, hidden-test cells left out;
    with ``with_origins``, (cells, origins, notes), a :class:`CellOrigin` per kept cell.

    Reads raw JSON and tolerates missing metadata, deleted, duplicated or reordered cells:
    graded functions are found later by name, not by cell id.

    ``tests``: a set to fill with the indices of the kept autograder-test cells. Given it, the
    nbgrader test cells (by metadata) are kept, hidden tests included. Only pass it for a
    notebook nbgrader has sanitized (its ``OverwriteCells`` put the instructor's source back
    into every cell whose metadata says it is a test), or a student could mark a cell as one.
    """
    if isinstance(notebook_paths, (str, Path)):
        notebook_paths = [notebook_paths]
    cells, origins, notes = [], [], []
    for path in notebook_paths:
        try:
            nb = json.loads(Path(path).read_text(encoding="utf-8", errors="replace"))
            raw_cells = nb.get("cells", []) if isinstance(nb, dict) else []
        except (OSError, ValueError) as exc:
            text = f"{Path(path).name}: unreadable notebook ({type(exc).__name__})"
            notes.append(Note(text, for_student=text))
            continue
        prompt = 0
        for position, cell in enumerate(raw_cells if isinstance(raw_cells, list) else [], 1):
            if not isinstance(cell, dict) or cell.get("cell_type") != "code":
                continue
            source = cell_source(cell)
            prompt += bool(source.strip())
            is_test = tests is not None and _is_test_cell(cell)
            if HIDDEN_MARK in source and not is_test:
                continue
            source = _strip_magics(source)
            if source and source.strip():
                if is_test:
                    tests.add(len(cells))
                cells.append(source)
                origins.append(CellOrigin(Path(path).name, position, prompt))
    return (cells, origins, notes) if with_origins else (cells, notes)


# Patterns that have no business in a lab answer; a match is flagged for the instructor
# to look at (it does not change the score, which is computed independently anyway).
_TAMPER_PATTERNS = {
    "exception_handler": r"set_custom_exc|sys\.excepthook|showtraceback",
    "kernel_patch": r"\.kernel\b|do_execute|run_cell|ipykernel|shell_handlers",
    "sys_modules": r"sys\.modules\s*\[[^\]]*\]\s*=|sys\.modules\.(?:update|pop|__setitem__)",
    "numpy_patch": r"\b(?:np|numpy)(?:\.\w+)+\s*=(?!=)|setattr\(\s*(?:np|numpy)\b",
    # Student-facing imports are fine: check, and the practice data of autograder.datasets
    # and autograder.synthetic (lab 1 on); any other use of the package is looked at.
    "grader_patch": r"\bautograder\b(?!\.checks import check\b|\.(?:datasets|synthetic) import\b)",
    "secret_probe": r"COBOTLAB_GRADING_SECRET|\.cobotlab\b|os\.environ|getenv",
    "stack_inspection": r"_getframe|inspect\.(?:stack|currentframe)|f_back|f_locals",
    "signal_handling": r"\bsignal\.(?:signal|setitimer|alarm)|\bsetrlimit\b",
    # A lab answer reads no other files' code: searching the disk and running what it finds
    # is how a submission would reach an answer key (none is in the worker's view).
    "file_search": r"\bos\.walk\b|\bos\.scandir\b|\bos\.listdir\b|\bglob\.i?glob\b|"
                   r"\.rglob\(|\bsys\.path\b|\bsite\.getsitepackages\b",
    "code_loading": r"(?<![\w.])(?:exec|compile)\s*\(|\brunpy\b|spec_from_file_location|"
                    r"SourceFileLoader|\bimp\.load_source\b",
}


def scan_for_tampering(cells: list[str]) -> list[str]:
    """Names of suspicious patterns found in the student's code (see ``_TAMPER_PATTERNS``)."""
    code = "\n".join(cells)
    code = "\n".join(line for line in code.splitlines()
                     if "from autograder.checks import check" not in line)
    return [f"suspicious_{name}" for name, pattern in _TAMPER_PATTERNS.items()
            if re.search(pattern, code)]


_HIDDEN_TEST_CALL = re.compile(r"\bhidden_test\(\s*([A-Za-z_]\w*)")


def hidden_tests_called(test_sources) -> list[str]:
    """The functions the test cells' ``hidden_test(f)`` lines name, in order, once each.

    Read from the instructor's source (restored by nbgrader), not reported by the worker,
    so student code that patches ``hidden_test`` cannot skip one."""
    names: list[str] = []
    for source in test_sources:
        for name in _HIDDEN_TEST_CALL.findall(source):
            if name not in names:
                names.append(name)
    return names
