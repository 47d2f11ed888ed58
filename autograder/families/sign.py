"""A sign: the answer negated (a direction or an order taken the other way).

Applies to any numeric answer that is no pose (a pose negated is no pose). Output side.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, is_numeric_array

SIGN = ("it has the opposite sign of the expected answer (check the direction or the "
        "order)")


def _negated(problem: Problem) -> list[Prediction]:
    if not is_numeric_array(problem.truth):
        return []
    t = np.asarray(problem.truth, dtype=float)
    return [Prediction(-t, lambda v: -np.asarray(v, float), t, null=np.zeros_like(t))]


FAMILIES = (Family("sign", SIGN, OUTPUT, _negated, "sign"),)
