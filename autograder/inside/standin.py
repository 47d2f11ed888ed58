"""Stand-ins that answer with the true value: one bug costs once.

When a graded function relies on another graded function of the same notebook (IBVS on the
interaction matrix, the hand-to-eye chain on the three-point frame), the grader swaps in a
stand-in for the second one while the first is scored: calls with the arguments the grader
expects get the true answer, any other call goes to the student's own function. Only values
travel (never the reference code), and only for the problem's own inputs.

Standard library and numpy only: the sandboxed worker imports this module next to student code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["copy_value", "substitute", "substituted"]


def copy_value(value):
    """A copy of an array (or a list of them, nested) that the callee may write into."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, list):
        return [copy_value(x) for x in value]
    return value


def _flat_args(args) -> np.ndarray | None:
    """All of a call's arguments as one float vector (None when one is not numeric)."""
    try:
        parts = [np.asarray(a, dtype=float).ravel() for a in args]
    except (TypeError, ValueError):
        return None
    return np.concatenate(parts) if parts else np.zeros(0)


def substitute(name: str, own, table):
    """A stand-in for the student's ``own`` function ``name``: calls whose arguments match an
    entry of ``table`` ([(args, value), ...], compared as flattened floats) get a copy of
    that value; every other call goes to ``own``. Used by the worker and by ``check()``."""
    keys = [(_flat_args(entry_args), value) for entry_args, value in table]

    def stand_in(*args, **kwargs):
        flat = _flat_args(list(args) + list(kwargs.values()))
        if flat is not None:
            for key, value in keys:
                # np.allclose's own tolerance test, without its ~0.1 ms of wrapping: a
                # closed loop calls this every control period.
                if key is not None and key.shape == flat.shape and \
                        bool(np.all(np.abs(flat - key) <= 1e-15 + 1e-12 * np.abs(key))):
                    return copy_value(value)
        if own is None:
            raise NameError(f"name {name!r} is not defined")
        return own(*args, **kwargs)

    stand_in.__name__ = stand_in.__qualname__ = name
    return stand_in


class substituted:
    """``with substituted(namespace, tables):`` swaps the stand-ins of :func:`substitute` into
    ``namespace`` (a dict: the notebook's globals) and puts the originals back after."""

    _MISSING = object()

    def __init__(self, namespace: dict, tables: dict | None):
        self.namespace, self.tables, self.saved = namespace, tables or {}, {}

    def __enter__(self):
        for name, table in self.tables.items():
            own = self.namespace.get(name, self._MISSING)
            self.saved[name] = own
            self.namespace[name] = substitute(name, None if own is self._MISSING else own,
                                              table)
        return self

    def __exit__(self, *exc):
        for name, own in self.saved.items():
            if own is self._MISSING:
                self.namespace.pop(name, None)
            else:
                self.namespace[name] = own
        return False
