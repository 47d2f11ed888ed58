"""Lab 0 (frames and poses): the graded functions and how they are scored.

Noise-free problems, scored with the float64-rounding tolerances of ``checks.EXACT_TOL``.
Each function gets three times the problems of one practice seed, as many as ``check()``
shows over its three seeds. ``pose_from_rotvec`` puts 0.9 of its credit on the rotation
(Rodrigues' formula, what it teaches) and 0.1 on the translation (copying ``t``): an
identity rotation with the translation copied earns a tenth, not half.
"""

from __future__ import annotations

import numpy as np

from autograder.spec_types import (
    EXACT_BANDS,
    EXACT_TOL,
    Check,
    FunctionSpec,
    Trial,
    measure_pose,
    pose_checks,
    random_pose,
    random_rotvec,
)
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


ROTVEC_PRACTICE = 8  # problems per practice seed


INVERT_POSE = FunctionSpec(
    name="invert_pose", points=3.0, n_trials=18, practice_trials=6, make_trial=_trial_invert, measure=measure_pose,
    checks=pose_checks("b_T_a = inv(a_T_b): R^T and -R^T t"),
    signature="invert_pose(a_T_b: (4, 4) array) -> b_T_a (4, 4)",
    forbidden=("robots.geometry.invert",),
)
COMPOSE_CHAIN = FunctionSpec(
    name="compose_chain", points=3.0, n_trials=18, practice_trials=6, make_trial=_trial_compose,
    measure=measure_pose,
    checks=pose_checks("a_T_d = a_T_b @ b_T_c @ c_T_d, multiplied left to right"),
    signature="compose_chain(poses: list of (4, 4)) -> (4, 4)",
    forbidden=("robots.geometry.compose",),
    mistakes=lambda trial: [] if len(trial.args[0]) < 2 else [
        ("the poses are multiplied in reverse order (y_T_z @ ... @ a_T_b): a_T_z is "
         "a_T_b @ b_T_c @ ... @ y_T_z, left to right", geo.compose(*trial.args[0][::-1]))],
)
POSE_FROM_ROTVEC = FunctionSpec(
    name="pose_from_rotvec", points=4.0, n_trials=3 * ROTVEC_PRACTICE,
    practice_trials=ROTVEC_PRACTICE, make_trial=_trial_rotvec, measure=measure_pose,
    checks=(
        Check("rotation", "deg", 0.9, EXACT_BANDS,
              "the rotation block: Rodrigues' formula, including a zero rotation vector"),
        Check("translation", "mm", 0.1, EXACT_BANDS, "the translation column: t itself"),
    ),
    signature="pose_from_rotvec(rvec: (3,), t: (3,)) -> (4, 4)",
    forbidden=("cv2.Rodrigues", "robots.geometry.pose_from_rotvec"),
)

SPECS = (INVERT_POSE, COMPOSE_CHAIN, POSE_FROM_ROTVEC)
