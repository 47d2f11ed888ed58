"""A stack's first or last item where the mean (or the RMS) over all of them was asked.

Applies to a function whose answer is a mean or a root mean square over the items of its
input stacks of n >= 3 items (with two, the first alone is also "all but the last"; see
:class:`.stacks.Reduction`). Input side: the private reference is called on the first (or
the last) item of each stack alone.

An odd stack's median, and any stack's maximum, is one of its items: where it is the first
or the last item, the answer is as much a median or a maximum (.statistic) as one item for
all, and neither is named.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem
from autograder.families.stacks import coincide, loses_credit, reduction

FIRST = ("it uses only the first item of the inputs where all of them were asked (a mean "
         "over every item): loop over, or vectorise across, the whole stack")
LAST = ("it uses only the last item of the inputs where all of them were asked (a mean over "
        "every item): accumulate over the whole stack, not the loop's last value")


def _one_item(at: int):
    def make(problem: Problem) -> list[Prediction]:
        r = reduction(problem)
        if r is None or r.divisor != r.n:
            return []   # no mean over the items: no item stands for it
        item = r.items[at]
        if coincide(item, [r.median(), r.maximum()]):
            return []   # as much a median or a maximum (.statistic) as one item: no name
        # in the reference's type: a float answer stays a float (practice data keeps types)
        answer = float(item) if np.ndim(problem.right_answer()) == 0 else item
        return [Prediction(answer)] if loses_credit(problem, answer) else []
    return make


FAMILIES = (
    Family("first/last for mean", FIRST, INPUT, _one_item(0), "first item"),
    Family("first/last for mean", LAST, INPUT, _one_item(-1), "last item"),
)
