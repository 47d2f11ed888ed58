"""What every mistake family is made of: the typed name, a prediction, the problem it is
tried on, and the kinds of value a family reads from a function's answer and inputs.

A family never looks at a lab's title or a function's name: it decides from the *kind* of
the truth (a pose, a rotation, an (N, 3) point set, a scalar error, a tuple of parts) and of
the inputs (a stack of poses, a pair of same-typed arguments) whether it applies.

Frames follow DESIGN.md: a pose ``a_T_b`` is a (4, 4) homogeneous matrix in metres.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from autograder.spec_types import FunctionSpec, MistakeName, Trial, copied

__all__ = ["Family", "MistakeName", "Prediction", "Problem", "as_array", "is_pose",
           "is_rotation", "is_stack", "is_points", "is_numeric_array", "part_predictions", "parts",
           "scale_lengths"]

OUTPUT, INPUT = "output", "input"


@dataclass(frozen=True)
class Prediction:
    """The answer a mistake gives on one problem.

    ``answer`` is that answer (what a student making only this mistake returns).
    ``undo``, for a mistake that is an invertible transform of a right answer (the inverse,
    x1000, degrees), maps a student's answer back: the grader then asks whether the answer
    with the mistake undone lies within the problem's noise of ``base`` (the truth), which
    holds on noisy problems where the student's estimate, not the truth, was transformed.
    ``words`` overrides the family's words (a part of a tuple answer names which part).
    ``null`` is ``base`` with the quantity the mistake scales set to zero (the translation,
    the angle): undoing tells the mistake apart only where the noise resolves that quantity
    (a 5 cm translation under a 40 cm tolerance divided by 1000 is still "right"), so where
    ``null`` itself lies within a few noise units of ``base``, the answer is compared with
    ``answer`` as it is instead.
    ``loose``: the prediction compares a part of the answer only (the rotation of a pose,
    whatever its translation): the grader weighs it only where no whole-answer candidate
    names the answer.
    ``wraps``: the prediction is an angle scaled past a full turn (a pose's angle times
    180/pi), compared as it is: any wrong angle about the right axis lands within the noise
    of it by chance, so the grader names it only within the radius where that chance is
    small (``autograder.checks``).
    ``resolved``: the prediction is weighed only where it lies more than a few noise units
    from the truth (``families.RESOLVED``): an angle halved on a problem whose noise
    spans degrees is no mistake the answer can be told by."""

    answer: Any
    undo: Callable[[Any], Any] | None = None
    base: Any = None
    words: str | None = None
    null: Any = None
    loose: bool = False
    wraps: bool = False
    resolved: bool = False


@dataclass(frozen=True)
class Problem:
    """One problem as a family sees it: the spec, the trial, and ``truth``, the part of
    ``trial.truth`` a student's answer is compared with (a pose where the truth is
    (pose, points))."""

    spec: FunctionSpec
    trial: Trial
    truth: Any
    # the reference's answers already computed on this problem, by their inputs' position
    # in the calls (the families share them: a stack's items alone cost a call each)
    cache: dict = field(default_factory=dict, compare=False)

    def right_answer(self):
        """The reference's answer on the problem's own inputs (cached), or None."""
        if "right" not in self.cache:
            self.cache["right"] = self.reference(*self.trial.args)
        return self.cache["right"]

    def item_answers(self, lengths: list, n: int) -> list:
        """The reference's answer on each item alone of the inputs with ``n`` items (the
        others as they are), cached; None for an item it refuses."""
        key = ("items", n)
        if key not in self.cache:
            args = tuple(self.trial.args)
            self.cache[key] = [self.reference(*[a[i:i + 1] if n_a == n else a
                                                for a, n_a in zip(args, lengths)])
                               for i in range(n)]
        return self.cache[key]

    def reference_on(self, key, make_args: Callable[[], tuple]):
        """The reference on the inputs ``make_args()`` gives, cached under ``key`` (the
        transform and the inputs it changes, e.g. ("inverted", (2,))): two families that
        transform the inputs alike (a stack's poses inverted, for its order and for the
        product's) share one call."""
        cached = ("on", key)
        if cached not in self.cache:
            self.cache[cached] = self.reference(*make_args())
        return self.cache[cached]

    def reference(self, *args):
        """The spec's private reference on ``args`` (copies: it must not write into the
        problem), or None when there is none or it raises on them."""
        ref = self.spec.reference
        if ref is None:
            return None
        try:
            # a reference that warns about its inputs (motions in the wrong convention) is
            # told so on purpose here: the inputs carry the mistake
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return ref(*copied(args))
        except Exception:  # noqa: BLE001 - transformed inputs may be ones it refuses
            return None


@dataclass(frozen=True)
class Family:
    """One classic mistake, tried on every graded function whose types it fits.

    ``name`` is the family ("units m/mm", the same for each direction of it); ``words``
    what the student is told, the diagnosis then the fix after a colon; ``side`` "output"
    (a transform of the truth, public: computed where check() runs) or "input" (the
    reference called on transformed inputs: private, precomputed for practice data).
    ``predict(problem)`` gives the mistake's :class:`Prediction`s on a problem (none: the
    family does not apply there)."""

    name: str
    words: str
    side: str
    make: Callable[[Problem], list[Prediction]]
    key: str = ""

    def label(self, prediction: Prediction | None = None) -> MistakeName:
        """The typed name of this mistake (with a prediction's own words when it has them)."""
        words = prediction.words if prediction is not None and prediction.words else self.words
        return MistakeName(self.name, words)

    def predictions(self, problem: Problem) -> list[Prediction]:
        """Every prediction of this family on ``problem`` ([] when it does not apply);
        never raises."""
        try:
            with np.errstate(all="ignore"):
                return [p for p in self.make(problem) if p is not None]
        except Exception:  # noqa: BLE001 - a family that cannot read a value does not apply
            return []

    def applies(self, spec: FunctionSpec, trial: Trial, truth=None) -> bool:
        """True when this family predicts an answer on ``trial`` (see :meth:`predict`)."""
        return self.predict(spec, trial, truth) is not None

    def predict(self, spec: FunctionSpec, trial: Trial, truth=None):
        """The answer this mistake gives on ``trial`` (the first when it gives several, as
        one per part of a tuple answer), or None when the family does not apply."""
        return self.answer_on(Problem(spec, trial, answer_truth(trial, truth)))

    def answer_on(self, problem: Problem):
        """:meth:`predict` on a problem already built (several families sharing one problem
        share the reference's answers cached on it)."""
        found = self.predictions(problem)
        return found[0].answer if found else None


def answer_truth(trial: Trial, truth=None):
    """``truth`` if given, else ``trial.truth``'s answer part: a truth that carries what the
    measure needs beside it (fit_rigid's (pose, points)) gives its first item when that is a
    pose."""
    if truth is not None:
        return truth
    t = trial.truth
    if isinstance(t, (tuple, list)) and t and is_pose(t[0]) and not is_pose(t[-1]):
        return t[0]
    return t


def same_answer(a, b) -> bool:
    """True when ``a`` and ``b`` are one answer up to rounding (a tuple part by part)."""
    if isinstance(a, tuple) or isinstance(b, tuple):
        return isinstance(a, tuple) and isinstance(b, tuple) and len(a) == len(b) \
            and all(same_answer(x, y) for x, y in zip(a, b))
    x, y = as_array(a), as_array(b)
    if x is None or y is None or x.shape != y.shape:
        return False
    return bool(np.allclose(x, y, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(y).max()))))


