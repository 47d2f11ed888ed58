"""The run-time nets against forbidden routines, inside the sandbox (and in ``check()``):
:class:`Guard` poisons the routines while a graded function runs, :class:`Tripwire`'s
profile hook records calls of them. The rule and the authoritative static scan are
:mod:`autograder.forbidden`'s, on the trusted side.

Standard library only: the worker imports this module next to student code.
"""

from __future__ import annotations

import importlib
import sys
import threading
import types

__all__ = ["ALWAYS_FORBIDDEN", "ForbiddenCall", "Guard", "Tripwire", "matches", "resolve"]

ALWAYS_FORBIDDEN = ("solutions",)


def matches(dotted: str, forbidden: str) -> bool:
    """True when ``dotted`` (e.g. ``cv2.cv2.calibrateHandEye``) names ``forbidden``.

    Same top-level module and same final name (re-exports such as ``cv2.cv2.X`` count), or
    anything inside a forbidden module (``solutions.handeye.solve`` for ``solutions``).
    """
    parts, want = dotted.split("."), forbidden.split(".")
    if dotted == forbidden or dotted.startswith(forbidden + "."):
        return True
    return len(want) > 1 and len(parts) > 1 and parts[0] == want[0] and parts[-1] == want[-1]


class ForbiddenCall(BaseException):
    """What a poisoned forbidden routine raises while a graded function runs in the worker:
    a BaseException, so a student's ``except Exception`` fallback does not swallow it."""


def resolve(dotted: str):
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


_STUBS: dict[int, types.CodeType] = {}


def _stub_code(cells: int) -> types.CodeType:
    """The code a poisoned routine runs: it calls its ``_forbidden_call`` default (which
    records the call and raises), whatever it is given. ``cells`` unused free variables: a
    function's code can only be swapped for code with as many as its closure holds."""
    if cells not in _STUBS:
        names = [f"_cell{i}" for i in range(cells)]
        source = "def _outer():\n" + "".join(f"    {n} = None\n" for n in names) + \
            "    def _poisoned(*args, _forbidden_call=None, **kwargs):\n" + \
            (f"        ({', '.join(names)},)\n" if names else "") + \
            "        return _forbidden_call()\n    return _poisoned\n"
        scope: dict = {}
        exec(compile(source, "<forbidden routine>", "exec"), scope)
        _STUBS[cells] = scope["_outer"]().__code__
    return _STUBS[cells]


def _pass_through(real):
    """A Python function that calls the C routine ``real``: unlike ``real``, its code can be
    swapped while a graded function runs."""
    def routine(*args, **kwargs):
        return real(*args, **kwargs)

    routine.__name__ = routine.__qualname__ = getattr(real, "__name__", "routine")
    routine.__doc__ = getattr(real, "__doc__", None)
    routine.__module__ = getattr(real, "__module__", None)
    return routine


class _Routine:
    """A forbidden routine as the library defines it: ``function`` is what gets poisoned
    (the routine itself, or the pass-through put in place of a C routine ``c_function``),
    ``code`` its own code."""

    __slots__ = ("function", "code", "c_function")

    def __init__(self, function, c_function=None):
        self.function, self.code, self.c_function = function, function.__code__, c_function


