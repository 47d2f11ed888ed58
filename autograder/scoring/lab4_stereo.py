"""Lab 4 (stereo single-shot hand-to-eye): how its graded functions are scored.

* ``frame_from_three_points``: the returned pose against the true frame, with the
  float64-rounding tolerances of lab 0; 0.9 of its credit on the rotation (the cross
  products, what it teaches) and 0.1 on the translation (``p_origin`` copied), which counts
  only with the rotation right (``Check.requires``: a copied origin alone earns nothing);
* ``reproject``: distance (mm) to the true point, within a tolerance that float32 arithmetic
  (correct code) meets, per problem;
* ``hand_to_eye_from_three_points``: the RMS distance between the returned map and the true
  one over 12 board points, within a band set by the noise;
* ``per_axis_rmse``: the RMS residual along each *camera* axis (where stereo's depth error
  shows up on z), the same function and convention as in lab 1, so ``check(per_axis_rmse)``
  scores it the same whichever lab's specification it finds.

The problems themselves come from the private side (autograder/specs/lab4_stereo.py).
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
    measure_pose,
    pose_errors,
)
from robots import geometry as geo

FRAME_FROM_THREE_POINTS = FunctionSpec(
    name="frame_from_three_points", points=3.0, n_trials=18, practice_trials=6,
    make_trial=None, measure=measure_pose,
    checks=(
        Check("rotation", "deg", 0.9, EXACT_BANDS,
              "x = unit(p_x - o), z = unit(x cross (p_xy - o)), y = z cross x: right-handed, "
              "with p_xy on the +y side"),
        Check("translation", "mm", 0.1, EXACT_BANDS, "the origin: p_origin itself",
              requires=("rotation",)),
    ),
    signature="frame_from_three_points(p_origin (3,), p_x (3,), p_xy (3,)) -> parent_T_frame",
    parameters="p_origin, p_x, p_xy",
)


def _measure_point(value, trial: Trial) -> dict[str, float]:
    p = _as_point(value)
    return {"position": float(np.linalg.norm(p - trial.truth)) * 1000.0}


def _as_point(value) -> np.ndarray:
    try:
        p = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OutputError("returned something that is not a 3-vector of numbers") from None
    if p.size != 3:
        raise OutputError(f"returned shape {p.shape}, expected a 3-vector (x, y, z) in metres")
    p = p.reshape(3)
    if not np.all(np.isfinite(p)):
        raise OutputError("returned NaN or inf")
    return p


REPROJECT = FunctionSpec(
    name="reproject", points=3.0, n_trials=24, practice_trials=8, make_trial=None,
    measure=_measure_point,
    checks=(Check("position", "mm", 1.0, ((1.0, 1.0), (100.0, 0.5)),
                  "Q @ [u, v, d, 1] = [X, Y, Z, W]; the point is [X, Y, Z] / W"),),
    signature="reproject(u: float, v: float, d: float, Q: (4, 4)) -> p_cam (3,) metres",
    parameters="u, v, d, Q",
)


def _measure_hand_to_eye(value, trial: Trial) -> dict[str, float]:
    T = as_output_pose(value)
    truth, check_cam = trial.truth
    if not math.isfinite(pose_errors(T, truth)["rotation"]):
        raise OutputError("returned a rotation block that is not a proper rotation (det +1)")
    diff = geo.transform_points(T, check_cam) - geo.transform_points(truth, check_cam)
    return {"mapping": float(np.sqrt(np.mean(np.sum(diff**2, axis=1)))) * 1000.0}


# Its calls of frame_from_three_points get the true frames (one bug costs once): the private
# side adds those tables, which it computes from the problem's points.
HAND_TO_EYE = FunctionSpec(
    name="hand_to_eye_from_three_points", points=2.0, n_trials=18, practice_trials=6,
    make_trial=None, measure=_measure_hand_to_eye,
    checks=(Check("mapping", "mm", 1.0, ((1.0, 1.0), (2.0, 0.5)),
                  "base_T_cam = base_T_world @ inv(cam_T_world); RMS error of the map over "
                  "12 board points"),),
    signature="hand_to_eye_from_three_points(cam_points (3, 3), base_points (3, 3)) -> "
              "base_T_cam (4, 4)",
    parameters="cam_points, base_points",
)


def _measure_rmse(value, trial: Trial) -> dict[str, float]:
    try:
        r = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OutputError("returned something that is not 3 numbers") from None
    if r.shape != (3,):
        raise OutputError(f"returned shape {r.shape}, expected (3,): one RMSE per base axis")
    if not np.all(np.isfinite(r)):
        raise OutputError("returned NaN or inf")
    return {"rmse": float(np.abs(r - trial.truth).max()) * 1000.0}


PER_AXIS_RMSE = FunctionSpec(
    name="per_axis_rmse", points=2.0, n_trials=18, practice_trials=6, make_trial=None,
    measure=_measure_rmse,
    checks=(Check("rmse", "mm", 1.0, EXACT_BANDS,
                  "r_i = base_T_cam @ cam_i - base_i, turned onto the camera axes (R^T r_i); "
                  "sqrt(mean(r**2)) per camera axis"),),
    signature="per_axis_rmse(base_T_cam (4, 4), cam_points (N, 3), base_points (N, 3)) -> (3,) m "
              "along the camera axes",
    parameters="base_T_cam, cam_points, base_points",
)

SPECS = (FRAME_FROM_THREE_POINTS, REPROJECT, HAND_TO_EYE, PER_AXIS_RMSE)
