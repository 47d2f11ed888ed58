"""Precision: float32 arithmetic where float64 was asked.

Applies to a numeric answer (a pose, a vector, a scalar) on a problem whose tolerance is
tight enough that float32 rounding alone loses credit there (the truth rounded to float32
lies outside the tolerance band: exact problems, never noisy ones, nor a problem whose
tolerance was set to hold float32). Output side, read from the answer itself: an answer
whose every value is a float32 number (its dtype, or float64 values that float32 holds
exactly) and that lies within float32 arithmetic's reach of the truth (1e-4 of the truth's
largest value, room for cancellation in a difference of nearly equal values, far below any
other mistake's change) is the truth computed in float32.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, as_array, parts
from autograder.families.stacks import noise_units

FLOAT32 = ("it is computed in float32 (single precision), whose rounding alone exceeds the "
           "tolerance here: keep float64 arrays throughout (np.float64, no dtype=np.float32, "
           "no .astype(np.float32))")

# float32 arithmetic's reach, relative to the truth's largest value: about 840 float32
# epsilons, for a residual that is a small difference of metre-sized values; a wrong
# statistic or divisor moves an answer by per cents.
REACH = 1e-4
# float32 loses credit where the truth rounded to float32 is this far out, in noise units.
SHOWS = 1.0


def _in_float32(value) -> bool:
    a = np.asarray(value)
    if a.dtype == np.float32:
        return True
    f = np.asarray(value, dtype=float)
    return bool(np.array_equal(f.astype(np.float32).astype(float), f))


def _float32(problem: Problem) -> list[Prediction]:
    truth = as_array(problem.truth)
    if problem.spec is None or truth is None or parts(problem.truth) is not None \
            or isinstance(problem.truth, (tuple, list)):
        return []
    rounded = truth.astype(np.float32).astype(float)
    if _in_float32(truth) or not noise_units(problem, rounded, problem.truth) > SHOWS:
        return []   # float32 loses no credit here: no mistake to name
    reach = REACH * float(np.abs(truth).max())

    def undo(value):
        # the float64 answer a float32 one stands for: the truth, when the answer is float32
        # numbers within float32 arithmetic's reach of it; else the answer as it is
        v = np.asarray(value, dtype=float)
        if v.shape == truth.shape and _in_float32(value) \
                and float(np.abs(v - truth).max()) <= reach:
            return truth.copy()
        return v

    return [Prediction(rounded, undo, truth)]


FAMILIES = (Family("precision", FLOAT32, OUTPUT, _float32, "float32"),)
