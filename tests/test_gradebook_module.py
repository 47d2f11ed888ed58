"""autograder/gradebook.py is the one module that opens nbgrader's gradebook.

Every other module of ``autograder``, ``cobotlab`` and ``benchmarks`` goes through it: none
imports nbgrader.api's ``Gradebook`` or calls ``sqlite3.connect``. The walk reads each
module's syntax tree (imports inside functions too, whatever alias), so a comment or a
string that names them is no finding. Tests may still open a gradebook to assert on it.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCANNED = ("autograder", "cobotlab", "benchmarks")
THE_MODULE = "autograder/gradebook.py"
_DYNAMIC_IMPORTS = {"import_module", "__import__"}


def _openings(source: str) -> list[str]:
    """Each place ``source`` imports nbgrader.api's Gradebook or calls sqlite3's connect,
    as ``line N: what``."""
    tree = ast.parse(source)
    sqlite_names: set[str] = set()   # names bound to the sqlite3 module
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "sqlite3":
                    sqlite_names.add(alias.asname or "sqlite3")
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            for alias in node.names:
                if (module == "nbgrader.api" or module.startswith("nbgrader.api.")) \
                        and alias.name in ("Gradebook", "*"):
                    found.append(f"line {node.lineno}: from {module} import {alias.name}")
                if module == "sqlite3" and alias.name in ("connect", "*"):
                    found.append(f"line {node.lineno}: from sqlite3 import {alias.name}")
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in _DYNAMIC_IMPORTS and node.args \
                    and isinstance(node.args[0], ast.Constant) \
                    and node.args[0].value in ("sqlite3", "nbgrader.api"):
                found.append(f"line {node.lineno}: {name}({node.args[0].value!r})")
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        if node.attr == "Gradebook":   # nbgrader.api.Gradebook, api.Gradebook, ...
            found.append(f"line {node.lineno}: .Gradebook")
        elif node.attr == "connect" and isinstance(node.value, ast.Name) \
                and node.value.id in sqlite_names:
            found.append(f"line {node.lineno}: {node.value.id}.connect")
    return sorted(found)


def _modules():
    for top in SCANNED:
        for path in sorted((ROOT / top).rglob("*.py")):
            if "__pycache__" not in path.parts:
                yield path.relative_to(ROOT).as_posix(), path


def test_only_the_gradebook_module_opens_a_gradebook():
    scanned = dict(_modules())
    assert THE_MODULE in scanned and len(scanned) > 50, sorted(scanned)
    wrong = {}
    for name, path in scanned.items():
        if name == THE_MODULE:
            continue
        found = _openings(path.read_text(encoding="utf-8"))
        if found:
            wrong[name] = found
    assert not wrong, ("only autograder/gradebook.py may open nbgrader's gradebook; move "
                       f"these into it: {wrong}")


def test_the_walk_sees_the_gradebook_module_itself():
    """The walk above is no test that cannot fail: the real module is found opening it,
    both ways."""
    found = _openings((ROOT / THE_MODULE).read_text(encoding="utf-8"))
    assert any("from nbgrader.api import Gradebook" in f for f in found), found
    assert any("sqlite3.connect" in f for f in found), found


def test_the_walk_finds_every_spelling_and_ignores_comments_and_strings():
    bad = (
        "import os\n"
        "import sqlite3 as lite\n"
        "import nbgrader.api\n"
        "from nbgrader import api\n"
        "def f(db):\n"
        "    from nbgrader.api import Gradebook\n"
        "    from sqlite3 import connect\n"
        "    lite.connect(db)\n"
        "    api.Gradebook(db)\n"
        "    nbgrader.api.Gradebook(db)\n"
        "    __import__('sqlite3')\n"
    )
    found = _openings(bad)
    assert found == sorted([
        "line 6: from nbgrader.api import Gradebook", "line 7: from sqlite3 import connect",
        "line 8: lite.connect", "line 9: .Gradebook", "line 10: .Gradebook",
        "line 11: __import__('sqlite3')"]), found
    harmless = (
        "# sqlite3.connect(db) and `from nbgrader.api import Gradebook` in a comment\n"
        "'''Gradebook(f\"sqlite:///{db}\") in a docstring'''\n"
        "import nbgrader.api as api\n"
        "from nbgrader.api import MissingEntry\n"
        "api.get_alembic_version = None\n"
        "socket = None\n"
        "socket.connect(('host', 1))\n"
    )
    assert _openings(harmless) == []


def test_nbgrader_hooks_stays_light():
    """nbgrader imports autograder.nbgrader_hooks in its own process: it opens no gradebook,
    so it loads neither this module nor nbgrader's database layer."""
    code = ("import sys, autograder.nbgrader_hooks\n"
            "print(sorted(m for m in ('autograder.gradebook', 'nbgrader.api', 'sqlalchemy', "
            "'sqlite3') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, check=True)
    assert done.stdout.strip() == "[]", done.stdout + done.stderr
