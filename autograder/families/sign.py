"""A sign: the answer negated (a direction or an order taken the other way).

Applies to any numeric answer that is no pose (a pose negated is no pose: a pose's
translation negated is :mod:`.pose_parts`'), and to each part alone of a tuple answer (a
plane's normal flipped beside its right centre). Output side.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import (
    OUTPUT,
    Family,
    Prediction,
    Problem,
    is_numeric_array,
    part_predictions,
    parts,
)

SIGN = ("it has the opposite sign of the expected answer (check the direction or the "
        "order)")
PART_SIGN = ("item {k} of the answer has the opposite sign of the expected one, the rest "
             "is right (check the direction of that vector, or the order of a difference)")


def _negated(problem: Problem) -> list[Prediction]:
    split = parts(problem.truth)
    if split is not None:
        # a pose or a stack of poses negated is none: only the plain parts
        found = part_predictions(problem.truth, lambda t: -t, lambda v: -v,
                                 lambda k: PART_SIGN.format(k=k + 1))
        return [p for p, part in zip(found, split) if is_numeric_array(part)]
    if not is_numeric_array(problem.truth):
        return []
    t = np.asarray(problem.truth, dtype=float)
    return [Prediction(-t, lambda v: -np.asarray(v, float), t, null=np.zeros_like(t))]


FAMILIES = (Family("sign", SIGN, OUTPUT, _negated, "sign"),)
