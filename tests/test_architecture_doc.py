"""docs/architecture.md is true: its ten-line scoring example runs as written (no sandbox,
no course), and every file and function it names exists."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "architecture.md").read_text()


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
    names = set(re.findall(r"`((?:course|grading|executions|checks)\.[A-Za-z_]+)`", DOC))
    assert len(names) >= 8, names
    for dotted in names:
        module, attr = dotted.split(".")
        assert hasattr(importlib.import_module(f"autograder.{module}"), attr), dotted


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


def test_the_stage_table_names_the_functions_the_line_calls():
    source = (ROOT / "autograder" / "course.py").read_text()
    body = source.split("def grade_course(", 1)[1].split("\ndef ", 1)[0]
    table = DOC.split("| stage | function |", 1)[1].split("\n\n", 1)[0]
    for stage in ("_begin", "_freeze", "_problems", "_execute", "_score", "_record",
                  "_end_run"):
        assert f"{stage}(" in body, f"grade_course no longer calls {stage}"
        assert f"course.{stage}" in table or stage == "_freeze", stage
