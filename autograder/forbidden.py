"""Routines a graded function must not call (the library that already does what the lab teaches).

A function spec names them (``FunctionSpec.forbidden``: ``"cv2.calibrateHandEye"``,
``"robots.geometry.invert"``, ...); ``solutions`` (the reference solvers) is forbidden to
every function. A notebook cell that calls ``cv2.calibrateHandEye`` to compare against
OpenCV is fine; the graded function, or anything it reaches, doing so is not.

The rule, and who decides
-------------------------
The verdict is the trusted grader's. The worker runs student code, so what it reports can be
forged or left out; it can only *add* a violation, never clear one, and a forbidden routine
called while a graded function runs answers nothing the grader would credit, whatever the
worker reports. Three nets:

* :func:`static_hits`, in the grader, on the frozen notebook code: authoritative. It starts
  from everything the notebook binds to the graded name at module level (every ``def``,
  every assignment, wherever it sits: a lambda, an alias of the library routine, a
  ``functools.partial``, an instance of a class with ``__call__``, a decorated function, a
  name declared ``global`` in a function) and follows every name those reach to the
  notebook's own definitions, assignments and import aliases. What a module-level object
  is given counts as part of it (``box.f = ...``, ``box[k] = ...``, ``queue.put(...)`` in a
  function that does not own ``queue``): a thread started at load time that hands its
  results over a queue is reached through the queue. A dotted name, alias, ``from ...
  import``, or a constant string handed to ``getattr`` / ``importlib`` / ``__import__`` /
  ``eval`` / ``sys.modules[...]`` / ``vars(m)[...]`` is resolved and compared with the
  forbidden names. Dynamic lookups count as uses: a module that holds a forbidden routine
  (``robots.geometry`` holds ``robots.geometry.invert``; ``robots`` and ``cv2`` count too)
  used as a value rather than through a plain attribute (``vars(geo)``, ``geo.__dict__``,
  ``getattr(geo, name)``, ``helper(geo)``) uses every forbidden routine it holds; a module,
  namespace or code named at run time (``importlib.import_module(name)``,
  ``sys.modules`` or ``globals()`` looked up by a computed key, ``eval(text)``) uses
  every forbidden routine of the spec.
* The worker's :class:`Guard` (with :class:`Tripwire`), inside the sandbox: while a graded
  function runs, each forbidden routine is *poisoned*: the routine object itself (so every
  alias, saved reference, ``partial`` and dynamic lookup of it, in every thread, with or
  without a profile hook) runs code that records the call and raises
  :class:`ForbiddenCall` instead of answering. A Python function gets its ``__code__``
  swapped for the call's duration; a C routine (``cv2.*``) is replaced in every loaded
  module by a pass-through Python function before any student code runs, and that is
  poisoned in turn. So a call the static scan could not see earns nothing: the answer is
  missing, no report needed. The worker turns what a returned object does on conversion
  (a list subclass's ``__iter__``) into plain values while still poisoned.
* :class:`Tripwire`'s profile hook (``sys.setprofile``, and ``threading.setprofile`` for
  threads started during the call), in the worker and in ``check()`` in the student's
  kernel, where nothing is poisoned: it records calls of the routines' own code objects
  and C functions, so a copy made with ``types.FunctionType(f.__code__, ...)`` is seen too.
  A hook removed during the call (``sys.setprofile(None)``) or a poisoned routine whose
  code was put back counts as a call of every forbidden routine of the spec.

What no in-process net can settle, and the static scan is there for: student code may
rewrite the worker itself (its modules are reachable through ``sys.modules`` and the
garbage collector), undo a poisoning it can see, or rebuild a routine from its source file;
rebuilding is indistinguishable from copying the routine's code into the notebook, which
no grader tells apart from writing it. Such code, where the graded function reaches it,
names the routine or its module and is caught by :func:`static_hits`.

The static scan is the grader's (and check()'s); the run-time nets (:mod:`autograder.inside.tripwire`)
run inside the sandbox.
"""

from __future__ import annotations

import ast
import threading

# The run-time nets live with the rest of what runs inside the sandbox; the rule's names
# are re-exported here for the grader, check() and the tests.
from autograder.inside.tripwire import (  # noqa: F401
    ALWAYS_FORBIDDEN,
    ForbiddenCall,
    Guard,
    Tripwire,
    matches,
    resolve,
)

__all__ = ["ALWAYS_FORBIDDEN", "ForbiddenCall", "Guard", "Tripwire", "is_reference_solver",
           "matches", "resolve", "static_hits"]

