"""What the families about stacks and reductions share: which inputs are stacks of items,
the reference's answer rebuilt as a reduction over its items, and how far two answers lie
apart on the problem's own noise scale.

A *stack* is an input whose first axis lists items of a few numbers each: an (N, 3) point
set, an (N, 2) set of pixels, an (N, 4, 4) stack of poses or a list of poses, a vector of N
values (N errors, or a vector's coordinates, whose norm is a root of their summed squares).
A single pose or a depth image is no stack (a pose's rows are no items; a depth image's rows
are too big to be one).

A *reduction* is how the reference's answer ``W`` is made of its answers ``v_i`` on each
item alone (the reference called on one-item stacks): ``W = (sum_i v_i^p / d)^(1/p)`` with
the power ``p`` 1 (a mean, or a sum) or 2 (a root mean square, where ``v_i = |e_i|``), and
the divisor ``d`` n, n - 1 or 1. Only what the reference shows is read: a function whose
answer is no such reduction has none, and the families built on it do not apply.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from autograder.families.base import Problem, as_array, is_numeric_array, is_pose, same_answer
from autograder.spec_types import Trial

# An item of a stack holds at most this many numbers (a pose's 16): a depth image's rows
# are no items.
_ITEM_SIZE = 16
# Two answers this many noise units apart (the check's widest credited band) are told apart
# by the grader: a mistake whose answer lies nearer the right one loses no credit and is not
# worth a name, and two mistakes' answers nearer each other are one explanation.
APART = 2.0


def _length(a) -> int | None:
    if isinstance(a, (int, float, str, bytes, dict)) or is_pose(a):
        return None
    arr = as_array(a)
    if arr is None or arr.ndim < 1 or arr.shape[0] < 2 or arr[0].size > _ITEM_SIZE:
        return None
    return int(arr.shape[0])


def stack_lengths(args) -> list[int | None]:
    """Each argument's number of items when it is a stack (see the module's docstring),
    else None."""
    return [_length(a) for a in args]


def lengths_of(problem: Problem) -> list[int | None]:
    """:func:`stack_lengths` of the problem's inputs, cached on it (each stack family asks)."""
    if "lengths" not in problem.cache:
        problem.cache["lengths"] = stack_lengths(tuple(problem.trial.args))
    return problem.cache["lengths"]


def longest(args, lengths: list | None = None) -> int | None:
    """The number of items of the longest stacks among ``args`` (None: no stack);
    ``lengths`` their :func:`stack_lengths` when known."""
    lengths = stack_lengths(args) if lengths is None else lengths
    return max((n for n in lengths if n is not None), default=None)


def _like(original, items: list):
    """``items`` in the container ``original`` came in (a list stays a list)."""
    if isinstance(original, list):
        return list(items)
    if isinstance(original, tuple):
        return tuple(items)
    return np.stack([np.asarray(x, dtype=float) for x in items])


def with_stacks(args, n: int, change, lengths: list | None = None) -> tuple:
    """``args`` with every stack of ``n`` items replaced by ``change(list of its items)``,
    in its own container; the other arguments as they are (``lengths``: their
    :func:`stack_lengths` when known)."""
    lengths = stack_lengths(args) if lengths is None else lengths
    return tuple(_like(a, change(list(a))) if n_a == n else a for a, n_a in zip(args, lengths))


@dataclass(frozen=True)
class Reduction:
    """The reference's answer as ``(sum_i v_i^power / divisor)^(1/power)`` over ``items``
    (``v_i``, one row per item, each of the answer's shape, non-negative for power 2)."""

    items: np.ndarray
    power: int
    divisor: int

    @property
    def n(self) -> int:
        return int(self.items.shape[0])

    def over(self, divisor: float) -> np.ndarray:
        """The same reduction with another divisor."""
        return (np.sum(self.items ** self.power, axis=0) / divisor) ** (1.0 / self.power)

    def median(self) -> np.ndarray:
        """The median over the items, of their powers (an RMS's median is the root of the
        median square)."""
        return np.median(self.items ** self.power, axis=0) ** (1.0 / self.power)

    def maximum(self) -> np.ndarray:
        return np.max(self.items, axis=0)

    def ends(self) -> list[np.ndarray]:
        """The first and the last item."""
        return [self.items[0], self.items[-1]]


