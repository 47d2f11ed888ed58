"""The wrong axis: a reduction over the items and the answer's axes at once where one value
per axis was asked (np.mean(r ** 2) for np.mean(r ** 2, axis=0): one RMS repeated on x, y
and z).

Applies to a function whose answer is a short vector (one value per axis) reduced over the
items of its input stacks (:class:`.stacks.Reduction` with divisor n). Input side: the
reference on each item alone gives that item's per-axis values, and the mistake reduces
them over every axis together, the one value in each slot.

Not covered: a reduction that changes the answer's shape (per point where per axis was
asked: an (N,) answer for a (3,) one). Such an answer cannot be measured, and the grader
names no mistake on an answer it cannot measure.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem
from autograder.families.stacks import loses_credit, reduction

ALL_AXES = ("one value is repeated on every axis: it reduces over the axes too (axis=None) "
            "where one value per axis was asked: reduce over the items only (axis=0)")


def _all_axes(problem: Problem) -> list[Prediction]:
    r = reduction(problem, min_items=2)
    if r is None or r.divisor != r.n or r.items.ndim != 2 or r.items.shape[1] < 2:
        return []
    k = r.items.shape[1]
    value = np.full(k, (np.sum(r.items ** r.power) / (r.n * k)) ** (1.0 / r.power))
    return [Prediction(value)] if loses_credit(problem, value) else []


FAMILIES = (Family("wrong axis", ALL_AXES, INPUT, _all_axes, "all axes"),)
