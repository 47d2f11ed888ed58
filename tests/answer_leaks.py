"""Find answer code in files: the reference solutions and the private answer functions,
compared as normalised syntax trees so that renaming, docstrings and annotations hide nothing.

A function is normalised by :func:`normalise`: docstrings, annotations and decorators dropped,
every identifier it binds or reads (its own name, parameters, variables, globals such as an
imported module's alias) replaced by a placeholder numbered in order of first appearance.
Attribute names (``np.linalg.pinv``), keywords and constants stay: they are what the code
does. Two functions that differ only in naming and comments normalise to the same string.

:func:`answer_functions` collects the needles (each function def of every solution region of
the source notebooks, and every function of each private spec module's ``ANSWERS``, nested
defs included); :func:`find_answers` reports where any of them occurs among the function defs
of some files (.py sources, and the code cells of .ipynb notebooks).

:func:`find_near_copies` finds what the exact search cannot: a copy with a few lines changed.
The same functions are cut into statements, each normalised on its own (:func:`statements`),
and a function def of the files that holds at least ``NEAR_SHARE`` of a reference's
non-trivial statements, and at least ``NEAR_STATEMENTS`` of them, is reported.
"""

from __future__ import annotations

import ast
import builtins
import importlib
import inspect
import json
import pkgutil
import textwrap
from collections import Counter
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LABS_DIR = ROOT / "labs"

_FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)


class _Normaliser(ast.NodeTransformer):
    """Renames identifiers to placeholders in order of appearance; drops what says nothing."""

    def __init__(self, bound: set[str]):
        self.names: dict[str, str] = {}
        self.bound = bound

    def _name(self, name: str) -> str:
        # A builtin the function does not rebind (len, range) is what the code calls, as an
        # attribute is; renaming it would only make unrelated functions look alike.
        if hasattr(builtins, name) and name not in self.bound:
            return name
        return self.names.setdefault(name, f"_{len(self.names)}")

    @staticmethod
    def _without_docstring(body: list) -> list:
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                and isinstance(body[0].value.value, str):
            body = body[1:]
        return body or [ast.Pass()]

    def _function(self, node):
        node.name = self._name(node.name)
        node.decorator_list = []
        node.returns = None
        node.type_comment = None
        node.body = self._without_docstring(node.body)
        self.generic_visit(node)
        return node

    visit_FunctionDef = visit_AsyncFunctionDef = _function

    def visit_ClassDef(self, node):
        node.name = self._name(node.name)
        node.decorator_list = []
        node.body = self._without_docstring(node.body)
        self.generic_visit(node)
        return node

    def visit_arg(self, node):
        node.arg = self._name(node.arg)
        node.annotation = None
        node.type_comment = None
        return node

    def visit_Name(self, node):
        node.id = self._name(node.id)
        node.ctx = ast.Load()  # a store and a load of one name are the same name
        return node

    def visit_ExceptHandler(self, node):
        if node.name:
            node.name = self._name(node.name)
        self.generic_visit(node)
        return node

    def visit_Global(self, node):
        node.names = [self._name(n) for n in node.names]
        return node

    visit_Nonlocal = visit_Global

    def visit_alias(self, node):
        # `import numpy as N` binds N; the module itself is what it is.
        if node.asname:
            node.asname = self._name(node.asname)
        return node

    def visit_AnnAssign(self, node):
        if node.value is None:
            return None
        return self.visit(ast.Assign(targets=[node.target], value=node.value, lineno=0))


def _bound_names(tree: ast.AST) -> set[str]:
    bound = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
            bound.add(node.id)
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            bound.add(node.name)
        elif isinstance(node, ast.alias):
            bound.add(node.asname or node.name.split(".")[0])
        elif isinstance(node, ast.ExceptHandler) and node.name:
            bound.add(node.name)
    return bound


def normalise(function: ast.AST) -> str:
    """The normalised form of one function def (or lambda): equal for renamed copies."""
    tree = ast.parse(ast.unparse(function))  # a copy, never the caller's
    tree = _Normaliser(_bound_names(tree)).visit(tree)
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


def functions_in(source: str) -> list[ast.AST]:
    """Every function def in ``source`` (nested ones too); [] if it does not parse."""
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return []
    return [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]


def notebook_code(path: Path) -> list[str]:
    """The code cells of a notebook, IPython magics and shell lines left out."""
    nb = json.loads(Path(path).read_text())
    cells = []
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "code":
            continue
        source = cell.get("source", "")
        source = "".join(source) if isinstance(source, list) else source
        cells.append("\n".join(line for line in source.splitlines()
                               if not line.lstrip().startswith(("%", "!"))))
    return cells


