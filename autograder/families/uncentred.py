"""An uncentred fit: a rigid fit of two point sets made without subtracting their centroids,
or with its translation left from before the reflection fix.

Applies to a function of two (N, 3) point sets whose answer is a pose that maps one set
onto the other (the truth tells which way: ``Q_i = R P_i + t``). Output side, the fit
redone from the inputs with plain SVD (Kabsch) math, no solver:

* uncentred: ``H = sum P_i Q_i^T`` of the raw points, ``R`` from its SVD (reflection fixed),
  ``t = c_Q - R c_P``;
* translation before the fix: ``R`` fixed, but ``t = c_Q - R0 c_P`` with ``R0`` the mirror
  image before the fix (only where the centred fit needs the fix).

Named only where the fit it gives loses credit (far from the truth and the reference's
answer on the problem's noise scale).
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import (
    OUTPUT,
    Family,
    Prediction,
    Problem,
    as_array,
    is_points,
    is_pose,
)
from autograder.families.stacks import loses_credit

UNCENTRED = ("the fit is made of the raw points, not the centred ones: subtract each set's "
             "centroid before the cross-covariance H = sum (p_i - c_p)(q_i - c_q)^T")
TRANSLATION = ("the translation was computed before the rotation's reflection fix: "
               "recompute t = c_q - R c_p with the fixed R")


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _pairs(problem: Problem) -> list[tuple[np.ndarray, np.ndarray]]:
    """(P, Q) of the point-set inputs, each pair ordered so the truth maps P onto Q."""
    args = [as_array(a) if is_points(a) else None for a in problem.trial.args]
    T = problem.truth
    out = []
    for i, a in enumerate(args):
        for b in args[i + 1:]:
            if a is None or b is None or a.shape != b.shape:
                continue
            forward = np.abs(a @ T[:3, :3].T + T[:3, 3] - b).mean()
            backward = np.abs(b @ T[:3, :3].T + T[:3, 3] - a).mean()
            out.append((a, b) if forward <= backward else (b, a))
    return out


def _rotation(H: np.ndarray, fixed: bool = True) -> np.ndarray:
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) if fixed else 1.0
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def _uncentred(P: np.ndarray, Q: np.ndarray) -> np.ndarray | None:
    R = _rotation(P.T @ Q)
    return _pose(R, Q.mean(axis=0) - R @ P.mean(axis=0))


def _translation_before_fix(P: np.ndarray, Q: np.ndarray) -> np.ndarray | None:
    cP, cQ = P.mean(axis=0), Q.mean(axis=0)
    H = (P - cP).T @ (Q - cQ)
    mirror = _rotation(H, fixed=False)
    if np.linalg.det(mirror) > 0:
        return None   # no fix needed: the translation is the right one
    return _pose(_rotation(H), cQ - mirror @ cP)


def _fit(mistake):
    def make(problem: Problem) -> list[Prediction]:
        if problem.spec is None or not is_pose(problem.truth):
            return []
        found = [mistake(P, Q) for P, Q in _pairs(problem)]
        return [Prediction(T) for T in found if T is not None and loses_credit(problem, T)]
    return make


FAMILIES = (
    Family("uncentred fit", UNCENTRED, OUTPUT, _fit(_uncentred), "uncentred"),
    Family("uncentred fit", TRANSLATION, OUTPUT, _fit(_translation_before_fix),
           "translation before fix"),
)
