"""Absolute for squared: a mean of absolute (unsquared) errors where their root mean square
(an RMS) was asked.

Applies to a function whose answer is an RMS over the items of its input stacks (a scalar
error over a stack, a per-axis RMS over points; see :class:`.stacks.Reduction`, power 2):
the private reference, called on each item alone, gives that item's absolute error
``|e_i|``, and the mistake's answer is their mean. Input side.

A mean of norms where a mean of *squared* norms was asked (no root anywhere) is the other
reading of "not squared": :mod:`.root` names it, so that the two never both fit.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem
from autograder.families.stacks import loses_credit, reduction

ABSOLUTE = ("it is a mean of absolute errors where their root mean square (the RMS) was "
            "asked: square each error, average, then take the square root")


def _absolute(problem: Problem) -> list[Prediction]:
    r = reduction(problem, min_items=2)
    if r is None or r.power != 2 or r.divisor != r.n:
        return []
    value = r.items.mean(axis=0)
    # in the reference's type: a float answer stays a float (practice data keeps types)
    answer = float(value) if np.ndim(problem.right_answer()) == 0 else value
    return [Prediction(answer)] if loses_credit(problem, answer) else []


FAMILIES = (Family("absolute for squared", ABSOLUTE, INPUT, _absolute, "absolute for squared"),)
