"""Item by item on a stack of poses: each pose of an answer inverted, or its rotation
transposed.

Applies to an answer that is a stack of poses (an (n, 4, 4) array or a list), or a tuple of
such stacks (the motions (A, B)), each part alone: a loop that builds each pose makes the
same mistake on every one (b_T_a for a_T_b, R^T for R). Output side: the student's stack
is undone item by item and compared with the truth.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, as_array, is_stack
from robots import geometry as geo

INVERTED = ("each pose of the stack is the inverse of the expected one (b_T_a where a_T_b "
            "was asked): check which frame each transform maps from and to")
TRANSPOSED = ("the rotation of each pose of the stack is the transpose of the expected one "
              "(R^T where R was asked): check the direction of the rotation")
PART = "{part}: "
ORDINALS = ("the first item of the answer", "the second item of the answer",
            "the third item of the answer")


def _each_inverted(stack) -> np.ndarray:
    return np.stack([geo.invert(T) for T in np.asarray(stack, float)])


def _each_transposed(stack) -> np.ndarray:
    out = np.array(stack, dtype=float)
    out[:, :3, :3] = np.transpose(out[:, :3, :3], (0, 2, 1))
    return out


def _items(change, words: str):
    def make(problem: Problem) -> list[Prediction]:
        truth = problem.truth
        if is_stack(truth):
            t = np.asarray(truth, dtype=float)
            return [Prediction(change(t), change, t)]
        if not isinstance(truth, tuple) or not any(is_stack(p) for p in truth):
            return []
        out = []
        for k, part in enumerate(truth):
            if not is_stack(part):
                continue

            def apply(v, k=k):
                return tuple(change(as_array(x)) if i == k else x for i, x in enumerate(v))
            name = ORDINALS[k] if k < len(ORDINALS) else f"item {k + 1} of the answer"
            out.append(Prediction(apply(truth), apply, truth, PART.format(part=name) + words))
        return out
    return make


FAMILIES = (
    Family("inverse/transpose", INVERTED, OUTPUT, _items(_each_inverted, INVERTED),
           "each pose inverted"),
    Family("inverse/transpose", TRANSPOSED, OUTPUT, _items(_each_transposed, TRANSPOSED),
           "each rotation transposed"),
)