def coincide(value: np.ndarray, others: list[np.ndarray]) -> bool:
    """True when ``value`` is one of ``others`` up to rounding. An order statistic (an odd
    stack's median, the maximum) is one of the items: where it is the first or the last,
    the answer is as much "one item for all" as that statistic, and neither is named."""
    return any(np.allclose(value, o, rtol=1e-9, atol=0) for o in others)


def reduction(problem: Problem, min_items: int = 3) -> Reduction | None:
    """How the reference's answer on ``problem`` is made of its answers on each item alone
    (the stacks of the most items cut to one item each), or None: no stack of at least
    ``min_items`` items, an answer that is no scalar or vector or that lists the items one
    by one, or no power and divisor that rebuild it. Cached on the problem (the statistic
    families each ask for it)."""
    key = ("reduction", min_items)
    if key not in problem.cache:
        problem.cache[key] = _reduction(problem, min_items)
    return problem.cache[key]


def _reduction(problem: Problem, min_items: int) -> Reduction | None:
    args = tuple(problem.trial.args)
    n = longest(args, lengths_of(problem))
    whole = problem.right_answer()
    if n is None or n < min_items or not is_numeric_array(whole):
        return None
    whole = np.asarray(whole, dtype=float)
    # an answer that lists the items one by one (a residual per point) has another shape on
    # one item than on n, and is no reduction: the shapes below tell, whatever n is
    if whole.ndim > 1:
        return None
    items = []
    for answer in problem.item_answers(lengths_of(problem), n):
        value = as_array(answer)
        if value is None or value.shape != whole.shape:
            return None
        items.append(value)
    stacked = np.stack(items)
    stacked.setflags(write=False)   # shared through the problem's cache by every family
    found = Reduction(stacked, 1, n)
    for power in (1, 2):
        if power == 2 and np.any(found.items < 0):
            continue
        for divisor in (n, n - 1, 1):
            candidate = Reduction(found.items, power, divisor)
            if same_answer(candidate.over(divisor), whole):
                return candidate
    return None


def as_truth_of(trial: Trial, answer):
    """``answer`` in the form of ``trial.truth`` (a truth that carries what the measure
    needs beside the answer, fit_rigid's (pose, points), keeps its other parts)."""
    truth = trial.truth
    if isinstance(truth, (tuple, list)) and truth and not isinstance(answer, (tuple, list)):
        return (answer, *truth[1:])
    return answer


def noise_units(problem: Problem, value, base) -> float:
    """How far ``value`` lies from ``base`` taken as the truth, by the spec's own measure in
    units of each check's widest credited band (the largest over the checks); inf when the
    measure cannot take them."""
    spec, trial = problem.spec, problem.trial
    try:
        with np.errstate(all="ignore"):
            measured = spec.measure(value, Trial(args=trial.args, truth=as_truth_of(trial, base),
                                                 tol=trial.tol, label=trial.label))
        return max(float(measured[c.name]) / (c.reach * trial.tol[c.name])
                   for c in spec.checks)
    except Exception:  # noqa: BLE001 - a value the measure refuses is far from anything
        return float("inf")


def apart(problem: Problem, value, *bases) -> bool:
    """True when ``value`` lies more than :data:`APART` noise units from each of ``bases``
    (None ones are left out): the grader tells it apart from each of them."""
    for base in bases:
        if base is None:
            continue
        if same_answer(value, base):
            return False
        if problem.spec is not None and not noise_units(problem, value, base) > APART:
            return False
    return True


def loses_credit(problem: Problem, value) -> bool:
    """True when a student giving ``value`` is told apart from the truth and from the
    reference's own answer (on a noisy problem the reference's estimate is off the truth):
    only then is a mistake worth a name."""
    return apart(problem, value, problem.truth, problem.right_answer())
