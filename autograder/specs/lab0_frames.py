"""Lab 0 (frames and poses), private side: the problem generators and the mistakes predictor.

The scoring (points, checks, bands) is public, in :mod:`autograder.scoring.lab0_frames`; this
module completes those entries with what computes an answer, and is never given to students.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from autograder.scoring import lab0_frames as scoring
from autograder.scoring.lab0_frames import ROTVEC_PRACTICE
from autograder.spec_types import EXACT_TOL, Trial, random_pose, random_rotvec
from robots import geometry as geo


def _trial_invert(rng, index: int) -> Trial:
    T = random_pose(rng)
    return Trial(args=(T,), truth=geo.invert(T), tol=dict(EXACT_TOL), label="random pose")


def _trial_compose(rng, index: int) -> Trial:
    n = 1 + index % 5  # chains of 1 to 5 poses, so a one-pose "chain" is tested too
    chain = [random_pose(rng, 0.5) for _ in range(n)]
    return Trial(args=(chain,), truth=geo.compose(*chain), tol=dict(EXACT_TOL),
                 label=f"chain of {n}")


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


def _compose_mistakes(trial: Trial) -> list:
    if len(trial.args[0]) < 2:
        return []
    return [("the poses are multiplied in reverse order (y_T_z @ ... @ a_T_b): a_T_z is "
             "a_T_b @ b_T_c @ ... @ y_T_z, left to right", geo.compose(*trial.args[0][::-1]))]


INVERT_POSE = replace(scoring.INVERT_POSE, make_trial=_trial_invert)
COMPOSE_CHAIN = replace(scoring.COMPOSE_CHAIN, make_trial=_trial_compose,
                        mistakes=_compose_mistakes)
POSE_FROM_ROTVEC = replace(scoring.POSE_FROM_ROTVEC, make_trial=_trial_rotvec)

SPECS = (INVERT_POSE, COMPOSE_CHAIN, POSE_FROM_ROTVEC)

# What computes a graded quantity (a truth or a mistaken answer): never in a student's copy.
ANSWERS = (_trial_invert, _trial_compose, _trial_rotvec, _compose_mistakes)
