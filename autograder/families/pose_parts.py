"""Per part of a pose: one part right, the other wrong by a classic mistake.

Many wrong poses are right in one part. A pose answer ``[R | t]`` (DESIGN.md: a (4, 4)
``a_T_b`` in metres) is tried part by part:

* the rotation right, the translation ``t`` wrong: negated (a sign), zero (left out, or
  read from the bottom row), or off by a rotation, ``M t`` with ``M`` one of ``R``, ``R^T``,
  ``R R``, ``R^T R^T`` and their negatives: the translation left unrotated where ``R t`` or
  ``-R^T t`` was asked, or rotated by ``R`` where ``R^T`` was meant;
* the translation right, the rotation's angle halved or doubled (a quaternion's half angle
  used as the angle, or the reverse);
* the rotation wrong by a family (transposed, halved or doubled) whatever the
  translation: a translation computed from a wrong rotation is wrong too (an SVD fit with
  the covariance transposed). These predictions are ``loose``: they compare the rotation
  only, and the grader weighs them only when no whole-answer candidate is near
  (``autograder.checks``), and only where the rotation mistake moves the rotation past
  the noise (degrees are left to :mod:`.units_angle`: an angle times 180/pi wraps, so
  its rotation cannot be undone).

Output side: every prediction maps the student's answer back with the answer's own
rotation (right, within the noise, where the mistake is one of the translation's), so a
noisy estimate is named too.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.families.base import OUTPUT, Family, Prediction, Problem, is_pose
from robots import geometry as geo

ROTATION_RIGHT = "its rotation is right; "
SIGN_T = (ROTATION_RIGHT + "its translation has the wrong sign (-t where t was asked): "
          "check the direction of the vector, or a minus sign that belongs to another term")
ZERO_T = (ROTATION_RIGHT + "its translation is zero: the translation was left out (or read "
          "from the bottom row of the matrix, which is 0 0 0 1): put t in the last column")
ROTATED_T = (ROTATION_RIGHT + "its translation is the right one rotated by {M}: the "
             "translation was left unrotated, or rotated the wrong way (check R t against "
             "R^T t, and that the inverse's translation is -R^T t)")
HALF_ANGLE = ("its rotation angle is half the right one, about the right axis: a "
              "quaternion's angle is half the rotation's (theta = 2 acos(w))")
DOUBLE_ANGLE = ("its rotation angle is twice the right one, about the right axis: the "
                "half angle of a quaternion was used as the rotation's angle")
TRANSPOSED_ANY_T = ("its rotation is the transpose of the expected one (R^T where R was "
                    "asked), and its translation, computed with it, is wrong too: check the "
                    "direction of the rotation (in an SVD fit, H = sum p_src p_dst^T, R = V U^T)")
HALF_ANY_T = HALF_ANGLE + "; its translation, computed with it, is wrong too"
DOUBLE_ANY_T = DOUBLE_ANGLE + "; its translation, computed with it, is wrong too"

def _pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _rotvec(R) -> np.ndarray:
    # scipy on the projected block: a student's answer may be a little off SO(3)
    return Rotation.from_matrix(geo.project_to_so3(np.asarray(R, float))).as_rotvec()


def _scaled(R, factor: float) -> np.ndarray:
    return Rotation.from_rotvec(_rotvec(R) * factor).as_matrix()


def _halved_back(R_answer, near) -> np.ndarray:
    """The rotation whose angle doubled is ``R_answer``: of its two (the half turn apart),
    the one nearer ``near`` (a doubled angle wraps past pi)."""
    r = _rotvec(R_answer)
    angle = float(np.linalg.norm(r))
    axis = r / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    options = [Rotation.from_rotvec(axis * angle / 2).as_matrix(),
               Rotation.from_rotvec(axis * (angle / 2 + np.pi)).as_matrix()]
    return min(options, key=lambda Q: float(np.abs(Q - near).sum()))


# --------------------------------------------------------------------------- the translation

def _matrices(R: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(name, M) of each rotation a translation may be off by."""
    found = []
    for name, M in (("R", R), ("R^T", R.T), ("R R", R @ R), ("R^T R^T", R.T @ R.T)):
        found += [(name, M), (f"-{name}", -M)]
    return found


