"""Root or not: the mean square where its root (an RMS) was asked, or the other way round.

Applies to a non-negative scalar or vector answer that is no pose. Output side: the answer's
square root (or square) is compared with the truth within the problem's noise.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, is_numeric_array

SQUARED = ("it is the square of the expected value: a mean square where its root (the RMS) "
           "was asked (take the square root)")
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


FAMILIES = (
    Family("root or not", SQUARED, OUTPUT, _squared, "squared"),
    Family("root or not", ROOTED, OUTPUT, _rooted, "rooted"),
)