class Guard:
    """The worker's hold on the forbidden routines, taken before any student code runs.

    :meth:`add` resolves each name once, to the object the library defines (student code
    that later rebinds the module attribute changes nothing here), and puts a pass-through
    in place of a C routine in every loaded module, so that every reference student code can
    take is to a Python function. :class:`Tripwire` then poisons them for each graded call.
    """

    def __init__(self):
        self._routines: dict[str, _Routine | None] = {}

    def add(self, names) -> None:
        """Take hold of the routines ``names`` (dotted; module names are left to the
        profile hook)."""
        for name in names:
            if "." in name and name not in self._routines:
                self._routines[name] = self._hold(resolve(name))

    @staticmethod
    def _hold(obj) -> _Routine | None:
        function = getattr(obj, "__func__", obj)   # a method: the function behind it
        if isinstance(function, types.FunctionType):
            return _Routine(function)
        if obj is None or isinstance(obj, type) or not callable(obj):
            return None
        routine = _pass_through(obj)
        for module in list(sys.modules.values()):
            try:
                namespace = vars(module)
            except TypeError:
                continue
            for key, value in list(namespace.items()):
                if value is obj:
                    namespace[key] = routine
        return _Routine(routine, obj)

    def routines(self, names) -> dict[str, _Routine]:
        """The routines of ``names`` held, by name."""
        return {n: r for n in names if (r := self._routines.get(n)) is not None}

    def poison(self, names, record) -> list[tuple]:
        """Make each routine of ``names`` call ``record(name)`` instead of answering, in
        every thread and through every reference; returns what :meth:`restore` needs."""
        self.add(names)
        swapped = []
        for name, routine in self.routines(names).items():
            function = routine.function
            kwdefaults = function.__kwdefaults__
            stub = _stub_code(len(function.__code__.co_freevars))
            # the routine's own keyword defaults stay: a thread already inside it keeps them
            function.__kwdefaults__ = {**(kwdefaults or {}),
                                       "_forbidden_call": lambda name=name: record(name)}
            function.__code__ = stub
            swapped.append((function, routine.code, kwdefaults, stub))
        return swapped

    @staticmethod
    def restore(swapped: list[tuple]) -> bool:
        """Undo :meth:`poison`; True when student code had put other code in a routine."""
        changed = False
        for function, code, kwdefaults, stub in swapped:
            changed |= function.__code__ is not stub
            function.__code__ = code
            function.__kwdefaults__ = kwdefaults
        return changed


class Tripwire:
    """Record calls of the forbidden routines made while the ``with`` block runs.

    A profile hook (this thread's, and that of every thread started inside the block)
    compares each called C function (``cv2.calibrateHandEye``) by identity and each Python
    function (``robots.geometry.invert``) by its code object, so an alias, a ``getattr``, a
    reference saved before the call or a copy of the function is caught as well. Importing
    ``solutions`` is caught by name. With a :class:`Guard` (the worker), the routines are
    also poisoned for the block: a call raises :class:`ForbiddenCall`, from any thread.
    A profile hook removed, or a poisoned routine's code replaced, counts as a call of every
    routine of ``forbidden``. ``hits`` holds what was called.
    """

    def __init__(self, forbidden, always=ALWAYS_FORBIDDEN, guard: Guard | None = None):
        self.hits: set[str] = set()
        self._names = tuple(f for f in forbidden if "." in f)
        self._guard = guard
        self._c: dict[int, str] = {}
        self._code: dict[types.CodeType, str] = {}
        self._modules = [f for f in tuple(forbidden) + tuple(always) if "." not in f]
        if guard is not None:
            guard.add(self._names)
            for name, routine in guard.routines(self._names).items():
                if routine.c_function is not None:
                    self._c[id(routine.c_function)] = name
                else:
                    self._code[routine.code] = name
        else:
            for name in self._names:
                obj = resolve(name)
                code = getattr(obj, "__code__", None)
                if isinstance(code, types.CodeType):
                    self._code[code] = name
                elif obj is not None:
                    self._c[id(obj)] = name
        self._hook = self._profile   # bound once: sys.getprofile() is compared with it
        self._previous = self._previous_threads = None
        self._swapped: list[tuple] = []

    def _profile(self, frame, event, arg):
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

    @staticmethod
    def is_hook(frame) -> bool:
        """True when ``frame`` is a tripwire's profile hook running: an exception raised
        there (a time-out's) would make CPython remove the hook."""
        return frame is not None and frame.f_code is Tripwire._profile.__code__

    def _record(self, name: str):
        self.hits.add(name)
        raise ForbiddenCall(f"{name} was called: it is one of the routines this function "
                            "must not use")

    def __enter__(self):
        if self._guard is not None:
            self._swapped = self._guard.poison(self._names, self._record)
        self._previous, self._previous_threads = sys.getprofile(), threading.getprofile()
        threading.setprofile(self._hook)
        sys.setprofile(self._hook)
        return self

    def __exit__(self, *exc):
        removed = sys.getprofile() is not self._hook
        sys.setprofile(self._previous)
        threading.setprofile(self._previous_threads)
        if Guard.restore(self._swapped) or removed:
            self.hits.update(self._names)
        self._swapped = []
        return False
