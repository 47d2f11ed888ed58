"""Lab 0 (frames and poses), private side: the problem generators and the code mistakes.

The scoring (points, checks, bands) is public, in :mod:`autograder.scoring.lab0_frames`; this
module completes those entries with what computes an answer, and is never given to students.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from autograder.scoring import lab0_frames as scoring
from autograder.scoring.lab0_frames import ROTVEC_PRACTICE
from autograder.spec_types import EXACT_TOL, CodeMistake, Trial, random_pose, random_rotvec
from robots import geometry as geo


def _trial_invert(rng, index: int) -> Trial:
    T = random_pose(rng)
    return Trial(args=(T,), truth=geo.invert(T), tol=dict(EXACT_TOL), label="random pose")


def _trial_compose(rng, index: int) -> Trial:
    n = 1 + index % 5  # chains of 1 to 5 poses, so a one-pose "chain" is tested too
    chain = [random_pose(rng, 0.5) for _ in range(n)]
    # A one-pose chain's answer is its input: an edge case (all-or-nothing), which counts
    # only when a longer chain is right too, so returning poses[0] earns nothing.
    return Trial(args=(chain,), truth=geo.compose(*chain), tol=dict(EXACT_TOL),
                 label=f"chain of {n}", all_or_nothing=n == 1)


def _trial_rotvec(rng, index: int) -> Trial:
    # The first problems are the edge cases of Rodrigues' formula: no rotation (0/0 if the
    # axis is computed as r/|r|), a tiny one, and a half-turn.
    # Three in every eight problems.
    edge = index % ROTVEC_PRACTICE
    angle = {0: 0.0, 1: 1e-9, 2: np.pi}.get(edge)
    rvec = random_rotvec(rng, angle)
    t = rng.uniform(-1.0, 1.0, 3)
    label = {0: "zero rotation", 1: "tiny rotation", 2: "half turn"}.get(edge, "random")
    return Trial(args=(rvec, t), truth=geo.pose_from_rotvec(rvec, t), tol=dict(EXACT_TOL),
                 label=label, all_or_nothing=edge in (0, 1, 2))


# --------------------------------------------------------------------------- code mistakes


def _pose(R, t) -> np.ndarray:
    # Not geo.make_pose: a mistake may build a matrix that is no rotation, and it must
    # return it as the student's code would.
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _compose(poses) -> np.ndarray:
    return geo.compose(*poses)


def _invert_keeps_r(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    return _pose(R, -R @ t)


def _invert_negates_t(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    return _pose(R.T, -t)


def _invert_returns_input(a_T_b):
    return np.array(a_T_b, dtype=float)


def _compose_left_to_right(poses) -> np.ndarray:
    out = np.eye(4)
    for T in poses:
        out = out @ T
    return out


def _compose_reversed(poses):
    return _compose_left_to_right(list(poses)[::-1])


def _compose_inverses(poses):
    return _compose_left_to_right([geo.invert(np.asarray(T, dtype=float)) for T in poses])


def _rotvec_as_degrees(rvec, t):
    return geo.pose_from_rotvec(np.radians(np.asarray(rvec, dtype=float)), t)


def _rotvec_transposed(rvec, t):
    T = geo.pose_from_rotvec(rvec, t)
    T[:3, :3] = T[:3, :3].T
    return T


def _rotvec_no_zero_check(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    with np.errstate(invalid="ignore"):  # 0/0 on purpose: this mistake returns NaN there
        K = geo.skew(rvec / theta)
    return _pose(np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K, t)


def _rotvec_translation_mm(rvec, t):
    T = geo.pose_from_rotvec(rvec, t)
    T[:3, 3] *= 1000.0
    return T


INVERT_MISTAKES = (
    CodeMistake("its rotation block is R, not R^T: the inverse of [R | t] is [R^T | -R^T t]",
                _invert_keeps_r),
    CodeMistake("its translation is -t, not -R^T t: undo the rotation too (b_T_a maps a's "
                "origin to -R^T t)", _invert_negates_t),
    CodeMistake("it is the given pose itself, not its inverse: b_T_a = [R^T | -R^T t]",
                _invert_returns_input),
)
COMPOSE_MISTAKES = (
    CodeMistake("the poses are multiplied in reverse order (y_T_z @ ... @ a_T_b): a_T_z is "
                "a_T_b @ b_T_c @ ... @ y_T_z, left to right", _compose_reversed),
    CodeMistake("each pose was inverted before multiplying: the list already holds a_T_b, "
                "b_T_c, ...; multiply them as given", _compose_inverses),
)
ROTVEC_MISTAKES = (
    CodeMistake("the rotation vector was converted from degrees (np.radians): it is in "
                "radians already", _rotvec_as_degrees),
    CodeMistake("its rotation is R^T, the rotation the other way: check the signs of K = "
                "[[0, -kz, ky], [kz, 0, -kx], [-ky, kx, 0]]", _rotvec_transposed),
    CodeMistake("a zero rotation vector divides 0 by 0 (r / |r|): return the identity "
                "rotation when |r| is (nearly) 0", _rotvec_no_zero_check),
    CodeMistake("its translation is in millimetres: t is given in metres, the course's unit; "
                "keep it as it is", _rotvec_translation_mm),
)

INVERT_POSE = replace(scoring.INVERT_POSE, make_trial=_trial_invert,
                      code_mistakes=INVERT_MISTAKES, reference=geo.invert)
COMPOSE_CHAIN = replace(scoring.COMPOSE_CHAIN, make_trial=_trial_compose,
                        code_mistakes=COMPOSE_MISTAKES, reference=_compose)
POSE_FROM_ROTVEC = replace(scoring.POSE_FROM_ROTVEC, make_trial=_trial_rotvec,
                           code_mistakes=ROTVEC_MISTAKES, reference=geo.pose_from_rotvec)

SPECS = (INVERT_POSE, COMPOSE_CHAIN, POSE_FROM_ROTVEC)

# What computes a graded quantity (a truth or a mistaken answer): never in a student's copy.
# (_invert_returns_input, np.array(T), is no answer code: helpers everywhere read the same.)
ANSWERS = (_trial_invert, _trial_compose, _trial_rotvec, _invert_keeps_r, _invert_negates_t,
           _compose_left_to_right, _compose_reversed, _compose_inverses, _rotvec_as_degrees,
           _rotvec_transposed, _rotvec_no_zero_check, _rotvec_translation_mm, _compose)
