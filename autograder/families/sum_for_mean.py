"""Sum for mean: a sum over the inputs' items where their mean was asked.

Applies to a numeric answer (no pose) of a function with a stacked input (a stack of poses,
an (N, 3) point set, a vector): the answer is N times the truth for that input's N. Output
side (N is read from the inputs' shapes): the answer divided by N is compared with the truth.
A single pose's four rows, or a depth image's rows, are no items (:mod:`.stacks`).
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, as_array, is_numeric_array
from autograder.families.stacks import stack_lengths

SUM = ("it is a sum over the items where their mean was asked: divide by their number")


def _counts(args) -> list[int]:
    found = []
    for a, n in zip(args, stack_lengths(args)):
        arr = None if isinstance(a, (str, bytes, dict)) else as_array(a)
        if n is not None:
            found.append(n)
        elif arr is not None and arr.ndim == 1 and arr.shape[0] >= 2:
            found.append(int(arr.shape[0]))   # a vector's entries are its items
    return sorted(set(found))


def _summed(problem: Problem) -> list[Prediction]:
    if not is_numeric_array(problem.truth):
        return []
    t = np.asarray(problem.truth, dtype=float)
    return [Prediction(t * n, lambda v, n=n: np.asarray(v, float) / n, t, null=np.zeros_like(t))
            for n in _counts(problem.trial.args)]


FAMILIES = (Family("sum for mean", SUM, OUTPUT, _summed, "sum for mean"),)
