"""Trivial answers: what a student who computes nothing could hand in for a graded function.

A check whose tolerance is wide, or that measures only part of an answer, can give credit to
an answer that uses nothing of the problem (zeros, the identity pose, a constant unit
vector) or only its crudest statistic (the inputs echoed back, the mean of the input
points). ``cobotlab labs verify`` scores the answers built here with the grader's own
scoring (:func:`autograder.checks.score_function`, through :class:`autograder.fairness.
TrivialGate`) and fails a lab on which one earns more than a few per cent of a function's
points.

The answers are built from the *shapes* of a problem, never from a lab's name: the shape of
its truth (and of each part of a tuple or dict truth, since ``measure`` often keeps more in
the truth than the answer holds: ``(pose, points to map)``), or, for a closed loop
(``FunctionSpec.drive``), of what the spec's first code mistake returns to the loop. Each
leaf of that shape gets its candidates:

* zeros of its shape; the identity pose for a (4, 4) (or a stack of (4, 4)); the constant
  unit vectors (0, 0, 1) and (0, 0, -1) for a 3-vector (a camera's optical axis: the normal
  a plane facing the camera is close to);
* each input echoed back where its shape is the leaf's, the first pose of an input stack
  of poses, and the mean and the median of an (N, 3) or (N, 2) input point array where the
  leaf is a 3- or 2-vector;

then the combinations of the leaves' candidates for a tuple or dict (``(median of points,
(0, 0, -1))``), the truth of another problem of the same student (a hard-coded answer), and,
where a problem expects an exception (``Trial.raises``), raising it on every problem.

Pure: no sandbox, no call of student code; the answers are values (a law for a closed loop)
whose names are the same on every problem, so their scores add up over problems and draws.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from autograder.spec_types import FunctionSpec, Trial, copied, declared_parameters

__all__ = ["TrivialAnswer", "trivial_answers", "MAX_COMBINATIONS"]

# A tuple answer's leaves are combined at most this many ways: (point, normal) answers give
# 5 x 5 combinations; a cap keeps a many-part answer from costing thousands of scorings.
MAX_COMBINATIONS = 36
UNIT_VECTORS = (("(0, 0, 1)", (0.0, 0.0, 1.0)), ("(0, 0, -1)", (0.0, 0.0, -1.0)))


@dataclass(frozen=True)
class TrivialAnswer:
    """One trivial answer to one problem. ``name`` is the same on every problem (the table
    shows it); ``value`` is what the answer returns (for a closed loop: the law, a callable
    taking the graded function's arguments); ``raises`` (an exception class name) instead
    means the answer raises that on every problem."""

    name: str
    value: Any = None
    raises: str | None = None


Builder = Callable[[tuple], Any]   # the graded function's arguments -> the answer's value


# --------------------------------------------------------------------------- shapes


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_))


def _is_leaf_array(value) -> bool:
    return isinstance(value, np.ndarray) and value.dtype.kind in "iuf" and value.size > 0


def _shape(value):
    """The structure of a value: ("array", shape), ("number",), ("tuple", [children]),
    ("dict", [(key, child)]), or None for what no trivial answer imitates (a string)."""
    if _is_leaf_array(value):
        return ("array", value.shape)
    if _is_number(value):
        return ("number",)
    if isinstance(value, (tuple, list)) and value:
        children = [_shape(v) for v in value]
        return None if any(c is None for c in children) else ("tuple", tuple(children))
    if isinstance(value, dict) and value:
        children = [(k, _shape(v)) for k, v in value.items()]
        return None if any(c is None for _, c in children) else ("dict", tuple(children))
    return None


def _parts(value, path=()):
    """(path, part) of ``value`` and of each part of a tuple or dict in it, outermost first."""
    yield path, value
    if isinstance(value, (tuple, list)):
        for i, v in enumerate(value):
            yield from _parts(v, path + (i,))
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _parts(v, path + (k,))


def _at(value, path):
    for key in path:
        value = value[key]
    return value


def _parameter_names(spec: FunctionSpec, n: int) -> list[str]:
    names = declared_parameters(spec)
    return [names[i] if i < len(names) else f"argument {i}" for i in range(n)]


# --------------------------------------------------------------------------- one leaf


def _copy(value):
    return np.array(value, dtype=float, copy=True) if isinstance(value, np.ndarray) else value


def _leaf_candidates(shape, args: tuple, names: Sequence[str]) -> list[tuple[str, Builder]]:
    """(name, builder) of the trivial values of one leaf: what uses a crude statistic of the
    inputs first, constants last (a tuple's combinations keep the first ones when capped)."""
    found: list[tuple[str, Builder]] = []
    if shape[0] == "number":
        for i, arg in enumerate(args):
            if _is_number(arg):
                found.append((f"{names[i]} echoed back", lambda a, i=i: float(a[i])))
        return found + [("zeros", lambda a: 0.0)]
    size = shape[1]
    for i, arg in enumerate(args):
        array = _as_numbers(arg)
        if array is None:
            continue
        if array.shape == size:
            found.append((f"{names[i]} echoed back", lambda a, i=i: _copy(np.asarray(a[i]))))
        elif array.ndim == 2 and len(size) == 1 and size[0] in (2, 3) and \
                array.shape[1] == size[0] and array.shape[0] >= 2:
            found.append((f"mean of {names[i]}",
                          lambda a, i=i: np.asarray(a[i], dtype=float).mean(axis=0)))
            found.append((f"median of {names[i]}",
                          lambda a, i=i: np.median(np.asarray(a[i], dtype=float), axis=0)))
        elif array.ndim == len(size) + 1 and array.shape[1:] == size and array.shape[0] >= 1:
            found.append((f"{names[i]}[0]", lambda a, i=i: _copy(np.asarray(a[i])[0])))
    if size == (3,):
        found += [(name, lambda a, v=v: np.array(v)) for name, v in UNIT_VECTORS]
    if size[-2:] == (4, 4):
        found.append(("identity pose" if size == (4, 4) else "identity poses",
                      lambda a, size=size: np.broadcast_to(np.eye(4), size).copy()))
    found.append(("zeros", lambda a, size=size: np.zeros(size)))
    return found


def _as_numbers(arg) -> np.ndarray | None:
    """An input as a numeric array (a list of poses as an (N, 4, 4) stack), or None."""
    if _is_leaf_array(arg):
        return arg
    if isinstance(arg, (list, tuple)) and arg and all(_is_leaf_array(a) for a in arg):
        try:
            return np.stack([np.asarray(a) for a in arg])
        except ValueError:
            return None
    return None


# --------------------------------------------------------------------------- combinations


def _combined(shape, args, names) -> list[tuple[str, Builder]]:
    """(name, builder) of a whole answer of this structure: a leaf's candidates, or the
    capped product of the parts' candidates."""
    if shape[0] in ("array", "number"):
        return _leaf_candidates(shape, args, names)
    keys = list(range(len(shape[1]))) if shape[0] == "tuple" else [k for k, _ in shape[1]]
    children = [c for c in shape[1]] if shape[0] == "tuple" else [c for _, c in shape[1]]
    # Each leaf value once per call, however many combinations hold it (a median is dear).
    options = [[(n, _once(b)) for n, b in _combined(c, args, names)] for c in children]
    while int(np.prod([len(o) for o in options])) > MAX_COMBINATIONS:
        longest = max(range(len(options)), key=lambda j: len(options[j]))
        if len(options[longest]) == 1:
            break
        options[longest] = options[longest][:-1]
    found = []
    for choice in itertools.product(*options):
        if shape[0] == "tuple":
            name = "(" + ", ".join(n for n, _ in choice) + ")"

            def build(a, choice=choice):
                return tuple(b(a) for _, b in choice)
        else:
            name = "{" + ", ".join(f"{k}: {n}" for k, (n, _) in zip(keys, choice)) + "}"

            def build(a, choice=choice, keys=keys):
                return {k: b(a) for k, (_, b) in zip(keys, choice)}
        found.append((name, build))
    return found


def _once(build: Builder) -> Builder:
    """``build``, remembering its value for the last arguments it was given."""
    last: list = [None, None]

    def built(a):
        if last[0] is not a:
            last[0], last[1] = a, build(a)
        return last[1]
    return built


def _templates(spec: FunctionSpec, trial: Trial) -> list[tuple[tuple, Any]]:
    """(path into the truth, the part) whose structure an answer may have: the truth and
    each part of it, distinct structures only."""
    seen, found = set(), []
    for path, part in _parts(trial.truth):
        shape = _shape(part)
        if shape is not None and shape not in seen:
            seen.add(shape)
            found.append((path, part))
    return found


class _Stop(BaseException):
    """Ends a closed loop after its first call (BaseException: a loop's own ``except
    Exception`` must not swallow it)."""


def _law_call(spec: FunctionSpec, trial: Trial) -> tuple[tuple, Any] | None:
    """(arguments, return value) of the first call of a closed loop, from the spec's code
    mistakes (the author's code, run in this process, as verify runs them), or None."""
    for mistake in spec.code_mistakes:
        seen = []

        def law(*args, func=mistake.func, seen=seen):
            seen.append((args, func(*args)))
            raise _Stop

        try:
            with np.errstate(all="ignore"):
                spec.drive(law, trial)
        except _Stop:
            pass
        except Exception:  # noqa: BLE001 - a mistake may raise: try the next one
            continue
        if seen:
            return seen[0]
    return None


def trivial_answers(spec: FunctionSpec, trial: Trial,
                    others: Sequence[Trial] = ()) -> list[TrivialAnswer]:
    """The trivial answers to one problem of ``spec`` (see the module's docstring), each
    named the same way on every problem where it applies. ``others``: the other problems of
    the same student, whose truths are answers that ignore this problem's inputs."""
    answers: list[TrivialAnswer] = []
    if trial.raises is not None or any(o.raises is not None for o in others):
        names = {trial.raises} | {o.raises for o in others}
        answers += [TrivialAnswer(f"raises {name} on every problem", raises=name)
                    for name in sorted(n for n in names if n)]
    if spec.drive is not None:
        call = _law_call(spec, trial)
        shape = _shape(call[1]) if call is not None else None
        if shape is None:
            return answers   # no law to imitate: nothing trivial is known for this loop
        args, _ = call
        names = _parameter_names(spec, len(args))
        for name, build in _combined(shape, args, names):
            answers.append(TrivialAnswer(f"a law returning {name}",
                                         value=lambda *a, build=build: build(a)))
        return answers
    args = tuple(trial.args)
    names = _parameter_names(spec, len(args))
    seen: set[str] = set()
    for path, part in _templates(spec, trial):
        shape = _shape(part)
        for name, build in _combined(shape, args, names):
            if name not in seen:
                seen.add(name)
                answers.append(TrivialAnswer(name, value=build(args)))
        other = next((o for o in others if o is not trial and o.raises is None
                      and _fits(o.truth, path, shape)), None)
        label = "truth of another problem" + ("" if not path else
                                              f" (part {'/'.join(map(str, path))})")
        if other is not None and label not in seen:
            seen.add(label)
            answers.append(TrivialAnswer(label, value=copied(_at(other.truth, path))))
    return answers


def _fits(truth, path, shape) -> bool:
    try:
        return _shape(_at(truth, path)) == shape
    except (KeyError, IndexError, TypeError):
        return False

