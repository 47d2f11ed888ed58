"""Absolute for squared: a mean of absolute (unsquared) errors where the mean of squared
errors, or their root (an RMS), was asked.

Applies to a function whose answer is a non-negative scalar or a short vector (a scalar
error over a stack, a per-axis RMS) and whose inputs include stacks of one length n >= 2
(motions, point sets) that the answer does not list item by item. Input side: the private
reference, called on each item alone, gives that item's squared error (for a mean square)
or its absolute error (for an RMS); the mistake's answer is the mean over the items of the
absolute errors.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem, as_array, is_numeric_array
from autograder.families.first_last import stack_lengths

ABSOLUTE = ("it is a mean of absolute errors where squared errors were asked (a mean square "
            "or its root, the RMS): square each error before averaging")


def _per_item(problem: Problem) -> list[np.ndarray] | None:
    args = tuple(problem.trial.args)
    lengths = stack_lengths(args)
    n = max((x for x in lengths if x is not None), default=None)
    truth = as_array(problem.truth)
    if n is None or truth is None or truth.ndim > 1 or truth.size == n or truth.size > 3:
        return None
    items = []
    for i in range(n):
        answer = problem.reference(*[a[i:i + 1] if n_a == n else a
                                     for a, n_a in zip(args, lengths)])
        value = as_array(answer)
        if value is None or value.shape != truth.shape or np.any(value < 0):
            return None
        items.append(value)
    return items


def _absolute(problem: Problem) -> list[Prediction]:
    if not is_numeric_array(problem.truth) or np.any(np.asarray(problem.truth) < 0):
        return []
    items = _per_item(problem)
    if items is None:
        return []
    stacked = np.stack(items)
    # an RMS's item is |e_i|, a mean square's is e_i^2: each reading's mean of |e_i| (the
    # one that equals the truth is the truth, and the grader drops it as no mistake)
    return [Prediction(stacked.mean(axis=0)), Prediction(np.sqrt(stacked).mean(axis=0))]


FAMILIES = (Family("absolute for squared", ABSOLUTE, INPUT, _absolute, "absolute for squared"),)
