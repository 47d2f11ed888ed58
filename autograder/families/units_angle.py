"""Radians and degrees: an angle off by a factor of 180/pi.

Applies to a pose answer (its rotation angle scaled, about the same axis) and to every other
numeric answer or part of a tuple answer (the values scaled). Output side: values and a
pose's angle in radians are mapped back and compared with the truth within the noise; a
pose's angle in degrees wraps around 2 pi, so it is compared as it is, with the truth's and
(input side) with the reference's own estimate scaled.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.families.base import (
    INPUT,
    OUTPUT,
    Family,
    Prediction,
    Problem,
    is_pose,
    is_stack,
    part_predictions,
    parts,
)
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


def _unscaled_pose(v, factor: float) -> np.ndarray | None:
    """``v`` with its angle divided by ``factor`` (< 1), or None where that angle passes
    half a turn: a rotation vector in radians never does, so an answer whose angle times
    180/pi would wrap is no angle in radians where degrees were asked."""
    if np.linalg.norm(_rotvec(np.asarray(v, float)[:3, :3])) / factor > math.pi + 1e-9:
        return None
    return _scaled_pose(v, 1 / factor)


def _angle(factor: float, array_words: str):
    def make(problem: Problem) -> list[Prediction]:
        truth = problem.truth
        if is_pose(truth):
            t = np.asarray(truth, dtype=float)
            if factor > 1.0:
                # an angle times 180/pi wraps around 2 pi: every rotation about the right
                # axis has a preimage within 3 degrees of the truth, so undoing would name
                # any wrong angle; compared as it is (and with the reference's answer scaled)
                return [Prediction(_scaled_pose(t, factor), wraps=True)]
            null = np.array(t)
            null[:3, :3] = np.eye(3)
            return [Prediction(_scaled_pose(t, factor), lambda v: _unscaled_pose(v, factor), t,
                               null=null)]
        if is_stack(truth):
            return []   # a stack of poses times 180/pi is no stack: no angle read that way
        found = part_predictions(truth, lambda t: t * factor, lambda v: v / factor,
                                 lambda k: f"item {k + 1} of the answer {array_words[3:]}",
                                 np.zeros_like)
        split = parts(truth)
        if split is not None:   # likewise a part that is a pose or a stack of them
            found = [p for p, part in zip(found, split) if not (is_pose(part) or is_stack(part))]
        return [p if p.words else Prediction(p.answer, p.undo, p.base, array_words, p.null)
                for p in found]
    return make


def _reference_in_degrees(problem: Problem) -> list[Prediction]:
    """The reference's own answer on the problem, its angle times 180/pi: on a noisy
    problem the student's estimate, not the truth, was scaled (input side: private)."""
    if not is_pose(problem.truth):
        return []
    answer = problem.right_answer()
    return [Prediction(_scaled_pose(answer, TO_DEGREES), wraps=True)] if is_pose(answer) \
        else []


FAMILIES = (
    Family("units rad/deg", DEGREES, OUTPUT, _angle(TO_DEGREES, ARRAY_DEGREES), "degrees"),
    Family("units rad/deg", DEGREES, INPUT, _reference_in_degrees, "degrees of the estimate"),
    Family("units rad/deg", DEGREES, OUTPUT, _angle(TO_RADIANS, ARRAY_RADIANS), "radians"),
)
