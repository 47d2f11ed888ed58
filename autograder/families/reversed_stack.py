"""A reversed stack or order: a stack of inputs taken last to first, or each of its poses
inverted (which reverses the order of every product built from them: inv(C_i) C_j where
C_i inv(C_j) was meant), or one input pose inverted.

Applies to a function with a stack of poses (a list or an (n, 4, 4) array) or a pose among
its inputs. Input side: the private reference is called on the transformed input.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem, is_pose, is_stack
from robots import geometry as geo

REVERSED = ("an input stack is taken in reverse order (last to first): keep the order the "
            "items are given in")
INVERTED = ("the poses of an input stack are used inverted (b_T_a for a_T_b), which "
            "reverses the order of each product built from them: check the order of the "
            "factors in each motion or chain")
POSE_INVERTED = ("an input pose is used inverted (b_T_a where a_T_b was given): check which "
                 "frame each transform maps from and to")


def _like(original, poses: list[np.ndarray]):
    """``poses`` in the container ``original`` came in (a list stays a list)."""
    return list(poses) if isinstance(original, list) else \
        tuple(poses) if isinstance(original, tuple) else np.stack(poses)


def _each(problem: Problem, test, change, tag: str) -> list[Prediction]:
    out = []
    args = tuple(problem.trial.args)
    for i, a in enumerate(args):
        if test(a):
            def changed(i=i, a=a):
                return tuple(change(a) if k == i else x for k, x in enumerate(args))
            # (tag, (i,)): the key product_order shares for the same inputs inverted
            answer = problem.reference_on((tag, (i,)), changed)
            if answer is not None:
                out.append(Prediction(answer))
    return out


def _reversed(problem: Problem) -> list[Prediction]:
    return _each(problem, is_stack, lambda a: _like(a, [np.asarray(T, float) for T in a][::-1]),
                 "reversed")


def _inverted(problem: Problem) -> list[Prediction]:
    return _each(problem, is_stack,
                 lambda a: _like(a, [geo.invert(np.asarray(T, float)) for T in a]), "inverted")


def _pose_inverted(problem: Problem) -> list[Prediction]:
    return _each(problem, is_pose, lambda a: geo.invert(np.asarray(a, float)), "inverted")


FAMILIES = (
    Family("reversed stack/order", REVERSED, INPUT, _reversed, "reversed stack"),
    Family("reversed stack/order", INVERTED, INPUT, _inverted, "stack inverted"),
    Family("inverse/transpose", POSE_INVERTED, INPUT, _pose_inverted, "input pose inverted"),
)
