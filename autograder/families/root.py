"""Root or not: the mean square where its root (an RMS) was asked, or the other way round.

Applies to a non-negative scalar or vector answer that is no pose. Output side: the answer's
square root (or square) is compared with the truth within the problem's noise.

Input side, "not squared": a mean of norms (or of absolute values) where the mean of their
squares was asked, each item's root taken before averaging. It applies where the answer is
a mean over the items of the input stacks (:class:`.stacks.Reduction`, power 1): the
reference on each item alone gives that item's square, and the mistake is the mean of their
roots. A mean of absolute errors where an RMS was asked is :mod:`.absolute`'s.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, OUTPUT, Family, Prediction, Problem, is_numeric_array
from autograder.families.stacks import loses_credit, reduction

SQUARED = ("it is the square of the expected value: a mean square where its root (the RMS) "
           "was asked (take the square root)")
NOT_SQUARED = ("each item's error is not squared: a mean of norms (or of absolute values) "
               "where the mean of their squares was asked (square each before averaging)")
ROOTED = ("it is the square root of the expected value: an RMS or a norm where the squared "
          "value was asked (drop the square root)")


def _non_negative(problem: Problem) -> np.ndarray | None:
    if not is_numeric_array(problem.truth):
        return None
    t = np.asarray(problem.truth, dtype=float)
    return t if t.ndim <= 1 and np.all(t >= 0) and np.any(t > 0) else None


def _squared(problem: Problem) -> list[Prediction]:
    t = _non_negative(problem)
    return [] if t is None else [Prediction(t ** 2, lambda v: np.sqrt(np.asarray(v, float)), t,
                                            null=np.zeros_like(t))]


def _rooted(problem: Problem) -> list[Prediction]:
    t = _non_negative(problem)
    return [] if t is None else [Prediction(np.sqrt(t), lambda v: np.asarray(v, float) ** 2, t,
                                            null=np.zeros_like(t))]


def _not_squared(problem: Problem) -> list[Prediction]:
    r = reduction(problem, min_items=2)
    if r is None or r.power != 1 or r.divisor != r.n or np.any(r.items < 0):
        return []
    value = np.sqrt(r.items).mean(axis=0)
    # in the reference's type: a float answer stays a float (practice data keeps types)
    answer = float(value) if np.ndim(problem.right_answer()) == 0 else value
    return [Prediction(answer)] if loses_credit(problem, answer) else []


FAMILIES = (
    Family("root or not", SQUARED, OUTPUT, _squared, "squared"),
    Family("root or not", ROOTED, OUTPUT, _rooted, "rooted"),
    Family("root or not", NOT_SQUARED, INPUT, _not_squared, "not squared"),
)