# CPython 3.11 builds AST objects with interpreter-wide recursion bookkeeping: two threads
# parsing at once (grade_course grades submissions in threads) can raise "SystemError: AST
# constructor recursion depth mismatch" (python/cpython#106905). One parse at a time.
_AST_LOCK = threading.Lock()
# Calls handed a name or code as text: a constant is searched for the forbidden names; a
# computed one (all but getattr, whose object is known) could name any of them.
_DYNAMIC = {"getattr", "__import__", "import_module", "eval", "exec", "compile",
            "find_spec", "spec_from_file_location"}
_NAMED_AT_RUN_TIME = _DYNAMIC - {"getattr"}
# Called without an argument, each gives a namespace that holds the notebook's modules.
_NAMESPACES = ("globals", "vars", "locals")
_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)


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


def _scope_body(root: ast.AST) -> list[ast.AST]:
    if isinstance(root, ast.Lambda):
        return [root.body]
    return list(getattr(root, "body", ()))


def _own_scope(root: ast.AST):
    """Every node of ``root``'s own scope (a module's or a function's): nested functions and
    classes are yielded but not entered."""
    todo = _scope_body(root)
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, _SCOPES):
            todo.extend(ast.iter_child_nodes(node))


def _locals(func: ast.AST) -> set[str]:
    """The names a function (or lambda) binds in its own scope, ``global`` ones and a
    comprehension's own variables left out."""
    args = func.args
    owned = {a.arg for a in args.posonlyargs + args.args + args.kwonlyargs}
    owned.update(a.arg for a in (args.vararg, args.kwarg) if a is not None)
    declared: set[str] = set()
    comprehended = {id(n) for node in _own_scope(func) if isinstance(node, ast.comprehension)
                    for n in ast.walk(node.target)}
    for node in _own_scope(func):
        if isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            if id(node) not in comprehended:
                owned.add(node.id)
        elif isinstance(node, (ast.Global, ast.Nonlocal)):
            declared.update(node.names)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            owned.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            owned.update((a.asname or a.name).split(".")[0] for a in node.names)
    return owned - declared


def _call_name(node: ast.Call, nb: _Notebook) -> str:
    """The last part of what a call calls, aliases resolved (``import_module`` for
    ``importlib.import_module`` and for ``im`` after ``from importlib import import_module
    as im``)."""
    return (_chain(node.func, nb) or "").rsplit(".", 1)[-1]


def _namespace_call(node: ast.AST, nb: _Notebook) -> bool:
    """``globals()``, ``vars()`` or ``locals()``: the namespace itself."""
    return isinstance(node, ast.Call) and not node.args and not node.keywords and \
        _call_name(node, nb) in _NAMESPACES


def _base_name(node: ast.AST, nb: _Notebook) -> str | None:
    """The module-level name an object expression starts from (``box`` for ``box.a[0]``)."""
    while True:
        if isinstance(node, ast.Name):
            return node.id
        if isinstance(node, (ast.Attribute, ast.Subscript, ast.Starred)):
            node = node.value
        elif isinstance(node, ast.Call) and _call_name(node, nb) == "vars" and node.args:
            node = node.args[0]
        else:
            return None


def _target_names(target: ast.AST, nb: _Notebook) -> list[str]:
    """The names an assignment target binds or gives something to (``globals()["f"] = ...``
    binds ``f``; ``box.f = ...`` gives it to ``box``)."""
    if isinstance(target, (ast.Tuple, ast.List)):
        return [n for t in target.elts for n in _target_names(t, nb)]
    if isinstance(target, ast.Subscript) and _namespace_call(target.value, nb):
        key = _fold(target.slice)
        return [key] if key else []
    name = _base_name(target, nb)
    return [name] if name else []


