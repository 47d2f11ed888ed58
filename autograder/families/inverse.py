"""Inverse and transpose: b_T_a where a_T_b was asked, R^T where R was, a matrix transposed.

Applies to a pose answer (the inverse, the rotation transposed, the whole 4x4 transposed, or
transposed where its inverse belongs: no pose, named where the answer failed the pose check) and to any other square
matrix answer (its transpose). Output side: the truth transformed; the student's answer is
undone the same way (the inverse of an inverse) and compared with the truth.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, as_array, is_pose
from robots import geometry as geo

INVERSE = ("it is the inverse of the expected pose: b_T_a where a_T_b was asked (check "
           "which frame each transform maps from and to)")
TRANSPOSED = ("its rotation is the transpose of the expected one (R.T where R was asked: "
              "check the direction of the rotation)")
TRANSPOSE = "it is the transpose of the expected matrix"
WHOLE_TRANSPOSED = ("the whole 4x4 matrix is transposed (T.T: its last row is no longer "
                    "[0, 0, 0, 1]): only a rotation's inverse is its transpose; a pose's "
                    "inverse is [R^T | -R^T t]")
TRANSPOSED_FOR_INVERSE = ("the whole 4x4 matrix was transposed where its inverse belongs "
                          "(T.T for T^-1: its last row is no longer [0, 0, 0, 1]): only a "
                          "rotation's inverse is its transpose; a pose's inverse is "
                          "[R^T | -R^T t]")


def _inverse(problem: Problem) -> list[Prediction]:
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    return [Prediction(geo.invert(truth), lambda v: geo.invert(np.asarray(v, float)), truth)]


def _rotation_transposed(T) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, :3] = out[:3, :3].T
    return out


def _transposed_rotation(problem: Problem) -> list[Prediction]:
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    return [Prediction(_rotation_transposed(truth), _rotation_transposed, truth)]


def _whole_transposed(problem: Problem) -> list[Prediction]:
    # T.T is no pose (unless t = 0, where it is the transposed rotation, listed before it):
    # only an answer that failed the pose check lands near it
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    return [Prediction(truth.T, lambda v: np.asarray(v, float).T, truth)]


def _matrix_inverse(M) -> np.ndarray:
    try:
        return np.linalg.inv(np.asarray(M, dtype=float))
    except (np.linalg.LinAlgError, ValueError):
        return np.full((4, 4), np.nan)


def transposed_for_inverse(value, truth, distance) -> bool:
    """True when ``value`` is a 4x4 whose last row is no pose's and whose transpose is the
    pose whose inverse ``truth`` is, within the problem's noise (``distance(a, b)``: 1 at
    its edge): T.T returned for T^-1. Read from the answer itself, never a candidate: above
    its last row, (truth^-1).T is the truth with its translation zeroed, which the
    translation-left-out family predicts, and only that last row tells the two apart."""
    v = as_array(value)
    if v is None or v.shape != (4, 4) or not is_pose(truth) or not np.all(np.isfinite(v)):
        return False
    if np.allclose(v[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        return False
    back = _matrix_inverse(v.T)
    return bool(np.all(np.isfinite(back)) and distance(back, truth) <= 1.0)


def _never_a_candidate(problem: Problem) -> list[Prediction]:
    return []


def _transpose(problem: Problem) -> list[Prediction]:
    t = as_array(problem.truth)
    if t is None or is_pose(t) or t.ndim != 2 or t.shape[0] != t.shape[1]:
        return []
    return [Prediction(t.T, lambda v: np.asarray(v, float).T, t)]


# named by transposed_for_inverse, read from the answer (autograder.checks)
FOR_INVERSE = Family("inverse/transpose", TRANSPOSED_FOR_INVERSE, OUTPUT, _never_a_candidate,
                     "transposed for its inverse")
FAMILIES = (
    Family("inverse/transpose", INVERSE, OUTPUT, _inverse, "inverse pose"),
    Family("inverse/transpose", TRANSPOSED, OUTPUT, _transposed_rotation, "transposed rotation"),
    Family("inverse/transpose", TRANSPOSE, OUTPUT, _transpose, "transposed matrix"),
    Family("inverse/transpose", WHOLE_TRANSPOSED, OUTPUT, _whole_transposed,
           "whole pose transposed"),
    FOR_INVERSE,
)