@dataclass(frozen=True)
class Needle:
    """One piece of answer code: where it comes from and its normalised form."""

    origin: str
    form: str


def solution_regions(labs_dir: Path = LABS_DIR) -> list[tuple[str, str]]:
    """(origin, code) of every solution region of the source notebooks: the cell with its
    ``### BEGIN SOLUTION`` / ``### END SOLUTION`` lines removed (the def around them kept)."""
    found = []
    for path in sorted(Path(labs_dir).glob("*/*.ipynb")):
        for index, cell in enumerate(notebook_code(path)):
            if "### BEGIN SOLUTION" not in cell:
                continue
            code = "\n".join(line for line in cell.splitlines()
                             if line.strip() not in ("### BEGIN SOLUTION", "### END SOLUTION"))
            found.append((f"{path.relative_to(Path(labs_dir).parent)} cell {index}", code))
    return found


def private_answers() -> list[tuple[str, object]]:
    """(origin, function) of every function in each private spec module's ``ANSWERS``."""
    import autograder.specs as specs

    found = []
    for module_info in sorted(pkgutil.iter_modules(specs.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"autograder.specs.{module_info.name}")
        for func in module.ANSWERS:
            found.append((f"autograder/specs/{module_info.name}.py {func.__name__}", func))
    return found


def answer_functions(labs_dir: Path = LABS_DIR) -> list[Needle]:
    """Every function def of the solution regions and of the private ``ANSWERS``."""
    needles = []
    for origin, code in solution_regions(labs_dir):
        for node in functions_in(code):
            needles.append(Needle(f"{origin}: def {node.name}", normalise(node)))
    for origin, func in private_answers():
        for node in functions_in(textwrap.dedent(inspect.getsource(func))):
            needles.append(Needle(f"{origin}: def {node.name}", normalise(node)))
    return needles


def code_of(path: Path) -> list[str]:
    """The Python code a file holds: a .py file's text, a notebook's code cells, else none."""
    path = Path(path)
    if path.suffix == ".py":
        return [path.read_text(errors="replace")]
    if path.suffix == ".ipynb":
        return notebook_code(path)
    return []


def _files(paths) -> list[Path]:
    """``paths`` with each folder replaced by the .py and .ipynb files under it."""
    files = []
    for path in map(Path, paths):
        files += sorted(p for p in path.rglob("*") if p.suffix in (".py", ".ipynb")) \
            if path.is_dir() else [path]
    return files


@cache
def _forms(code: str) -> tuple[tuple[str, str], ...]:
    """(name, normalised form) of every function def in ``code``. Kept by the code's text:
    a test run searches the same modules more than once (the student wheel, then the
    grading views' copies of them), and normalising is most of a search's CPU."""
    return tuple((node.name, normalise(node)) for node in functions_in(code))


def find_answers(paths, needles: list[Needle]) -> list[str]:
    """Where any needle occurs among the function defs of ``paths`` (files, or folders
    searched for .py and .ipynb files): "<file>: def <name> is <origin>" per finding."""
    by_form: dict[str, list[str]] = {}
    for needle in needles:
        by_form.setdefault(needle.form, []).append(needle.origin)
    findings = []
    for file in _files(paths):
        for code in code_of(file):
            for name, form in _forms(code):
                for origin in by_form.get(form, ()):
                    findings.append(f"{file}: def {name} is {origin}")
    return findings


# --------------------------------------------------------------------------- near copies
#
# Exact matching misses a copy with a line or two changed (robots/perception.py once shipped
# lab 5's RANSAC plane fit with NaN filtering and the normal's orientation left out). The
# measure below compares functions statement by statement instead: the share of a reference's
# statements that a candidate function also holds.

# The nodes of a statement that only moves names and constants around (``return x``,
# ``best = None``, ``continue``, a bare ``raise``, a docstring, an import): such a statement
# says nothing about how an answer is computed, and nearly every function has one, so it is
# never counted.
_TRIVIAL_NODES = (ast.Expr, ast.Assign, ast.Return, ast.Pass, ast.Break, ast.Continue,
                  ast.Raise, ast.Delete, ast.Global, ast.Nonlocal, ast.Import, ast.ImportFrom,
                  ast.alias, ast.Name, ast.Constant, ast.Tuple, ast.List, ast.Starred,
                  ast.expr_context)

# A candidate holding at least this share of a reference's statements, and at least this
# many of them, is a near copy. Four statements are the least that make an algorithm rather
# than a coincidence (two functions may both convert their input and loop over a range).
NEAR_SHARE = 0.5
NEAR_STATEMENTS = 4


# The fields of a compound statement that hold statements (or handlers and cases holding
# them): cut from the header, their statements counted one by one.
_BLOCKS = ("body", "orelse", "finalbody", "handlers", "cases")


def _is_trivial(node: ast.AST) -> bool:
    return all(isinstance(n, _TRIVIAL_NODES) for n in ast.walk(node))


def statements(function: ast.AST) -> list[str]:
    """The normalised non-trivial statements of one function def, nested blocks included,
    in order. A compound statement counts as its header (``for i in range(n):`` without its
    body), and its body's statements count one by one; a nested def counts as its body.

    Each statement is normalised on its own (placeholders numbered from ``_0`` again), so
    that a renamed variable, a statement inserted before it or two statements swapped change
    nothing; builtins the function rebinds are renamed as :func:`normalise` renames them."""
    tree = ast.parse(ast.unparse(function))  # a copy: headers are cut from their bodies
    bound = _bound_names(tree)
    forms: list[str] = []

    def visit(body: list) -> None:
        for stmt in _Normaliser._without_docstring(body):
            if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                visit(stmt.body)
                continue
            blocks = []
            for field in _BLOCKS:
                if getattr(stmt, field, None):
                    blocks.append(getattr(stmt, field))
                    setattr(stmt, field, [])
            header = _Normaliser(bound).visit(stmt)
            if header is not None and not _is_trivial(header):
                forms.append(ast.dump(header, annotate_fields=False, include_attributes=False))
            for block in blocks:
                for part in block:   # an except handler's or a match case's body
                    visit(part.body if isinstance(part, (ast.excepthandler, ast.match_case))
                          else [part])

    root = tree.body[0]
    visit(root.body if isinstance(root, (ast.FunctionDef, ast.AsyncFunctionDef)) else [root])
    return forms


@dataclass(frozen=True)
class Reference:
    """One piece of answer code (a def of a solution region or of a private answer): where
    it comes from and its normalised non-trivial statements (see :func:`statements`)."""

    origin: str
    forms: tuple[str, ...]


def reference_statements(labs_dir: Path = LABS_DIR) -> list[Reference]:
    """The statements of every function def of the source notebooks' solution regions and
    of the private ``ANSWERS`` (the same functions :func:`answer_functions` collects)."""
    found = []
    for origin, code in solution_regions(labs_dir):
        for node in functions_in(code):
            found.append(Reference(f"{origin}: def {node.name}", tuple(statements(node))))
    for origin, func in private_answers():
        for node in functions_in(textwrap.dedent(inspect.getsource(func))):
            found.append(Reference(f"{origin}: def {node.name}", tuple(statements(node))))
    return found


@dataclass(frozen=True)
class Resemblance:
    """How much of a reference one candidate function holds: ``matched`` of the reference's
    ``total`` statements (each of the candidate's statements matches one at most)."""

    reference: str
    where: str
    matched: int
    total: int

    @property
    def share(self) -> float:
        return self.matched / self.total if self.total else 0.0

    @property
    def near_copy(self) -> bool:
        return self.share >= NEAR_SHARE and self.matched >= NEAR_STATEMENTS

    def __str__(self) -> str:
        return (f"{self.where} holds {self.matched} of {self.total} statements "
                f"({self.share:.0%}) of {self.reference}")


def resemblances(paths, references: list[Reference]):
    """Every (reference, function def of ``paths``) pair sharing a statement, as
    :class:`Resemblance` (``paths``: files, or folders searched for .py and .ipynb files)."""
    wanted = [(ref, Counter(ref.forms)) for ref in references if ref.forms]
    for file in _files(paths):
        for code in code_of(file):
            for node in functions_in(code):
                held = Counter(statements(node))
                for ref, forms in wanted:
                    matched = sum((forms & held).values())
                    if matched:
                        yield Resemblance(ref.origin, f"{file}: def {node.name}", matched,
                                          len(ref.forms))


def closest_functions(paths, references: list[Reference]) -> dict[str, Resemblance]:
    """For each reference (by origin), the function def of ``paths`` that holds the largest
    share of its statements; no entry when no function holds any."""
    best: dict[str, Resemblance] = {}
    for found in resemblances(paths, references):
        if found.reference not in best or found.matched > best[found.reference].matched:
            best[found.reference] = found
    return best


def find_near_copies(paths, references: list[Reference]) -> list[str]:
    """Where a function def of ``paths`` is a near copy of a reference (at least
    ``NEAR_SHARE`` of its statements and ``NEAR_STATEMENTS`` of them): one line each."""
    return [str(r) for r in resemblances(paths, references) if r.near_copy]
