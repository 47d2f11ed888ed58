"""Issue 51, Required 4: one of each. The net score, the "no graded functions" check, the
roster reader and the reader of nbgrader's cell metadata each live in one function; an AST
walk over autograder/ and cobotlab/ finds any twin that comes back, and the one function is
tested on the inputs its twins disagreed on. Fast: no course, no sandbox."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

from autograder import gradebook
from autograder.nbgrader_cells import CellRole, cell_role, nbgrader_metadata
from autograder.pipeline.begin import _course
from autograder.pipeline.problems import draw_problems, specs_of
from autograder.pipeline.record import grade_row

ROOT = Path(__file__).resolve().parent.parent
SOURCES = sorted([*(ROOT / "autograder").rglob("*.py"), *(ROOT / "cobotlab").rglob("*.py")])


def _functions():
    """(path relative to the repo, enclosing function name or "", node) of every node."""
    for path in SOURCES:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        stack = [(tree, "")]
        while stack:
            node, owner = stack.pop()
            for child in ast.iter_child_nodes(node):
                name = child.name if isinstance(child, (ast.FunctionDef,
                                                        ast.AsyncFunctionDef)) else owner
                yield str(path.relative_to(ROOT)), name, child
                stack.append((child, name))


@functools.cache
def _nodes() -> tuple:
    """_functions(), walked once, when a test first asks: at import, every test worker paid
    its 2 s of CPU while collecting, whether it ran this file or not."""
    return tuple(_functions())


def _names(node) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} | {
        n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)}


def test_the_net_score_is_computed_once():
    """Points less a late penalty: only gradebook.net_score subtracts one."""
    found = {(path, fn) for path, fn, node in _nodes()
             if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Sub)
             and any("penalty" in n for n in _names(node))}
    assert found == {("autograder/gradebook.py", "net_score")}


def test_the_no_graded_functions_check_is_made_once():
    found = {(path, fn) for path, fn, node in _nodes()
             if isinstance(node, ast.Constant) and isinstance(node.value, str)
             and "no graded functions are registered" in node.value}
    assert found == {("autograder/pipeline/problems.py", "specs_of")}


def test_one_reader_of_nbgrader_cell_metadata():
    """Only autograder/nbgrader_cells.py looks up the "nbgrader" entry of a cell's metadata
    (``resources["nbgrader"]`` is nbconvert's, a kept execution's ``nbgrader`` is ours)."""
    def receiver(node):
        while isinstance(node, (ast.Subscript, ast.Attribute, ast.Call)):
            node = node.value if not isinstance(node, ast.Call) else node.func
        return node.id if isinstance(node, ast.Name) else ""

    found = set()
    for path, fn, node in _nodes():
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                node.func.attr == "get" and node.args and \
                isinstance(node.args[0], ast.Constant) and node.args[0].value == "nbgrader":
            who = receiver(node.func.value)
        elif isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) and \
                node.slice.value == "nbgrader":
            who = receiver(node.value)
        else:
            continue
        if who not in ("resources", "kept"):
            found.add((path, fn))
    assert found == {("autograder/nbgrader_cells.py", "nbgrader_metadata")}


def test_one_roster_reader():
    found = {(path, fn) for path, fn, node in _nodes()
             if isinstance(node, ast.Attribute) and node.attr == "DictReader"
             and "roster" in fn}
    assert found == {("autograder/roster.py", "read_roster")}


@pytest.mark.parametrize("raw, penalty, net", [(7.456, 1.0, 6.46), (2.0, 5.0, 0.0),
                                               (3.0, None, 3.0), (0.0, 0.0, 0.0)])
def test_the_net_score_is_rounded_and_never_below_zero(raw, penalty, net):
    assert gradebook.net_score(raw, penalty) == net
    nb = {"penalty": penalty or 0.0}
    assert grade_row("lab0_frames", "ana", nb, raw, 10.0, "")["score"] == net


def test_an_unknown_assignment_is_refused_the_same_way_everywhere(tmp_path):
    with pytest.raises(ValueError, match="no graded functions .* 'nope'; known") as one:
        specs_of("nope")
    with pytest.raises(ValueError) as two:
        _course(tmp_path, "nope")
    with pytest.raises(ValueError) as three:
        draw_problems("nope", "ana", "a-secret-of-16-chars-or-more", None)
    assert str(one.value) == str(two.value) == str(three.value)


@pytest.mark.parametrize("cell", [
    {}, {"metadata": []}, {"metadata": {"nbgrader": "grade"}}, {"metadata": {"nbgrader": 1}},
    {"metadata": {"nbgrader": {"grade": "yes", "solution": 1, "grade_id": ["x"]}}}, [],
])
def test_malformed_cell_metadata_reads_as_no_role(cell):
    """A student can write anything into their notebook's metadata: it is no role, never
    an exception (the readers this one replaced crashed on some of these)."""
    assert cell_role(cell) == CellRole()
    assert isinstance(nbgrader_metadata(cell), dict)


def test_cell_roles_as_nbgrader_writes_them():
    def cell(**meta):
        return {"cell_type": "code", "metadata": {"nbgrader": meta}}

    test = cell_role(cell(grade=True, solution=False, grade_id="test_f", points=2))
    assert test.autograder_test and not test.read_only and test.grade_id == "test_f"
    assert not cell_role(cell(grade=True, solution=True)).autograder_test
    assert cell_role(cell(locked=True)).read_only
    assert not cell_role(cell(locked=True, grade=True)).read_only
    meta = {"comment": "x"}
    assert nbgrader_metadata({"metadata": {"nbgrader": meta}}) is meta   # edited in place
