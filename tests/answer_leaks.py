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
"""

from __future__ import annotations

import ast
import builtins
import importlib
import inspect
import json
import pkgutil
import textwrap
from dataclasses import dataclass
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


def find_answers(paths, needles: list[Needle]) -> list[str]:
    """Where any needle occurs among the function defs of ``paths`` (files, or folders
    searched for .py and .ipynb files): "<file>: def <name> is <origin>" per finding."""
    by_form: dict[str, list[str]] = {}
    for needle in needles:
        by_form.setdefault(needle.form, []).append(needle.origin)
    files = []
    for path in map(Path, paths):
        files += sorted(p for p in path.rglob("*") if p.suffix in (".py", ".ipynb")) \
            if path.is_dir() else [path]
    findings = []
    for file in files:
        for code in code_of(file):
            for node in functions_in(code):
                for origin in by_form.get(normalise(node), ()):
                    findings.append(f"{file}: def {node.name} is {origin}")
    return findings
