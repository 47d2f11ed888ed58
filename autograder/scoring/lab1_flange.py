"""Lab 1 (camera intrinsics and flange calibration): how its graded functions are scored.

Three pure functions, all about the rigid fit ``dst ~= dst_T_src @ src`` of a flange
calibration (src = camera frame, dst = robot base frame):

* ``fit_rigid(src, dst) -> dst_T_src``: scored by how far the fitted map moves the measured
  points from where the true map puts them, within a tolerance set by the problem's noise.
  Some problems are degenerate (collinear points, or only two) and expect ``ValueError``;
  some are planar, where a fit without the reflection fix returns a mirror image.
* ``per_point_residuals(dst_T_src, src, dst) -> (N,)`` and
  ``per_axis_rmse(dst_T_src, src, dst) -> (3,)``: exact formulas on given inputs, scored
  with a small multiple of float64 rounding (in mm).

The problems themselves come from the private side (autograder/specs/lab1_flange.py).
"""

from __future__ import annotations

import math

import numpy as np

from autograder.spec_types import (
    EXACT_BANDS,
    Check,
    FunctionSpec,
    OutputError,
    Trial,
    as_output_pose,
    pose_errors,
)


def _measure_fit(value, trial: Trial) -> dict[str, float]:
    T = as_output_pose(value)
    truth, cam_points = trial.truth
    if not math.isfinite(pose_errors(T, truth)["rotation"]):
        raise OutputError("returned a rotation block that is not a proper rotation (det +1): "
                          "a mirror image? flip the last singular vector when det < 0")
    mapped = cam_points @ T[:3, :3].T + T[:3, 3]
    true_mapped = cam_points @ truth[:3, :3].T + truth[:3, 3]
    rms = float(np.sqrt(np.mean(np.sum((mapped - true_mapped) ** 2, axis=1)))) * 1000.0
    return {"mapping": rms}


def _as_output_vector(value, n: int) -> np.ndarray:
    """A student's return value as a finite float vector of length ``n``, or OutputError."""
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OutputError(f"returned {type(value).__name__}, expected a numpy array of "
                          "numbers") from None
    if v.shape != (n,):
        raise OutputError(f"returned shape {v.shape}, expected ({n},)")
    if not np.all(np.isfinite(v)):
        raise OutputError("returned NaN or inf")
    return v


def _measure_vector(key: str):
    def measure(value, trial: Trial) -> dict[str, float]:
        v = _as_output_vector(value, len(trial.truth))
        return {key: float(np.abs(v - trial.truth).max() * 1000.0)}
    return measure


FIT_RIGID = FunctionSpec(
    name="fit_rigid", points=4.0, n_trials=18, practice_trials=6, make_trial=None,
    measure=_measure_fit,
    checks=(
        Check("mapping", "mm", 1.0, ((1.0, 1.0), (2.0, 0.5)),
              "RMS distance between your map and the true one over the measured points; "
              "planar sets need the reflection fix, collinear points or fewer than 3 a "
              "ValueError"),
    ),
    signature="fit_rigid(src: (N, 3), dst: (N, 3)) -> dst_T_src (4, 4)",
    parameters="src, dst",
)
PER_POINT_RESIDUALS = FunctionSpec(
    name="per_point_residuals", points=2.0, n_trials=12, practice_trials=4, make_trial=None,
    measure=_measure_vector("residuals"),
    checks=(Check("residuals", "mm", 1.0, EXACT_BANDS,
                  "|dst_T_src @ src_i - dst_i| per point, in metres"),),
    signature="per_point_residuals(dst_T_src: (4, 4), src: (N, 3), dst: (N, 3)) -> (N,)",
    parameters="dst_T_src, src, dst",
)
PER_AXIS_RMSE = FunctionSpec(
    name="per_axis_rmse", points=2.0, n_trials=12, practice_trials=4, make_trial=None,
    measure=_measure_vector("rmse"),
    checks=(Check("rmse", "mm", 1.0, EXACT_BANDS,
                  "RMS of the residuals along the x, y, z axes of the src (camera) frame: "
                  "rotate each residual by R^T first"),),
    signature="per_axis_rmse(dst_T_src: (4, 4), src: (N, 3), dst: (N, 3)) -> (3,) "
              "along the src axes",
    parameters="dst_T_src, src, dst",
)

SPECS = (FIT_RIGID, PER_POINT_RESIDUALS, PER_AXIS_RMSE)
