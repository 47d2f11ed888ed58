"""Lab 0 (frames and poses): how its graded functions are scored.

Noise-free problems, scored with the float64-rounding tolerances of ``EXACT_TOL``. Each
function gets three times the problems of one practice seed, as many as ``check()`` shows
over its three seeds. ``pose_from_rotvec`` puts 0.9 of its credit on the rotation
(Rodrigues' formula, what it teaches) and 0.1 on the translation (copying ``t``), which
counts only with the rotation right (``Check.requires``): an identity rotation with the
translation copied earns nothing, and its right answers to the zero and tiny rotations
(all-or-nothing edge cases) count only when some ordinary rotation is right too.
"""

from __future__ import annotations

from autograder.spec_types import EXACT_BANDS, Check, FunctionSpec, measure_pose, pose_checks

ROTVEC_PRACTICE = 8  # problems per practice seed; the edge cases repeat with this period

INVERT_POSE = FunctionSpec(
    name="invert_pose", points=3.0, n_trials=18, practice_trials=6, make_trial=None,
    measure=measure_pose,
    checks=pose_checks("b_T_a = inv(a_T_b): R^T and -R^T t"),
    signature="invert_pose(a_T_b: (4, 4) array) -> b_T_a (4, 4)",
    parameters="a_T_b",
    forbidden=("robots.geometry.invert",),
)
COMPOSE_CHAIN = FunctionSpec(
    name="compose_chain", points=3.0, n_trials=18, practice_trials=6, make_trial=None,
    measure=measure_pose,
    checks=pose_checks("a_T_d = a_T_b @ b_T_c @ c_T_d, multiplied left to right"),
    signature="compose_chain(poses: list of (4, 4)) -> (4, 4)",
    parameters="poses",
    forbidden=("robots.geometry.compose",),
)
POSE_FROM_ROTVEC = FunctionSpec(
    name="pose_from_rotvec", points=4.0, n_trials=3 * ROTVEC_PRACTICE,
    practice_trials=ROTVEC_PRACTICE, make_trial=None, measure=measure_pose,
    checks=(
        Check("rotation", "deg", 0.9, EXACT_BANDS,
              "the rotation block: Rodrigues' formula, including a zero rotation vector"),
        Check("translation", "mm", 0.1, EXACT_BANDS, "the translation column: t itself",
              requires=("rotation",)),
    ),
    signature="pose_from_rotvec(rvec: (3,), t: (3,)) -> (4, 4)",
    parameters="rvec, t",
    forbidden=("cv2.Rodrigues", "robots.geometry.pose_from_rotvec"),
)

SPECS = (INVERT_POSE, COMPOSE_CHAIN, POSE_FROM_ROTVEC)
