"""Radians and degrees: an angle off by a factor of 180/pi.

Applies to a pose answer (its rotation angle scaled, about the same axis) and to every other
numeric answer or part of a tuple answer (the values scaled). Output side: the answer is
mapped back (for a pose, the preimage angle nearest the truth's, since a scaled angle wraps
around 2 pi) and compared with the truth within the problem's noise.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.families.base import OUTPUT, Family, Prediction, Problem, is_pose, part_predictions
from robots import geometry as geo

DEGREES = ("its rotation angle is off by a factor of 180/pi: degrees and radians mixed up "
           "(numpy's trigonometry takes radians)")
ARRAY_DEGREES = "it is in degrees where radians were asked"
ARRAY_RADIANS = "it is in radians where degrees were asked"
TO_DEGREES, TO_RADIANS = 180.0 / math.pi, math.pi / 180.0


def _rotvec(R) -> np.ndarray:
    # scipy, not robots.geometry: a rotation vector scaled by 180/pi is the mistake here,
    # not a reason to warn
    return Rotation.from_matrix(geo.project_to_so3(np.asarray(R, float))).as_rotvec()


def _scaled_pose(T, factor: float) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, :3] = Rotation.from_rotvec(_rotvec(out[:3, :3]) * factor).as_matrix()
    return out


def _unscaled_pose(value, truth, factor: float) -> np.ndarray:
    """The pose whose rotation, angle times ``factor``, is ``value``'s: of the preimages
    (the scaled angle wraps around 2 pi), the one nearest ``truth``'s rotation."""
    v = np.array(value, dtype=float)
    r = _rotvec(v[:3, :3])
    angle, axis = float(np.linalg.norm(r)), r / max(float(np.linalg.norm(r)), 1e-300)
    target = float(np.linalg.norm(_rotvec(np.asarray(truth)[:3, :3]))) * factor
    best, best_err = None, math.inf
    for sign in (1.0, -1.0):
        k = round((target - sign * angle) / (2 * math.pi))
        for kk in (k - 1, k, k + 1):
            R = Rotation.from_rotvec(sign * axis * (sign * angle + 2 * math.pi * kk)
                                     / factor).as_matrix()
            err = float(np.abs(R - np.asarray(truth)[:3, :3]).max())
            if err < best_err:
                best, best_err = R, err
    v[:3, :3] = best
    return v


def _angle(factor: float, array_words: str):
    def make(problem: Problem) -> list[Prediction]:
        truth = problem.truth
        if is_pose(truth):
            t = np.asarray(truth, dtype=float)
            return [Prediction(_scaled_pose(t, factor),
                               lambda v: _unscaled_pose(v, t, factor), t)]
        found = part_predictions(truth, lambda t: t * factor, lambda v: v / factor,
                                 lambda k: f"item {k + 1} of the answer: {array_words[3:]}")
        return [p if p.words else Prediction(p.answer, p.undo, p.base, array_words)
                for p in found]
    return make


FAMILIES = (
    Family("units rad/deg", DEGREES, OUTPUT, _angle(TO_DEGREES, ARRAY_DEGREES), "degrees"),
    Family("units rad/deg", DEGREES, OUTPUT, _angle(TO_RADIANS, ARRAY_RADIANS), "radians"),
)
