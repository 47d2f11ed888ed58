"""The wrong axis: a reduction over the items and the answer's axes at once where one value
per axis was asked (np.mean(r ** 2) for np.mean(r ** 2, axis=0): one RMS repeated on x, y
and z), or over each item's axes where it was over the items (axis=1 for axis=0).

Applies to a function whose answer is a short vector (one value per axis) reduced over the
items of its input stacks (:class:`.stacks.Reduction` with divisor n). Input side: the
reference on each item alone gives that item's per-axis values; the mistake reduces them
over every axis together (the one value in each slot), or over each item's axes (one value
per item).

Only partly covered: one value per item is an (N,) answer for a (3,) one, which the grader
cannot measure and names no mistake on; it is predicted only where N is the number of axes.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem
from autograder.families.stacks import loses_credit, reduction

PER_ITEM = ("it reduces over each item's axes (axis=1) where one value per axis, over the "
            "items, was asked: reduce over the items (axis=0)")
ALL_AXES = ("one value is repeated on every axis: it reduces over the axes too (axis=None) "
            "where one value per axis was asked: reduce over the items only (axis=0)")


def _all_axes(problem: Problem) -> list[Prediction]:
    r = reduction(problem, min_items=2)
    if r is None or r.divisor != r.n or r.items.ndim != 2 or r.items.shape[1] < 2:
        return []
    k = r.items.shape[1]
    value = np.full(k, (np.sum(r.items ** r.power) / (r.n * k)) ** (1.0 / r.power))
    return [Prediction(value)] if loses_credit(problem, value) else []


def _per_item(problem: Problem) -> list[Prediction]:
    r = reduction(problem, min_items=2)
    if r is None or r.divisor != r.n or r.items.ndim != 2 or r.items.shape != (r.n, r.n):
        return []   # another shape than the answer's: no answer to compare with
    value = np.mean(r.items ** r.power, axis=1) ** (1.0 / r.power)
    return [Prediction(value)] if loses_credit(problem, value) else []


FAMILIES = (
    Family("wrong axis", ALL_AXES, INPUT, _all_axes, "all axes"),
    Family("wrong axis", PER_ITEM, INPUT, _per_item, "per item"),
)
