"""The wrong statistic over a stack: the median or the maximum where the mean (or the RMS)
was asked, n - 1 where n divides (or n where n - 1 does), the mean where the sum was asked.

Applies to a function whose answer is a reduction over the items of its input stacks (a
mean error over motions, a per-axis RMS over points; see :class:`.stacks.Reduction`): the
reference's answers on each item alone give the per-item values ``v_i``, and each mistake
is the same values reduced the other way (the median of an RMS's ``|e_i|`` is the root of
the median of ``e_i^2``). Input side (it calls the private reference on each item).

A centred statistic (a standard deviation, a variance) is no reduction of its items' own
answers (one item has no spread), so n - 1 for n (np.std's ddof) is also read from the
answer, output side: the truth times n / (n - 1), or its root for a statistic that is a
root, for each stack length n >= 3 of the inputs (with two, n / (n - 1) is the sum's 2).

Not covered: the centred standard deviation where the RMS was asked. It needs the signs of
the per-item errors, and a reference on one item gives only ``|e_i|``.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, OUTPUT, Family, Prediction, Problem, is_numeric_array
from autograder.families.stacks import Reduction, coincide, lengths_of, loses_credit, reduction

MEDIAN = ("it takes the median over the items where their mean (or RMS) was asked: "
          "average over every item (np.mean), the median ignores how large the largest "
          "errors are")
MAXIMUM = ("it takes the largest item where the mean (or RMS) over the items was asked: "
           "average over every item (np.mean), not np.max")
N_MINUS_1 = ("it divides by n - 1 where the mean over the n items was asked: divide by n "
             "(np.mean; np.std and np.var take ddof=0 unless told otherwise)")
N_FOR_N_MINUS_1 = ("it divides by n where n - 1 was asked (the unbiased estimate): divide "
                   "by n - 1 (ddof=1)")
MEAN_FOR_SUM = ("it is the mean over the items where their sum was asked: add them up, "
                "do not divide by their number")


def _statistic(of):
    """A family's make: ``of(reduction)`` the mistaken value, or None where the mistake
    does not apply to that reduction."""
    def make(problem: Problem) -> list[Prediction]:
        if problem.spec is None or problem.spec.reference is None:
            return []
        r = reduction(problem)
        value = None if r is None else of(r)
        if value is None:
            return []
        # in the reference's type: a float answer stays a float (practice data keeps types)
        answer = float(value) if np.ndim(problem.right_answer()) == 0 else value
        return [Prediction(answer)] if loses_credit(problem, answer) else []
    return make


def _median(r: Reduction) -> np.ndarray | None:
    value = r.median()
    return None if r.divisor == 1 or coincide(value, r.ends()) else value


def _maximum(r: Reduction) -> np.ndarray | None:
    value = r.maximum()
    return None if r.divisor == 1 or coincide(value, r.ends()) else value


def _n_minus_1(r: Reduction) -> np.ndarray | None:
    return r.over(r.n - 1) if r.divisor == r.n else None


def _n_for_n_minus_1(r: Reduction) -> np.ndarray | None:
    return r.over(r.n) if r.divisor == r.n - 1 else None


def _mean_for_sum(r: Reduction) -> np.ndarray | None:
    return r.over(r.n) if r.divisor == 1 else None


def _divisor_swapped(up: bool):
    """The truth with n - 1 for n (``up``) or n for n - 1, linear and rooted, for each stack
    length n >= 3 among the inputs (output side: no reference)."""
    def make(problem: Problem) -> list[Prediction]:
        if problem.spec is None or not is_numeric_array(problem.truth):
            return []
        truth = np.asarray(problem.truth, dtype=float)
        out = []
        for n in sorted({n for n in lengths_of(problem) if n and n >= 3}):
            ratio = n / (n - 1) if up else (n - 1) / n
            for factor in (ratio, np.sqrt(ratio)):
                answer = float(truth * factor) if truth.ndim == 0 else truth * factor
                if loses_credit(problem, answer):
                    out.append(Prediction(answer))
        return out
    return make


FAMILIES = (
    Family("wrong statistic", MEDIAN, INPUT, _statistic(_median), "median for mean"),
    Family("wrong statistic", MAXIMUM, INPUT, _statistic(_maximum), "max for mean"),
    Family("wrong statistic", N_MINUS_1, INPUT, _statistic(_n_minus_1), "n-1 for n"),
    Family("wrong statistic", N_FOR_N_MINUS_1, INPUT, _statistic(_n_for_n_minus_1),
           "n for n-1"),
    Family("wrong statistic", MEAN_FOR_SUM, INPUT, _statistic(_mean_for_sum), "mean for sum"),
    Family("wrong statistic", N_MINUS_1, OUTPUT, _divisor_swapped(True), "n-1 for n, any"),
    Family("wrong statistic", N_FOR_N_MINUS_1, OUTPUT, _divisor_swapped(False),
           "n for n-1, any"),
)
