"""Lab 2 (AX = XB eye-in-hand calibration): how its graded functions are scored.

Conventions (eye-in-hand, X = flange_T_cam): for poses i < j,
``A = inv(base_T_flange[i]) @ base_T_flange[j]`` and ``B = cam_T_target[i] @ inv(cam_T_target[j])``,
so that ``A @ X == X @ B``.

* ``motions``: exact arithmetic on the inputs, within 1e-9 of the truth on every entry;
* ``tsai_lenz``, ``axes_ls``: the returned X against the truth, in degrees and millimetres,
  each problem with its own full-credit tolerance, set by its noise level and the geometry
  of its motions (how the private generator derives it is explained there,
  autograder/specs/lab2_handeye.py, and measured in docs/benchmarks/grading_fairness.md);
* ``rotation_residual``, ``translation_residual``: relative error of the number, within 1e-9.
"""

from __future__ import annotations

import math

import numpy as np

from autograder.spec_types import Check, FunctionSpec, OutputError, Trial, measure_pose

SOLVER_BANDS = ((1.0, 1.0), (2.0, 0.5))
# Motions and residuals are exact arithmetic on the inputs: any correct float64 formula lands
# within ~1e-15 of the truth; 1e-9 leaves room for any summation order.
EXACT_BANDS = ((1.0, 1.0),)


def _as_stack(value, m: int, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OutputError(f"{what} is not an array of numbers") from None
    if arr.shape != (m, 4, 4):
        raise OutputError(f"{what} has shape {arr.shape}, expected ({m}, 4, 4): one motion per "
                          "pose pair of the strategy, pairs (i, j) with i < j in order")
    if not np.all(np.isfinite(arr)):
        raise OutputError(f"{what} contains NaN or inf")
    return arr


def _measure_motions(value, trial: Trial) -> dict[str, float]:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise OutputError("expected a pair (A, B) of (M, 4, 4) arrays")
    A_true, B_true = trial.truth
    A = _as_stack(value[0], len(A_true), "A")
    B = _as_stack(value[1], len(B_true), "B")
    return {"A": float(np.abs(A - A_true).max()), "B": float(np.abs(B - B_true).max())}


def _solver_checks(method: str) -> tuple[Check, ...]:
    return (
        Check("rotation", "deg", 0.5, SOLVER_BANDS,
              f"R_X by {method}; an inverted X or A and B swapped is off by degrees"),
        # A mount puts the camera a few centimetres from the flange, within the translation
        # tolerance of a poorly conditioned capture: t_X counts only with R_X right, or the
        # identity would earn a fifth of the points.
        Check("translation", "mm", 0.5, SOLVER_BANDS,
              "t_X from the stacked (R_A - I) t_X = R_X t_B - t_A", requires=("rotation",)),
    )


def _measure_scalar(value, trial: Trial) -> dict[str, float]:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.ndarray, np.generic)):
        raise OutputError(f"returned {type(value).__name__}, expected a number (float)")
    arr = np.asarray(value, dtype=float)
    if arr.size != 1:
        raise OutputError(f"returned shape {arr.shape}, expected a single number: the mean "
                          "over all motions")
    v = float(arr.reshape(()))
    if not math.isfinite(v):
        raise OutputError("returned NaN or inf")
    return {"value": abs(v - trial.truth) / abs(trial.truth)}


# The solvers are what the lab teaches: OpenCV's own hand-eye routines do the whole job.
_SOLVERS_FORBIDDEN = ("cv2.calibrateHandEye", "cv2.calibrateRobotWorldHandEye")


MOTIONS = FunctionSpec(
    name="motions", points=3.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_motions,
    checks=(
        Check("A", "", 0.5, EXACT_BANDS,
              "A = inv(base_T_flange[i]) @ base_T_flange[j] for the strategy's pairs i < j"),
        Check("B", "", 0.5, EXACT_BANDS,
              "B = cam_T_target[i] @ inv(cam_T_target[j]) (the order matters)"),
    ),
    signature="motions(base_T_flange (n, 4, 4), cam_T_target (n, 4, 4), strategy 'all' | "
              "'consecutive') -> (A (M, 4, 4), B (M, 4, 4))",
    parameters="base_T_flange, cam_T_target, strategy='all'",
)
TSAI_LENZ = FunctionSpec(
    name="tsai_lenz", points=4.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=measure_pose,
    checks=_solver_checks("Tsai-Lenz"),
    signature="tsai_lenz(A (M, 4, 4), B (M, 4, 4)) -> X = flange_T_cam (4, 4)",
    parameters="A, B",
    forbidden=_SOLVERS_FORBIDDEN,
)
AXES_LS = FunctionSpec(
    name="axes_ls", points=4.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=measure_pose,
    checks=_solver_checks("least squares on the rotation axes, projected onto SO(3)"),
    signature="axes_ls(A (M, 4, 4), B (M, 4, 4)) -> X = flange_T_cam (4, 4)",
    parameters="A, B",
    forbidden=_SOLVERS_FORBIDDEN,
)
ROTATION_RESIDUAL = FunctionSpec(
    name="rotation_residual", points=2.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_scalar,
    checks=(Check("value", "relative", 1.0, EXACT_BANDS,
                  "(1/n) sum ||R_A R_X - R_X R_B||_F^2: squared Frobenius norm, mean over n"),),
    signature="rotation_residual(A (M, 4, 4), B (M, 4, 4), X (4, 4)) -> float",
    parameters="A, B, X",
)
TRANSLATION_RESIDUAL = FunctionSpec(
    name="translation_residual", points=2.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_scalar,
    checks=(Check("value", "relative", 1.0, EXACT_BANDS,
                  "(1/n) sum ||R_A t_X + t_A - R_X t_B - t_X||^2 in m^2, mean over n"),),
    signature="translation_residual(A (M, 4, 4), B (M, 4, 4), X (4, 4)) -> float (m^2)",
    parameters="A, B, X",
)

SPECS = (MOTIONS, TSAI_LENZ, AXES_LS, ROTATION_RESIDUAL, TRANSLATION_RESIDUAL)
