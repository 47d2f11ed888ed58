"""docs/architecture.md is true: its ten-line scoring example runs as written (no sandbox,
no course), every file and function it names exists, and its stage table names the modules
and functions ``grade_course`` calls, in the order it calls them."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "architecture.md").read_text()
# the modules the doc names functions of as `module.name`: autograder's own, then the line's
MODULES = ("course", "executions", "checks", "freeze", "shards", "secret", "pipeline", "begin",
           "draw", "problems", "cells", "worker", "execution", "execute", "score", "record",
           "rescore", "nbgrader_results")


def _resolve(dotted: str):
    """The object `module.name[.attr]` names in autograder/pipeline/ or autograder/, or None."""
    module, *attrs = dotted.split(".")
    for package in ("autograder.pipeline", "autograder"):
        try:
            obj = importlib.import_module(f"{package}.{module}")
        except ModuleNotFoundError:
            continue
        for attr in attrs:
            obj = getattr(obj, attr, None)
        if obj is not None:
            return obj
    return None


def test_the_scoring_example_runs_as_written():
    (block,) = re.findall(r"```python\n(.*?)```", DOC, re.S)
    assert len(block.strip().splitlines()) <= 14
    exec(compile(block, "docs/architecture.md", "exec"), {})  # noqa: S102 - our own doc


def test_every_file_and_function_it_names_exists():
    paths = set(re.findall(r"`(autograder/[\w/.<>]+?|benchmarks/\w+\.py|tests/[\w/]+?\.py)`",
                           DOC))
    assert paths, "the doc names no files?"
    for path in paths:
        if "<" in path:   # a pattern, e.g. autograder/scoring/<lab>.py
            continue
        assert (ROOT / path.rstrip("/")).exists(), path
    names = set(re.findall(rf"`((?:{'|'.join(MODULES)})\.[A-Za-z_]+(?:\.[A-Za-z_]+)?)`", DOC))
    assert len(names) >= 8, names
    for dotted in names:
        assert _resolve(dotted) is not None, dotted


def test_where_to_fix_what_names_one_existing_file_per_symptom():
    section = DOC.split("## Where to fix what", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines()
            if line.startswith("| ") and not line.startswith(("| symptom", "| ---"))]
    assert len(rows) >= 10, rows
    for row in rows:
        symptom, first = (cell.strip() for cell in row.strip("|").split("|"))
        files = re.findall(r"`([\w/.<>]+\.py)`", first)
        assert len(files) == 1 and first == f"`{files[0]}`", (symptom, first)
        if "<lab>" in files[0]:
            files[0] = files[0].replace("<lab>", "lab0_frames")
        assert (ROOT / files[0]).is_file(), (symptom, files[0])


def _stage_rows() -> list[list[str]]:
    table = DOC.split("| stage | function |", 1)[1].split("\n\n", 1)[0]
    return [[cell.strip() for cell in line.strip("|").split("|")]
            for line in table.splitlines()[2:] if line.startswith("| ")]


def _calls_in_order(source: str, function: str) -> list[str]:
    """The names ``function`` calls, in the order of the lines they are on."""
    fn = next(n for n in ast.parse(source).body
              if isinstance(n, ast.FunctionDef) and n.name == function)
    calls = [n for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    return [c.func.id for c in sorted(calls, key=lambda c: (c.lineno, c.col_offset))]


def test_the_stage_table_names_the_modules_and_functions_the_line_calls_in_order():
    rows = _stage_rows()
    assert [row[0] for row in rows] == ["begin", "freeze", "draw", "execute", "score", "record"]
    called = _calls_in_order((ROOT / "autograder" / "pipeline" / "pipeline.py").read_text(),
                             "grade_course")
    order = []
    for stage, functions, module, *_ in rows:
        files = re.findall(r"`(autograder/[\w/]+\.py)`", module)
        assert len(files) == 1 and (ROOT / files[0]).is_file(), (stage, module)
        named = re.findall(r"`(\w+)\.(\w+)`", functions)
        assert named, (stage, functions)
        for dotted in (".".join(n) for n in named):
            assert _resolve(dotted) is not None, (stage, dotted)
        # the first function of each row is the one the line calls, from the row's module
        first_module, first = named[0]
        assert first in called, f"grade_course no longer calls {first} ({stage})"
        defined = importlib.import_module(files[0][:-3].replace("/", "."))
        assert getattr(defined, first, None) is _resolve(f"{first_module}.{first}"), (stage, first)
        order.append(called.index(first))
    assert order == sorted(order), "the stages are not called in the table's order"
