"""Metres and millimetres in an input: one input's lengths converted and the others not.

Applies to a function with a length-carrying input (a point set, a pose, a stack of poses):
input side, the private reference is called with that input's lengths (the points, the
translations) times 1000 or a thousandth.
"""

from __future__ import annotations

from autograder.families.base import (
    INPUT,
    Family,
    Prediction,
    Problem,
    is_points,
    is_pose,
    is_stack,
    scale_lengths,
)

MM_INPUT = ("one input's lengths were taken in millimetres (times 1000) while the rest are in "
            "metres: keep every length in metres")
M_INPUT = ("one input's lengths were divided by 1000 while the rest were not: they are "
           "already in metres")


def _scaled_input(factor: float):
    def make(problem: Problem) -> list[Prediction]:
        args = tuple(problem.trial.args)
        out = []
        for i, a in enumerate(args):
            if isinstance(a, (int, float)) or not (is_points(a) or is_pose(a) or is_stack(a)):
                continue
            changed = list(args)
            changed[i] = scale_lengths(a, factor)
            answer = problem.reference(*changed)
            if answer is not None:
                out.append(Prediction(answer))
        return out
    return make


FAMILIES = (
    Family("units m/mm", MM_INPUT, INPUT, _scaled_input(1000.0), "input in millimetres"),
    Family("units m/mm", M_INPUT, INPUT, _scaled_input(1e-3), "input divided by 1000"),
)
