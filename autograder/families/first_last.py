"""A stack's first or last item where the mean over all of them was asked.

Applies to a function whose answer is the mean over the items of its input stacks (of one
length n >= 3; with two items the first alone is also "all but the last"): the reference's
answer is the mean of its answers on each item alone. Input side: the private reference is
called on the first (or the last) item of each stack alone.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem, as_array, same_answer

FIRST = ("it uses only the first item of the inputs where all of them were asked (a mean "
         "over every item): loop over, or vectorise across, the whole stack")
LAST = ("it uses only the last item of the inputs where all of them were asked (a mean over "
        "every item): accumulate over the whole stack, not the loop's last value")


def _length(a) -> int | None:
    arr = None if isinstance(a, (int, float, str)) else as_array(a)
    return int(arr.shape[0]) if arr is not None and arr.ndim >= 2 and arr.shape[0] >= 2 \
        else None


def stack_lengths(args) -> list[int | None]:
    """Each argument's number of items when it is a stack (n >= 2 rows of 2-D or more
    items: poses, points), else None."""
    return [_length(a) for a in args]


def _one_item(at: int):
    def make(problem: Problem) -> list[Prediction]:
        args = tuple(problem.trial.args)
        lengths = stack_lengths(args)
        n = max((x for x in lengths if x is not None), default=None)
        if n is None or n < 3:
            return []
        items = [as_array(problem.reference(*[a[i:i + 1] if n_a == n else a
                                              for a, n_a in zip(args, lengths)]))
                 for i in range(n)]
        whole = as_array(problem.reference(*args))
        if whole is None or any(x is None or x.shape != whole.shape for x in items) \
                or not same_answer(np.mean(items, axis=0), whole):
            return []   # no mean over the items: no item stands for it
        return [Prediction(items[at])]
    return make


FAMILIES = (
    Family("first/last for mean", FIRST, INPUT, _one_item(0), "first item"),
    Family("first/last for mean", LAST, INPUT, _one_item(-1), "last item"),
)
