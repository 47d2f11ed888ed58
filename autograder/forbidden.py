"""Routines a graded function must not call (the library that already does what the lab teaches).

A function spec names them (``FunctionSpec.forbidden``: ``"cv2.calibrateHandEye"``,
``"robots.geometry.invert"``, ...); ``solutions`` (the reference solvers) is forbidden to
every function. Two independent nets find a use:

* :func:`static_hits`, run by the trusted grader on the frozen notebook code: every name,
  attribute chain, ``from ... import`` alias and string handed to ``importlib`` /
  ``__import__`` / ``getattr`` / ``eval`` reachable from the graded function (through the
  notebook's own helper functions and module-level aliases) is resolved to a dotted name and
  compared with the forbidden ones. A notebook cell that calls ``cv2.calibrateHandEye`` to
  compare against OpenCV is fine; the graded function (or a helper it calls) doing so is not.
* :class:`Tripwire`, inside the sandbox and in ``check()``: a profile hook that records every
  call of a forbidden routine while the graded function runs, however it was reached.

Standard library only: the worker imports this module next to student code.
"""

from __future__ import annotations

import ast
import importlib
import sys
import threading
import types

__all__ = ["ALWAYS_FORBIDDEN", "Tripwire", "is_reference_solver", "matches", "static_hits"]

ALWAYS_FORBIDDEN = ("solutions",)
# CPython 3.11 builds AST objects with interpreter-wide recursion bookkeeping: two threads
# parsing at once (grade_course grades submissions in threads) can raise "SystemError: AST
# constructor recursion depth mismatch" (python/cpython#106905). One parse at a time.
_AST_LOCK = threading.Lock()
_DYNAMIC = {"getattr", "__import__", "import_module", "eval", "exec", "compile",
            "find_spec", "spec_from_file_location"}


def matches(dotted: str, forbidden: str) -> bool:
    """True when ``dotted`` (e.g. ``cv2.cv2.calibrateHandEye``) names ``forbidden``.

    Same top-level module and same final name (re-exports such as ``cv2.cv2.X`` count), or
    anything inside a forbidden module (``solutions.handeye.solve`` for ``solutions``).
    """
    parts, want = dotted.split("."), forbidden.split(".")
    if dotted == forbidden or dotted.startswith(forbidden + "."):
        return True
    return len(want) > 1 and len(parts) > 1 and parts[0] == want[0] and parts[-1] == want[-1]


