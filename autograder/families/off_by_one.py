"""Off by one: a loop over a stack that leaves out its first or its last item, or that
takes one of them twice.

Applies to any function with a stack among its inputs (an (N, 3) point set, a stack of
poses; see :mod:`.stacks`), whatever its answer: a mean over the items, a fit, a product
of the poses (``range(1, n)`` drops the first factor, ``range(n - 1)`` the last). Input
side: the private reference is called with every stack of the most items cut (or the item
repeated) the same way, so paired stacks (A and B, src and dst) stay paired. Named only
where the answer it gives loses credit (a fit on noisy points without one of twenty is
still right).

An item is left out only from a stack of three or more: with two, what remains is one item,
as much "only the first (or last) item" as "the other end left out" (or the stack reversed
and cut), and no one mistake describes it.
"""

from __future__ import annotations

from autograder.families.base import INPUT, Family, Prediction, Problem
from autograder.families.stacks import lengths_of, longest, loses_credit, with_stacks

WITHOUT_FIRST = ("it leaves out the first item of the input stack (a loop from 1, or a "
                 "slice [1:]): go over every item, from index 0")
WITHOUT_LAST = ("it leaves out the last item of the input stack (range(n - 1), or a slice "
                "[:-1]): go over every item, up to index n - 1")
FIRST_TWICE = ("it takes the first item of the input stack twice (one item too many): go "
               "over each item once")
LAST_TWICE = ("it takes the last item of the input stack twice (one item too many, as "
              "range(n + 1) with the index clipped): go over each item once")


def _off_by_one(change, min_items: int):
    def make(problem: Problem) -> list[Prediction]:
        args = tuple(problem.trial.args)
        lengths = lengths_of(problem)
        n = longest(args, lengths)
        if n is None or n < min_items or problem.spec is None or problem.spec.reference is None:
            return []
        answer = problem.reference(*with_stacks(args, n, change, lengths))
        if answer is None or not loses_credit(problem, answer):
            return []
        return [Prediction(answer)]
    return make


FAMILIES = (
    Family("off by one", WITHOUT_FIRST, INPUT, _off_by_one(lambda s: s[1:], 3), "first left out"),
    Family("off by one", WITHOUT_LAST, INPUT, _off_by_one(lambda s: s[:-1], 3), "last left out"),
    Family("off by one", FIRST_TWICE, INPUT, _off_by_one(lambda s: [s[0], *s], 2), "first twice"),
    Family("off by one", LAST_TWICE, INPUT, _off_by_one(lambda s: [*s, s[-1]], 2), "last twice"),
)