def _translation_off(problem: Problem) -> list[Prediction]:
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    R, t = truth[:3, :3], truth[:3, 3]
    null = _pose(R, np.zeros(3))
    out = [Prediction(_pose(R, -t), lambda v: _pose(v[:3, :3], -v[:3, 3]), truth, SIGN_T, null,
                      resolved=True)]
    for name, M in _matrices(R):
        # M built from the answer's own rotation when undone: the truth's, within the noise
        index = [n for n, _ in _matrices(R)].index(name)

        def undo(v, index=index):
            v = np.asarray(v, float)
            M_v = _matrices(geo.project_to_so3(v[:3, :3]))[index][1]
            return _pose(v[:3, :3], M_v.T @ v[:3, 3])
        out.append(Prediction(_pose(R, M @ t), undo, truth, ROTATED_T.format(M=name), null,
                              resolved=True))
    return out


def _translation_zero(problem: Problem) -> list[Prediction]:
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    return [Prediction(_pose(truth[:3, :3], np.zeros(3)), words=ZERO_T, resolved=True)]


# --------------------------------------------------------------------------- the rotation

def _angle(factor: float, words: str):
    def make(problem: Problem) -> list[Prediction]:
        if not is_pose(problem.truth):
            return []
        truth = np.asarray(problem.truth, dtype=float)
        R, t = truth[:3, :3], truth[:3, 3]
        if factor < 1:
            def undo(v):
                return _pose(_scaled(v[:3, :3], 1 / factor), np.asarray(v, float)[:3, 3])
        else:
            def undo(v):
                return _pose(_halved_back(np.asarray(v, float)[:3, :3], R), v[:3, 3])
        return [Prediction(_pose(_scaled(R, factor), t), undo, truth, words, resolved=True,
                           wraps=True)]
    return make


def _centre(R_answer, t_answer, R, t) -> np.ndarray:
    """The point the answer's rotation turns about relative to the truth's: a fit computes
    its translation as c_dst - R c_src, so a wrong R moves t by (R_answer - R) c_src; the
    least-squares c from the two translations (the part along the axis, which no rotation
    moves, is left at zero)."""
    return np.linalg.pinv(R_answer - R) @ (np.asarray(t, float) - t_answer)


def _loose(change, back, words: str, wraps: bool = False):
    """A rotation mistake whatever the translation: the answer's rotation undone (``back``
    maps it to the right one) with the truth's translation, compared with the truth: only
    the rotation counts (turned about :func:`_centre`, where a fit's error lies)."""
    def make(problem: Problem) -> list[Prediction]:
        if not is_pose(problem.truth):
            return []
        truth = np.asarray(problem.truth, dtype=float)
        R, t = truth[:3, :3], truth[:3, 3]

        def undo(v):
            v = np.asarray(v, float)
            R_v, t_v = v[:3, :3], v[:3, 3]
            R_back = back(R_v, R)
            # the truth's translation, moved as the rotation's own error moves it about
            # the centre (a fit's error is a turn about its centroid, not about the origin)
            return _pose(R_back, t + (R - R_back) @ _centre(R_v, t_v, R, t))
        return [Prediction(_pose(change(R), t), undo, truth, words, loose=True,
                           resolved=True, wraps=wraps)]
    return make


FAMILIES = (
    Family("sign", SIGN_T, OUTPUT, lambda p: _translation_off(p)[:1], "translation sign"),
    Family("inverse/transpose", ROTATED_T, OUTPUT, lambda p: _translation_off(p)[1:],
           "translation rotated"),
    Family("missing part", ZERO_T, OUTPUT, _translation_zero, "translation zero"),
    Family("half angle", HALF_ANGLE, OUTPUT, _angle(0.5, HALF_ANGLE), "half angle"),
    Family("half angle", DOUBLE_ANGLE, OUTPUT, _angle(2.0, DOUBLE_ANGLE), "double angle"),
    Family("inverse/transpose", TRANSPOSED_ANY_T, OUTPUT,
           _loose(lambda R: R.T, lambda R_v, R: R_v.T, TRANSPOSED_ANY_T),
           "transposed rotation, any translation"),
    Family("half angle", HALF_ANY_T, OUTPUT,
           _loose(lambda R: _scaled(R, 0.5), lambda R_v, R: _scaled(R_v, 2.0), HALF_ANY_T, True),
           "half angle, any translation"),
    Family("half angle", DOUBLE_ANY_T, OUTPUT,
           _loose(lambda R: _scaled(R, 2.0), _halved_back, DOUBLE_ANY_T, True),
           "double angle, any translation"),
)
