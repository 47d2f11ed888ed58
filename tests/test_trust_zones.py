"""The grader's trust zones (issue 39, item 2), read from the source.

What runs inside the sandbox is one package, ``autograder.inside``, which the worker's view
binds whole and which imports nothing of the trusted side (the grader, the specs, the
answers): only the standard library, numpy and itself. The worker's view holds that package
and the student-facing practice data, nothing else of ``autograder``.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import autograder
from autograder import views

INSIDE = Path(autograder.__file__).parent / "inside"
ALLOWED_THIRD_PARTY = {"numpy"}


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of its code (functions included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:   # relative: inside the package by construction
                found.add("autograder.inside")
            elif node.module == "autograder" or node.module.startswith("autograder."):
                found.update(f"{node.module}.{a.name}" if node.module == "autograder"
                             else node.module for a in node.names)
            else:
                found.add(node.module)
    return found


def test_the_inside_package_imports_nothing_of_the_trusted_side():
    modules = sorted(INSIDE.glob("*.py"))
    assert {p.stem for p in modules} >= {"__init__", "worker", "isolate", "syscalls", "wire",
                                         "standin", "tripwire"}
    wrong = {}
    for path in modules:
        for name in _imports(path):
            top = name.split(".")[0]
            if name == "autograder.inside" or name.startswith("autograder.inside."):
                continue
            if top in sys.stdlib_module_names or top in ALLOWED_THIRD_PARTY:
                continue
            wrong.setdefault(path.name, []).append(name)
    assert not wrong, f"autograder/inside imports the trusted side or more: {wrong}"


def test_the_imports_walk_sees_what_it_must_refuse(tmp_path):
    """The walk above is no test that cannot fail: a module that imports the grader, even
    inside a function, is found."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\ndef f():\n    from autograder import grading\n"
                   "    from autograder.specs import lab0_frames\n    import solutions\n")
    assert _imports(bad) == {"os", "autograder.grading", "autograder.specs", "solutions"}


def test_the_workers_view_binds_the_inside_package_and_nothing_trusted():
    assert "inside" in views.WORKER_MODULES
    trusted = {"pipeline", "secret.py", "course.py", "checks.py", "executions.py", "record.py", "gradebook.py",
               "specs", "scoring", "secret", "registry.py", "practice.py", "cluster.py"}
    assert not trusted & set(views.WORKER_MODULES), views.WORKER_MODULES
    # the rest of what the worker sees of autograder is what a lab notebook imports
    assert set(views.WORKER_MODULES) - {"inside"} == {"__init__.py", "datasets.py",
                                                      "synthetic.py", "data"}


def _top_level_autograder_imports(path: Path) -> set[str]:
    """The autograder modules ``path`` imports when it is imported (not inside functions),
    as files or folders below autograder/ ("checks.py", "scoring")."""
    found = set()

    def visit(node) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(child, ast.ImportFrom) and child.module and not child.level \
                    and child.module.split(".")[0] == "autograder":
                parts = child.module.split(".")[1:]
                names = [parts] if parts else [[a.name] for a in child.names]
                for name in names:
                    found.add(name[0] if (ROOT / name[0]).is_dir() else f"{name[0]}.py")
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return found


ROOT = Path(autograder.__file__).parent


def test_nbgrader_kernels_view_holds_every_module_the_public_scoring_imports():
    """nbgrader's own kernel imports autograder.checks for the hidden tests: every module
    of autograder that import pulls in must be in its view, or every hidden test fails."""
    seen, todo = set(), ["checks.py"]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = ROOT / name / "__init__.py" if (ROOT / name).is_dir() else ROOT / name
        todo.extend(_top_level_autograder_imports(path))
    missing = seen - set(views.KERNEL_MODULES)
    assert not missing, f"autograder.checks imports {sorted(missing)}, not in KERNEL_MODULES"
    assert {"checks.py", "outcomes.py", "errors.py"} <= seen