class _Notebook:
    """What the notebook's code binds at module level, and its import aliases.

    ``defs``: every ``def`` and ``class`` of a module-level name (inside an ``if`` or a
    ``try`` too, or in a function that declares it ``global``); ``assigned``: every other
    expression bound to a module-level name, or handed to the object it names (``box.f = x``,
    ``box[k] = x``, ``box.put(x)``, ``setattr(box, k, x)``), by module-level code or by a
    function for which the name is not local; ``aliases``: names bound by imports, or by
    module-level assignments of a dotted name (``G = robots.geometry``).
    """

    def __init__(self, cells: list[str]):
        self.defs: dict[str, list[ast.AST]] = {}
        self.assigned: dict[str, list[ast.AST]] = {}
        self.aliases: dict[str, str] = {}
        self.imports: set[str] = set()   # names bound by an import statement
        self.star: list[str] = []
        self.imported: set[str] = set()
        trees = []
        for source in cells:
            try:
                with _AST_LOCK:
                    trees.append(ast.parse(source))
            except (SyntaxError, ValueError, RecursionError, MemoryError):
                continue
        for tree in trees:
            for node in ast.walk(tree):  # imports anywhere count (inside functions too)
                self._imports(node)
        for tree in trees:
            for node in _own_scope(tree):
                self._binding(node, None)
            for func in ast.walk(tree):
                if isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                    owned = _locals(func)
                    for node in _own_scope(func):
                        self._binding(node, owned)

    def _bind(self, name: str, value: ast.AST) -> None:
        self.assigned.setdefault(name, []).append(value)

    def _binding(self, node: ast.AST, owned: set[str] | None) -> None:
        """Record what ``node`` binds at module level; ``owned``: the local names of the
        function it sits in (None: module-level code)."""
        def outer(name: str) -> bool:
            return owned is None or name not in owned

        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            if outer(node.name):
                self.defs.setdefault(node.name, []).append(node)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            if node.value is None:
                return
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for name in _target_names(target, self):
                    if outer(name):
                        self._bind(name, node.value)
                if owned is None and isinstance(target, ast.Name) and \
                        isinstance(node.value, (ast.Name, ast.Attribute)):
                    dotted = _chain(node.value, self)
                    if dotted and dotted != target.id:
                        self.aliases.setdefault(target.id, dotted)
        elif isinstance(node, ast.NamedExpr):
            if outer(node.target.id):
                self._bind(node.target.id, node.value)
        elif isinstance(node, (ast.For, ast.AsyncFor)):
            for name in _target_names(node.target, self):
                if outer(name):
                    self._bind(name, node.iter)
        elif isinstance(node, (ast.With, ast.AsyncWith)):
            for item in node.items:
                for name in _target_names(item.optional_vars, self) if item.optional_vars else ():
                    if outer(name):
                        self._bind(name, item.context_expr)
        elif isinstance(node, ast.Call):
            if _call_name(node, self) == "setattr" and node.args:
                name = _base_name(node.args[0], self)
            elif isinstance(node.func, ast.Attribute):
                name = _base_name(node.func.value, self)
                if name in self.imports:   # a module's function called, not a box filled
                    name = None
            else:
                name = None
            if name and outer(name):
                self._bind(name, node)

    def _imports(self, node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            for a in node.names:
                self.imported.add(a.name)
                if a.asname:
                    self.aliases[a.asname] = a.name
                    self.imports.add(a.asname)
                else:
                    top = a.name.split(".")[0]
                    self.aliases.setdefault(top, top)
                    self.imports.add(top)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            self.imported.add(node.module)
            for a in node.names:
                if a.name == "*":
                    self.star.append(node.module)
                else:
                    self.aliases[a.asname or a.name] = f"{node.module}.{a.name}"
                    self.imports.add(a.asname or a.name)


def _table(node: ast.AST, nb: _Notebook) -> str | None:
    """What a key looked up in ``node`` is relative to: "" for ``sys.modules`` (a module's
    full name), "<globals>" for the notebook's namespace (``globals()``), the module's dotted
    name for ``vars(m)`` and ``m.__dict__``; None when ``node`` is none of these."""
    if _namespace_call(node, nb):
        return "<globals>"
    if isinstance(node, ast.Call) and _call_name(node, nb) == "vars" and len(node.args) == 1:
        return _chain(node.args[0], nb)
    if isinstance(node, ast.Attribute) and node.attr == "__dict__":
        return _chain(node.value, nb)
    if isinstance(node, (ast.Name, ast.Attribute)) and _chain(node, nb) == "sys.modules":
        return ""
    return None


def _lookup(node: ast.AST) -> tuple[ast.AST, ast.AST] | None:
    """(table, key) of ``table[key]`` or ``table.get(key, ...)``."""
    if isinstance(node, ast.Subscript) and not isinstance(node.slice, ast.Slice):
        return node.value, node.slice
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
            node.func.attr == "get" and node.args:
        return node.func.value, node.args[0]
    return None


def _chain(node: ast.AST, nb: _Notebook) -> str | None:
    """The dotted name an expression such as ``geo.invert``, ``__import__('cv2').X``,
    ``sys.modules['cv2']`` or ``vars(geo)['invert']`` means."""
    if isinstance(node, ast.Name):
        return nb.aliases.get(node.id, node.id)
    if isinstance(node, ast.Attribute):
        base = _chain(node.value, nb)
        return f"{base}.{node.attr}" if base else None
    lookup = _lookup(node)
    if lookup is not None:
        where, key = _table(lookup[0], nb), _fold(lookup[1])
        if where is None or not key:
            return None
        if where == "<globals>":
            return nb.aliases.get(key, key)
        return f"{where}.{key}" if where else key
    if isinstance(node, ast.Call):
        last = _call_name(node, nb)
        if last in ("__import__", "import_module") and node.args:
            return _fold(node.args[0])
        if last == "getattr" and len(node.args) >= 2:
            base, attr = _chain(node.args[0], nb), _fold(node.args[1])
            return f"{base}.{attr}" if base and attr else None
    return None


def _dunder(name: str) -> bool:
    return name.startswith("__") and name.endswith("__")


def _read_plainly(root: ast.AST, nb: _Notebook) -> tuple[set[int], set[int]]:
    """(ids of the expressions in ``root`` that are only read through a plain attribute, ids
    of the namespaces looked up by a constant key). ``geo`` in ``geo.invert`` or
    ``getattr(geo, "invert")`` is read plainly; in ``vars(geo)``, ``geo.__dict__`` or
    ``helper(geo)`` it is handed over whole. A root that is a dotted name is bound to a
    name whose own uses are looked at instead."""
    plain = {id(root)} if isinstance(root, (ast.Name, ast.Attribute)) else set()
    keyed: set[int] = set()
    for sub in ast.walk(root):
        if isinstance(sub, ast.Attribute) and not _dunder(sub.attr):
            plain.add(id(sub.value))
        elif isinstance(sub, ast.Call) and _call_name(sub, nb) in ("getattr", "hasattr") and \
                len(sub.args) >= 2 and _fold(sub.args[1]) is not None:
            plain.add(id(sub.args[0]))
        lookup = _lookup(sub)
        if lookup is not None and _fold(lookup[1]) is not None:
            keyed.add(id(lookup[0]))
    return plain, keyed


def _named_at_run_time(node: ast.AST, nb: _Notebook, keyed: set[int]) -> bool:
    """True for a module, namespace or code named by a computed value: an import or
    ``eval`` of a computed string, ``sys.modules`` or ``globals()`` used other than by a
    constant key."""
    if isinstance(node, ast.Call) and _call_name(node, nb) in _NAMED_AT_RUN_TIME and \
            node.args and _fold(node.args[0]) is None:
        return True
    return id(node) not in keyed and _table(node, nb) in ("", "<globals>")


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
    :data:`ALWAYS_FORBIDDEN`) that whatever the notebook binds to ``function``, or anything
    it reaches in the notebook's code, names or looks up dynamically (the rule of this
    module's docstring); sorted, empty when clean."""
    own = tuple(forbidden)
    names = own + tuple(always)
    nb = _Notebook(cells)
    hits: set[str] = set()
    seen: set[int] = set()
    todo: list[ast.AST] = [*nb.defs.get(function, ()), *nb.assigned.get(function, ())]

    def check(dotted: str | None) -> None:
        if dotted:
            hits.update(f for f in names if matches(dotted, f))

    check(nb.aliases.get(function))   # from robots.geometry import invert as invert_pose
    while todo:
        node = todo.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        plain, keyed = _read_plainly(node, nb)
        # a function's own variable is not the module-level name it shadows
        owned = _locals(node) if isinstance(
            node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) else set()
        for sub in ast.walk(node):
            if isinstance(sub, ast.Name) and isinstance(sub.ctx, ast.Load) and \
                    sub.id not in owned:
                todo.extend(nb.defs.get(sub.id, ()))
                todo.extend(nb.assigned.get(sub.id, ()))
                check(nb.aliases.get(sub.id))
                for module in nb.star:
                    check(f"{module}.{sub.id}")
            elif isinstance(sub, (ast.Attribute, ast.Call, ast.Subscript)):
                check(_chain(sub, nb))
            if id(sub) not in plain and isinstance(getattr(sub, "ctx", ast.Load()), ast.Load):
                module = _chain(sub, nb) if isinstance(
                    sub, (ast.Name, ast.Attribute, ast.Call, ast.Subscript)) else None
                if module:   # a module handed over whole: all it holds is within reach
                    hits.update(f for f in names if f.startswith(module + "."))
            if _named_at_run_time(sub, nb, keyed):
                hits.update(own)
            if isinstance(sub, ast.Call):
                if _call_name(sub, nb) in _DYNAMIC:
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
