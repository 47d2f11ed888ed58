"""A stack's first or last item where the mean over all of them was asked.

Applies to a function whose inputs include stacks of the same length n >= 2 (poses, point
sets, vectors): input side, the private reference is called on the first (or the last) item
of each of them alone.
"""

from __future__ import annotations

from autograder.families.base import INPUT, Family, Prediction, Problem, as_array

FIRST = ("it uses only the first item of the inputs where all of them were asked (a mean "
         "over every item): loop over, or vectorise across, the whole stack")
LAST = ("it uses only the last item of the inputs where all of them were asked (a mean over "
        "every item): accumulate over the whole stack, not the loop's last value")


def _length(a) -> int | None:
    arr = None if isinstance(a, (int, float, str)) else as_array(a)
    return int(arr.shape[0]) if arr is not None and arr.ndim >= 2 and arr.shape[0] >= 2 \
        else None


def _one_item(at: slice):
    def make(problem: Problem) -> list[Prediction]:
        args = tuple(problem.trial.args)
        lengths = [_length(a) for a in args]
        n = max((x for x in lengths if x is not None), default=None)
        if n is None:
            return []
        cut = [a[at] if n_a == n else a for a, n_a in zip(args, lengths)]
        answer = problem.reference(*cut)
        return [] if answer is None else [Prediction(answer)]
    return make


FAMILIES = (
    Family("first/last for mean", FIRST, INPUT, _one_item(slice(0, 1)), "first item"),
    Family("first/last for mean", LAST, INPUT, _one_item(slice(-1, None)), "last item"),
)
