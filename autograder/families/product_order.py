"""The order of a product: B A where A B was asked, for a function that composes poses.

Applies to a function whose inputs hold poses (a pose, a stack of poses) and whose answer
is a pose, a stack of poses, or a tuple of stacks. Inverting every factor of a product and
then the product reverses the order of its factors: inv(inv(A) inv(B)) = B A. So the
reference called with the input poses inverted, its answer (each of its poses) inverted
back, is the answer of a student who multiplied each product in reverse order: a chain
composed right to left, the motion T_k^-1 T_{k+1} where T_{k+1} T_k^-1 was asked. Tried on
all pose inputs at once and on each alone; the parts of a tuple answer that the inversion
left unchanged stay as they are (B built right, A in the wrong order). Input side.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import (
    INPUT,
    Family,
    Prediction,
    Problem,
    is_pose,
    is_stack,
    same_answer,
)
from robots import geometry as geo

REVERSED_PRODUCT = ("the factors of a product are in reverse order (B @ A where A @ B was "
                    "asked; T_k^-1 T_{k+1} where T_{k+1} T_k^-1 was): frames chain left to "
                    "right, a_T_b @ b_T_c = a_T_c")


def _inverted(value):
    """A pose or a stack of poses with each pose inverted, in the container it came in."""
    if is_pose(value):
        return geo.invert(np.asarray(value, float))
    poses = [geo.invert(np.asarray(T, float)) for T in value]
    return list(poses) if isinstance(value, list) else np.stack(poses)


def _poses(value) -> bool:
    return is_pose(value) or is_stack(value)


def _back(answer, right):
    """``answer`` with each pose part that differs from ``right`` inverted back; None when
    no part is a pose or a stack of them."""
    if _poses(answer):
        return _inverted(answer)
    if not isinstance(answer, tuple) or not isinstance(right, tuple) \
            or len(answer) != len(right) or not any(_poses(a) for a in answer):
        return None
    return tuple(_inverted(a) if _poses(a) and not same_answer(a, r) else a
                 for a, r in zip(answer, right))


def _reversed_products(problem: Problem) -> list[Prediction]:
    args = tuple(problem.trial.args)
    which = [i for i, a in enumerate(args) if _poses(a)]
    if not which or problem.truth is None:
        return []
    right = problem.right_answer()
    subsets = [which] + ([[i] for i in which] if len(which) > 1 else [])
    out = []
    for subset in subsets:
        def changed(subset=subset):
            return tuple(_inverted(a) if i in subset else a for i, a in enumerate(args))
        # each pose input inverted alone is reversed_stack's call too: one call for both
        answer = problem.reference_on(("inverted", tuple(subset)), changed)
        back = None if answer is None else _back(answer, right)
        # a single factor has no order (the inverse of an inverse): no mistake here
        if back is not None and not (right is not None and same_answer(back, right)):
            out.append(Prediction(back))
    return out


FAMILIES = (Family("reversed stack/order", REVERSED_PRODUCT, INPUT, _reversed_products,
                   "product order"),)
