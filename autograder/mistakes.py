"""Name the classic mistake behind a wrong answer, for ``check()`` and the grader's feedback.

A wrong pose that is exactly the inverse of the right one, or right but in millimetres, says
far more than "worst error 1.15e+03 mm": :func:`diagnose` compares a wrong answer with the
truth transformed by each classic mistake (the inverse pose, a transposed rotation,
millimetres for metres, degrees for radians, a mirrored fit, a flipped sign) and returns the
hint for the one that matches, or None. It only ever looks at an answer that already failed,
so a hint never changes a score.

The grader names a mistake by :func:`nearest`: the answer's distance to every candidate (each
code mistake's answer on the problem, each of :func:`candidates`' transforms of the truth),
and to what is no mistake (the truth itself, the trivial answers of :func:`trivial_answers`),
on the scale of the problem's own tolerance (``autograder.checks``). A mistake is named only
when its answer is within the noise of the student's and clearly nearer than every other
candidate; an answer between two candidates, or nearer the truth or a trivial answer, gets
no name, and never two.

Frames follow DESIGN.md: a pose ``a_T_b`` is a (4, 4) homogeneous matrix, metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autograder import families
from autograder.families import inverse, reflection, units_angle, units_length
from robots import geometry as geo

__all__ = ["Weighing", "candidates", "diagnose", "matches", "mirrored", "nearest",
           "relative_distance", "trivial_answers", "weigh"]

# An answer "is" a mistake's prediction when it lies within this fraction of the
# prediction's own size (plus a floor for near-zero truths): loose enough for noisy
# problems, tight enough that an unrelated wrong answer is not given a wrong name.
_RELATIVE = 0.02
_FLOOR = 1e-6

# The words are the families' (one place for each mistake's words).
_INVERSE, _TRANSPOSED, _TRANSPOSE = inverse.INVERSE, inverse.TRANSPOSED, inverse.TRANSPOSE
_MILLIMETRES, _METRES = units_length.MILLIMETRES, units_length.METRES
_DEGREES, _MIRRORED = units_angle.DEGREES, reflection.MIRRORED


def _close(value: np.ndarray, predicted: np.ndarray) -> bool:
    scale = float(np.linalg.norm(predicted))
    return float(np.linalg.norm(value - predicted)) <= _RELATIVE * scale + _FLOOR


def _pose_mistake(value: np.ndarray, truth: np.ndarray) -> str | None:
    R, t = value[:3, :3], value[:3, 3]
    R_true, t_true = truth[:3, :3], truth[:3, 3]
    if np.linalg.det(R) < 0 and np.allclose(R.T @ R, np.eye(3), atol=1e-3):
        return _MIRRORED
    inverse = np.eye(4)
    inverse[:3, :3], inverse[:3, 3] = R_true.T, -R_true.T @ t_true
    rotation_differs = not _close(R, R_true)
    if rotation_differs and _close(value[:3], inverse[:3]):
        return _INVERSE
    if rotation_differs and _close(R, R_true.T):
        return _TRANSPOSED
    if not rotation_differs and np.linalg.norm(t_true) > 1e-4:
        if _close(t, 1000.0 * t_true):
            return _MILLIMETRES
        if _close(t, t_true / 1000.0):
            return _METRES
    if rotation_differs and _close(t, t_true):
        angle, angle_true = (math.radians(geo.rotation_angle_deg(M)) for M in (R, R_true))
        for factor in (math.pi / 180.0, 180.0 / math.pi):
            wrapped = math.remainder(angle_true * factor, 2 * math.pi)
            if angle_true > 1e-3 and abs(abs(wrapped) - angle) <= 0.02 * max(angle, 1e-3):
                return _DEGREES
    return None


def _array_mistake(value: np.ndarray, truth: np.ndarray) -> str | None:
    if float(np.linalg.norm(truth)) <= _FLOOR:
        return None
    for hint, predicted in candidates(truth):
        # a symmetric truth is its own transpose: no mistake to name
        if _close(value, predicted) and not (hint == _TRANSPOSE and _close(value, truth)):
            return hint
    return None


def relative_distance(value, predicted) -> float:
    """How far the array ``value`` is from ``predicted``, in units of "within a few per cent"
    (at most 1: :func:`matches`): |value - predicted| over 2 % of |predicted| plus a floor.
    NaN must sit where ``predicted`` has NaN (a depth image's holes) and is then left out;
    other shapes, inf, or values that are no numbers are infinitely far."""
    try:
        v = np.asarray(value, dtype=float)
        p = np.asarray(predicted, dtype=float)
    except (TypeError, ValueError):
        return math.inf
    if v.shape != p.shape or np.isinf(v).any() or np.isinf(p).any():
        return math.inf
    holes = np.isnan(p)
    if not np.array_equal(np.isnan(v), holes):
        return math.inf
    v, p = np.where(holes, 0.0, v), np.where(holes, 0.0, p)
    return float(np.linalg.norm(v - p)) / (_RELATIVE * float(np.linalg.norm(p)) + _FLOOR)


def mirrored(value, truth) -> str | None:
    """The mirror-image hint when ``value`` is a (4, 4) pose whose rotation block is
    orthonormal with determinant -1 (no rotation: an SVD fit without the reflection fix),
    the truth a pose; else None."""
    return _MIRRORED if reflection.mirrored(value, truth) else None


def matches(value, predicted) -> bool:
    """True when ``value`` is, within a few per cent, the answer a mistake predicts.

    NaN counts as a value where the prediction has NaN too (a depth image's holes, lab 5):
    the NaN must sit in the same places, the rest must be close; inf never matches. Two
    dicts (a closed loop's measured errors) match key by key."""
    if isinstance(value, dict) or isinstance(predicted, dict):
        return isinstance(value, dict) and isinstance(predicted, dict) \
            and value.keys() == predicted.keys() \
            and all(matches(value[k], predicted[k]) for k in value)
    return relative_distance(value, predicted) <= 1.0


def diagnose(value, truth) -> str | None:
    """A hint naming the classic mistake that turns ``truth`` into ``value``, or None.

    ``value`` and ``truth`` are the student's answer and the expected one, of the same shape:
    a (4, 4) pose (inverse, transposed rotation, millimetres, degrees, mirrored) or any
    numeric array (x1000, x1/1000, degrees, sign, transpose). Never raises.
    """
    try:
        v = np.asarray(value, dtype=float)
        t = np.asarray(truth, dtype=float)
    except (TypeError, ValueError):
        return None
    if v.shape != t.shape or v.size == 0 or not (np.all(np.isfinite(v)) and np.all(np.isfinite(t))):
        return None
    if t.shape == (4, 4) and np.allclose(t[3], [0, 0, 0, 1]):
        return _pose_mistake(v, t)
    return _array_mistake(v, t)


# --------------------------------------------------------------------------- nearest candidate

# "Clearly nearer": the named candidate's distance is at most this fraction of the runner-up's.
MARGIN = 0.5


def candidates(truth) -> list[tuple[str, np.ndarray]]:
    """[(hint, the answer that mistake gives)] for the output-side mistake families of
    :mod:`autograder.families` made on ``truth`` alone: for a (4, 4) pose ``a_T_b`` (metres)
    the inverse, the transposed rotation, the translation in mm or a thousandth, the
    rotation angle scaled by 180/pi or pi/180; for any other numeric array x1000, /1000,
    degrees, radians, the opposite sign, the square or the root and (square) the transpose.
    [] for what no family reads (a dict)."""
    try:
        t = np.asarray(truth, dtype=float)
    except (TypeError, ValueError):
        return []
    if t.size == 0 or not np.all(np.isfinite(t)):
        return []
    return [(name.words, p.answer) for name, p in families.transforms(truth)]


def trivial_answers(truth) -> list[np.ndarray]:
    """Answers of ``truth``'s shape that compute nothing (zeros; for a pose the identity):
    an answer nearest one of them is given no mistake's name."""
    try:
        t = np.asarray(truth, dtype=float)
    except (TypeError, ValueError):
        return []
    if t.size == 0:
        return []
    return [np.eye(4)] if families.is_pose(t) else [np.zeros(t.shape)]


# Two candidates this close (in units of the noise) are one answer: rounding apart, as the
# inverse of a fit and the fit with src and dst swapped.
SAME = 1e-6


@dataclass(frozen=True)
class Weighing:
    """An answer weighed against a problem's candidates (:func:`weigh`): ``label`` the one
    it is clearly nearest to (None: none), ``far`` the labels every candidate of which lies
    beyond the noise of it (on this problem the answer is no such mistake), ``near`` those
    with a candidate within it."""

    label: object
    far: frozenset = frozenset()
    near: frozenset = frozenset()


def nearest(value, candidates, distance, within: float = 1.0,
            margin: float = MARGIN, same: float = SAME) -> str | None:
    """The label of the one candidate ``value`` is clearly nearest to, or None (see
    :func:`weigh`, whose ``label`` this is)."""
    return weigh(value, candidates, distance, within, margin, same).label


def weigh(value, candidates, distance, within: float = 1.0,
          margin: float = MARGIN, same: float = SAME) -> Weighing:
    """The label of the one candidate ``value`` is clearly nearest to, or None, and the
    labels it is far from (:class:`Weighing`).

    ``candidates`` are ``[(label, answer)]`` in order of precedence, ``label`` None for an
    answer that is no mistake (the truth, a trivial answer); candidates of equal labels
    are one explanation, never each other's runner-up. ``distance(a, b)`` measures
    answer ``a`` against ``b`` taken as the truth, in units of the noise: at most
    ``within`` is within it. A candidate ``same`` close to an earlier one is the same answer
    on this problem and the earlier one speaks for it (a mistake that gives the truth or
    zeros here is never named). The nearest is named when it has a label, lies within the
    noise and is at most ``margin`` times as far as the runner-up; otherwise, e.g. an answer
    between two mistakes' answers or one nearer the truth, nothing is named. Never raises
    for a ``distance`` that does: that pair is taken as far apart."""
    def far(a, b) -> float:
        try:
            d = float(distance(a, b))
        except Exception:  # noqa: BLE001 - a value a measure cannot take is far from it
            return math.inf
        return d if math.isfinite(d) and d >= 0 else math.inf

    listed = list(candidates)
    if not listed:
        return Weighing(None)
    ranked = sorted((far(value, answer), i) for i, (_, answer) in enumerate(listed))
    near = frozenset(listed[i][0] for d, i in ranked if d <= within) - {None}
    ruled_out = frozenset({label for label, _ in listed if label is not None} - near)
    if ranked[0][0] > within:
        # nothing within the noise (most wrong answers, every garbage one): no need to
        # decide which candidates are one answer, which costs a measure per pair
        return Weighing(None, ruled_out, near)
    status: dict[int, bool] = {}

    def kept(i: int) -> bool:
        # dropped when ``same`` close to an earlier candidate that is itself kept; decided
        # only for the few candidates the ranking reaches (each costs a measure per earlier
        # candidate, and a problem has dozens of them)
        if i not in status:
            status[i] = not any(far(listed[i][1], listed[j][1]) <= same and kept(j)
                                for j in range(i))
        return status[i]

    survivors = (entry for entry in ranked if kept(entry[1]))
    best, index = next(survivors)
    label = listed[index][0]
    if label is None or best > within:
        return Weighing(None, ruled_out, near)
    # candidates of the same name are one explanation (a mistake made on each part of an
    # answer, each preimage of an angle): the runner-up is the nearest of another name
    runner_up = next((d for d, i in survivors if listed[i][0] != label), math.inf)
    if best > margin * runner_up:
        return Weighing(None, ruled_out, near)
    return Weighing(label, ruled_out, near)