def _fold(node: ast.AST) -> str | None:
    """The value of a constant string expression ("a" + "b", f-strings of constants,
    "".join([...]), reversed slices), or None when it is not one."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _fold(node.left), _fold(node.right)
        return left + right if left is not None and right is not None else None
    if isinstance(node, ast.JoinedStr):
        parts = [_fold(v.value if isinstance(v, ast.FormattedValue) else v) for v in node.values]
        return "".join(parts) if all(p is not None for p in parts) else None
    if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Slice):
        inner = _fold(node.value)
        s = node.slice
        if inner is not None and s.lower is None and s.upper is None and \
                isinstance(s.step, ast.UnaryOp) and isinstance(s.step.op, ast.USub) and \
                isinstance(s.step.operand, ast.Constant) and s.step.operand.value == 1:
            return inner[::-1]
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
            node.func.attr == "join" and len(node.args) == 1:
        sep = _fold(node.func.value)
        items = node.args[0]
        if sep is not None and isinstance(items, (ast.List, ast.Tuple)):
            parts = [_fold(x) for x in items.elts]
            if all(p is not None for p in parts):
                return sep.join(parts)
    return None


class _Notebook:
    """Module-level definitions, assignments and import aliases of the notebook's code."""

    def __init__(self, cells: list[str]):
        self.defs: dict[str, ast.AST] = {}
        self.assigned: dict[str, list[ast.AST]] = {}
        self.aliases: dict[str, str] = {}
        self.star: list[str] = []
        self.imported: set[str] = set()
        for source in cells:
            try:
                with _AST_LOCK:
                    tree = ast.parse(source)
            except (SyntaxError, ValueError, RecursionError, MemoryError):
                continue
            for node in ast.walk(tree):  # imports anywhere count (inside functions too)
                self._imports(node)
            for node in tree.body:
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    self.defs[node.name] = node
                elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
                    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                    for t in targets:
                        for name in ast.walk(t):
                            if isinstance(name, ast.Name) and node.value is not None:
                                self.assigned.setdefault(name.id, []).append(node.value)

    def _imports(self, node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            for a in node.names:
                self.imported.add(a.name)
                if a.asname:
                    self.aliases[a.asname] = a.name
                else:
                    top = a.name.split(".")[0]
                    self.aliases.setdefault(top, top)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            self.imported.add(node.module)
            for a in node.names:
                if a.name == "*":
                    self.star.append(node.module)
                else:
                    self.aliases[a.asname or a.name] = f"{node.module}.{a.name}"


def _chain(node: ast.AST, nb: _Notebook) -> str | None:
    """The dotted name an expression such as ``geo.invert`` or ``__import__('cv2').X`` means."""
    if isinstance(node, ast.Name):
        return nb.aliases.get(node.id, node.id)
    if isinstance(node, ast.Attribute):
        base = _chain(node.value, nb)
        return f"{base}.{node.attr}" if base else None
    if isinstance(node, ast.Call):
        func = _chain(node.func, nb) or ""
        last = func.rsplit(".", 1)[-1]
        if last in ("__import__", "import_module") and node.args:
            return _fold(node.args[0])
        if last == "getattr" and len(node.args) >= 2:
            base, attr = _chain(node.args[0], nb), _fold(node.args[1])
            return f"{base}.{attr}" if base and attr else None
    return None


def is_reference_solver(func) -> bool:
    """True for a function defined in the reference solvers themselves (``solutions.*``).

    The instructor's self-check scores the reference solvers with ``evaluate``: a reference
    does not *call* the answer key, it is the answer key, so :data:`ALWAYS_FORBIDDEN` does not
    apply to it. Student code never gets this pass where it counts: ``solutions`` is not
    importable in the student install nor in the grader's sandbox, and the grader's static
    scan reads the notebook's source, not ``__module__``.
    """
    module = str(getattr(func, "__module__", "") or "")
    return any(module == m or module.startswith(m + ".") for m in ALWAYS_FORBIDDEN)


def static_hits(cells: list[str], function: str, forbidden,
                always=ALWAYS_FORBIDDEN) -> list[str]:
    """The forbidden names (of ``forbidden`` and ``always``, by default
    :data:`ALWAYS_FORBIDDEN`) that ``function``, or anything it reaches in the notebook's
    code, names; sorted, empty when clean."""
    names = tuple(forbidden) + tuple(always)
    nb = _Notebook(cells)
    hits: set[str] = set()
    seen: set[int] = set()
    todo: list[ast.AST] = [nb.defs[function]] if function in nb.defs else []

    def check(dotted: str | None) -> None:
        if dotted:
            hits.update(f for f in names if matches(dotted, f))

    while todo:
        node = todo.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        for sub in ast.walk(node):
            if isinstance(sub, ast.Name) and isinstance(sub.ctx, ast.Load):
                if sub.id in nb.defs and sub.id != function:
                    todo.append(nb.defs[sub.id])
                todo.extend(nb.assigned.get(sub.id, ()))
                check(nb.aliases.get(sub.id))
                for module in nb.star:
                    check(f"{module}.{sub.id}")
            elif isinstance(sub, (ast.Attribute, ast.Call)):
                check(_chain(sub, nb))
            if isinstance(sub, ast.Call):
                func = (_chain(sub.func, nb) or "").rsplit(".", 1)[-1]
                if func in _DYNAMIC:
                    for arg in sub.args:
                        text = _fold(arg)
                        if text:  # a string handed to a dynamic lookup: any mention counts
                            hits.update(f for f in names if f.rsplit(".", 1)[-1] in text
                                        or f in text)
            elif isinstance(sub, (ast.Import, ast.ImportFrom)):
                module = sub.module if isinstance(sub, ast.ImportFrom) else None
                for a in sub.names:
                    check(f"{module}.{a.name}" if module else a.name)
    return sorted(hits)


# --------------------------------------------------------------------------- at run time


def _resolve(dotted: str):
    """The object ``dotted`` names, importing its module; None when it does not exist."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except Exception:  # noqa: BLE001 - a missing optional module is not an error here
            continue
        try:
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


class Tripwire:
    """Record calls of the forbidden routines made while the ``with`` block runs.

    A profile hook compares each called C function (``cv2.calibrateHandEye``) by identity
    and each Python function (``robots.geometry.invert``) by its code object, so an alias,
    a ``getattr`` or a reference saved before the call is caught as well. Importing
    ``solutions`` is caught by name. ``hits`` holds what was called.
    """

    def __init__(self, forbidden, always=ALWAYS_FORBIDDEN):
        self.hits: set[str] = set()
        self._c: dict[int, str] = {}
        self._code: dict[types.CodeType, str] = {}
        self._modules = [f for f in tuple(forbidden) + tuple(always) if "." not in f]
        for name in forbidden:
            if "." not in name:
                continue
            obj = _resolve(name)
            code = getattr(obj, "__code__", None)
            if isinstance(code, types.CodeType):
                self._code[code] = name
            elif obj is not None:
                self._c[id(obj)] = name
        self._previous = None

    def _hook(self, frame, event, arg):
        if event == "c_call":
            name = self._c.get(id(arg))
            if name:
                self.hits.add(name)
        elif event == "call":
            name = self._code.get(frame.f_code)
            if name:
                self.hits.add(name)
            module = frame.f_globals.get("__name__", "")
            for m in self._modules:
                if module == m or str(module).startswith(m + "."):
                    self.hits.add(m)

    def __enter__(self):
        self._previous = sys.getprofile()
        sys.setprofile(self._hook)
        return self

    def __exit__(self, *exc):
        sys.setprofile(self._previous)
        return False
