"""Swapped arguments: two inputs of the same kind used the other way round (A for B).

Applies to a function with two inputs of the same shape (two point sets, two stacks of
poses, two vectors). Input side: the private reference is called with the pair swapped.
"""

from __future__ import annotations

from autograder.families.base import INPUT, Family, Prediction, Problem, as_array

SWAPPED = ("two inputs of the same kind are used the other way round (swapped): check "
           "which argument is which, in the order of the parameters")


def same_kind_pairs(args) -> list[tuple[int, int]]:
    """(i, j), i < j, of the array arguments that have the same shape."""
    shapes = [getattr(as_array(a), "shape", None) if not isinstance(a, (int, float, str))
              else None for a in args]
    return [(i, j) for i in range(len(args)) for j in range(i + 1, len(args))
            if shapes[i] is not None and shapes[i] == shapes[j] and shapes[i] != ()]


def _swapped(problem: Problem) -> list[Prediction]:
    args = tuple(problem.trial.args)
    out = []
    for i, j in same_kind_pairs(args):
        swapped = list(args)
        swapped[i], swapped[j] = args[j], args[i]
        answer = problem.reference(*swapped)
        if answer is not None:
            out.append(Prediction(answer))
    return out


FAMILIES = (Family("swapped arguments", SWAPPED, INPUT, _swapped, "swapped arguments"),)