# --------------------------------------------------------------------------- kinds of value


def as_array(value) -> np.ndarray | None:
    """``value`` as a finite float array, or None (a dict, a string, NaN, an empty array)."""
    if isinstance(value, (dict, str, bytes)) or value is None:
        return None
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.size == 0 or not np.all(np.isfinite(a)):
        return None
    return a


_EYE3 = np.eye(3)


def _rotations(R: np.ndarray, atol: float) -> bool:
    """True when every 3x3 block of ``R`` (shape (..., 3, 3)) is a rotation (plain numpy:
    the families test every input of every failed problem)."""
    if R.ndim == 2:
        # one block (most calls: a truth or an answer), without einsum's and det's setup
        if np.abs(R.T @ R - _EYE3).max() > atol:
            return False
        (a, b, c), (d, e, f), (g, h, i) = R.tolist()
        return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0
    gram = np.einsum("...ji,...jk->...ik", R, R)
    return bool(np.abs(gram - np.eye(3)).max() <= atol) and bool(np.all(np.linalg.det(R) > 0))


def is_rotation(value, atol: float = 1e-6) -> bool:
    a = as_array(value)
    return a is not None and a.shape == (3, 3) and _rotations(a, atol)


def _last_rows(a: np.ndarray) -> bool:
    return bool(np.abs(a[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max() <= 1e-8)


def _not_shaped(value, test) -> bool:
    """True when ``value`` is an array whose shape fails ``test`` (checked before
    converting it: every family asks of every input whether it is a pose)."""
    return isinstance(value, np.ndarray) and not test(value.shape)


def is_pose(value) -> bool:
    if _not_shaped(value, lambda s: s == (4, 4)):
        return False
    a = as_array(value)
    return a is not None and a.shape == (4, 4) and _last_rows(a) \
        and _rotations(a[:3, :3], 1e-4)


def is_stack(value) -> bool:
    """A stack of poses: a list of them or an (n, 4, 4) array, n >= 2."""
    if _not_shaped(value, lambda s: len(s) == 3 and s[1:] == (4, 4)):
        return False
    a = as_array(value)
    return a is not None and a.ndim == 3 and a.shape[0] >= 2 and a.shape[1:] == (4, 4) \
        and _last_rows(a) and _rotations(a[:, :3, :3], 1e-4)


def is_points(value) -> bool:
    a = as_array(value)
    return a is not None and a.ndim == 2 and a.shape[1] == 3 and a.shape[0] >= 3


def is_numeric_array(value) -> bool:
    """A plain array of numbers (a scalar, a vector, a matrix): no pose, no tuple of parts."""
    if isinstance(value, (tuple, list)) and value and isinstance(value[0], (tuple, list,
                                                                             np.ndarray)):
        return False
    a = as_array(value)
    return a is not None and not is_pose(a) and not is_stack(a)


def parts(value) -> list | None:
    """The parts of a tuple answer ((centre, normal)), each an array; None for no tuple."""
    if not isinstance(value, tuple) or len(value) < 2:
        return None
    arrays = [as_array(v) for v in value]
    return None if any(a is None for a in arrays) else arrays


def scale_lengths(value, factor: float) -> np.ndarray:
    """``value`` with its lengths times ``factor``: a pose's (or each stacked pose's)
    translation, any other array whole."""
    a = np.array(value, dtype=float)
    if is_pose(a):
        a[:3, 3] *= factor
    elif is_stack(a):
        a[:, :3, 3] *= factor
    else:
        a = a * factor
    return a


def part_predictions(truth, forward: Callable, undo: Callable, words_of=None,
                     zero: Callable | None = None) -> list:
    """:class:`Prediction`s of a mistake made on the whole answer and, for a tuple answer,
    on each part alone (the centre of a (centre, normal) in millimetres): ``forward`` maps a
    right value to the mistaken one, ``undo`` back, ``zero`` to its ``null``;
    ``words_of(k)`` the words for part k."""
    def null(t):
        return None if zero is None else zero(t)
    out = [Prediction(forward(truth), undo, truth, null=null(truth))] \
        if parts(truth) is None else []
    split = parts(truth)
    if split is None:
        return out
    for k, part in enumerate(split):
        def fwd(t, k=k):
            return tuple(forward(np.asarray(x, float)) if i == k else x for i, x in enumerate(t))

        def back(v, k=k):
            return tuple(undo(np.asarray(x, float)) if i == k else x for i, x in enumerate(v))

        # no null for a part: zero is no value of every part (a unit normal), and a measure
        # given one as the truth has nothing to measure against
        out.append(Prediction(fwd(truth), back, truth, words_of(k) if words_of else None))
    return out
