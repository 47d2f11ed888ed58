"""Lab 4 (stereo single-shot hand-to-eye): the graded functions and how they are scored.

Four pure functions:

* ``frame_from_three_points`` and ``per_axis_rmse`` are exact formulas, graded with the
  float64-rounding tolerances of lab 0 on random frames and point sets; the frame puts 0.9
  of its credit on the rotation (the cross products, what it teaches) and 0.1 on the
  translation (``p_origin`` copied);
* ``reproject`` is graded on points seen by random rectified stereo pairs (focal length,
  principal points, baseline drawn per problem, the right principal point shifted as
  ``cv2.stereoRectify`` does without ``CALIB_ZERO_DISPARITY``), so both the homogeneous
  division and the ``(cx - cx') / Tx`` term of Q matter; float32 arithmetic is correct code
  and keeps full credit (the tolerance bounds its rounding, :func:`float32_bound_mm`);
* ``per_axis_rmse`` is the RMS residual along each *camera* axis (where stereo's depth error
  shows up on z), the same function and convention as in lab 1, so ``check(per_axis_rmse)``
  scores it the same whichever lab's specification it finds;
* ``hand_to_eye_from_three_points`` is graded on ``autograder.synthetic.make_three_point``
  experiments (flat and inclined boards, camera and pointer noise): the RMS distance between
  the returned map and the true one over the 12 check points, within a band set by the noise.
"""

from __future__ import annotations

import math

import numpy as np

from autograder import synthetic
from autograder.spec_types import (
    EXACT_BANDS,
    EXACT_TOL,
    Check,
    FunctionSpec,
    OutputError,
    Trial,
    as_output_pose,
    measure_pose,
    pose_errors,
    random_pose,
)
from robots import geometry as geo

# --------------------------------------------------------------------------- three-point frame


def _trial_frame(rng, index: int) -> Trial:
    parent_T_frame = random_pose(rng)
    # p_x anywhere on +x; p_xy anywhere on the +y side of the x axis, NOT on the y axis (a
    # measured third corner never is), so the y axis must be built, not copied.
    a = rng.uniform(0.05, 0.5)
    b = rng.uniform(0.05, 0.5)
    on_axis = index % 6 == 0  # one in six with p_xy on the y axis exactly
    c = 0.0 if on_axis else rng.uniform(-0.3, 0.3)
    local = np.array([[0.0, 0.0, 0.0], [a, 0.0, 0.0], [c, b, 0.0]])
    p = geo.transform_points(parent_T_frame, local)
    return Trial(args=(p[0], p[1], p[2]), truth=parent_T_frame, tol=dict(EXACT_TOL),
                 label="on the y axis" if on_axis else "off the y axis")


FRAME_FROM_THREE_POINTS = FunctionSpec(
    name="frame_from_three_points", points=3.0, n_trials=18, practice_trials=6,
    make_trial=_trial_frame, measure=measure_pose,
    checks=(
        Check("rotation", "deg", 0.9, EXACT_BANDS,
              "x = unit(p_x - o), z = unit(x cross (p_xy - o)), y = z cross x: right-handed, "
              "with p_xy on the +y side"),
        Check("translation", "mm", 0.1, EXACT_BANDS, "the origin: p_origin itself"),
    ),
    signature="frame_from_three_points(p_origin (3,), p_x (3,), p_xy (3,)) -> parent_T_frame",
)

# --------------------------------------------------------------------------- Q reprojection


def random_stereo_q(rng) -> tuple[np.ndarray, dict]:
    """OpenCV's Q (4, 4) for a random rectified horizontal pair, and its parameters.

    ``P2 = [[f, 0, cx2, Tx f], [0, f, cy, 0], [0, 0, 1, 0]]`` with ``Tx = -baseline`` (the right
    camera sits at +baseline along the left x axis); then, as in ``cv2.stereoRectify``,
    ``Q = [[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1/Tx, (cx - cx2)/Tx]]``.
    """
    f = rng.uniform(300.0, 1500.0)
    cx, cy = rng.uniform(250.0, 700.0), rng.uniform(200.0, 500.0)
    cx2 = cx + rng.uniform(-40.0, 40.0)
    baseline = rng.uniform(0.03, 0.3)
    tx = -baseline
    Q = np.array([[1.0, 0.0, 0.0, -cx],
                  [0.0, 1.0, 0.0, -cy],
                  [0.0, 0.0, 0.0, f],
                  [0.0, 0.0, -1.0 / tx, (cx - cx2) / tx]])
    return Q, {"f": f, "cx": cx, "cy": cy, "cx2": cx2, "baseline": baseline}


def _trial_reproject(rng, index: int) -> Trial:
    Q, s = random_stereo_q(rng)
    z = rng.uniform(0.3, 2.5)
    x, y = rng.uniform(-0.4, 0.4) * z, rng.uniform(-0.3, 0.3) * z
    u = s["f"] * x / z + s["cx"]
    v = s["f"] * y / z + s["cy"]
    d = u - (s["f"] * (x - s["baseline"]) / z + s["cx2"])  # u_left - u_right
    p = np.array([x, y, z])
    tol = max(REPROJECT_TOL_MM, FLOAT32_FACTOR * float32_bound_mm(u, v, d, Q, p))
    return Trial(args=(float(u), float(v), float(d), Q), truth=p,
                 tol={"position": tol}, label=f"point {z:.2f} m away")


def float32_bound_mm(u, v, d, Q, p) -> float:
    """First-order bound (mm) on the error of ``reproject`` done in float32.

    Q @ [u, v, d, 1] = [u - cx, v - cy, f, W] with W = Q[3, 2] d + Q[3, 3]; rounding every
    input and sum to float32 (relative eps32) moves W by eps32 (|Q32 d| + |Q33|), which moves
    p = [X, Y, Z] / W by |p| dW / |W|, and the numerators by eps32 (|u| + |cx| + ...) / |W|.
    W cancels when the principal points differ (cx - cx' against a small disparity), so the
    bound grows for far points seen by a short baseline: up to ~2e-3 mm at 2.5 m.
    """
    eps = float(np.finfo(np.float32).eps)
    W = Q[3, 2] * d + Q[3, 3]
    spread_w = eps * (abs(Q[3, 2] * d) + abs(Q[3, 3]))
    numerators = eps * (abs(u) + abs(Q[0, 3]) + abs(v) + abs(Q[1, 3]) + abs(Q[2, 3]))
    return 1000.0 * (float(np.linalg.norm(p)) * spread_w + numerators) / abs(W)


# Full credit within the larger of 1e-3 mm and twice the float32 bound: over 100,000 problems
# float32 arithmetic (numpy float32, cv2.perspectiveTransform) reached 0.64 of the bound (the
# old fixed 1e-3 mm failed float32 on 0.02 % of problems, 0.5 % of 24-problem draws); a wrong
# homogeneous coordinate, a dropped Q term or a flipped disparity is off by centimetres.
REPROJECT_TOL_MM = 1e-3
FLOAT32_FACTOR = 2.0


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
    name="reproject", points=3.0, n_trials=24, practice_trials=8, make_trial=_trial_reproject,
    measure=_measure_point,
    checks=(Check("position", "mm", 1.0, ((1.0, 1.0), (100.0, 0.5)),
                  "Q @ [u, v, d, 1] = [X, Y, Z, W]; the point is [X, Y, Z] / W"),),
    signature="reproject(u: float, v: float, d: float, Q: (4, 4)) -> p_cam (3,) metres",
)

# --------------------------------------------------------------------------- hand-to-eye


# Over 4000 simulated experiments a correct three-point calibration maps the check points
# within 5.1 sigma RMS (99.9 % within 4.5 sigma), where sigma^2 = camera^2 + pointer^2 noise
# per axis; 7 sigma keeps a correct method at full credit. A wrong chain (inverse, wrong
# order, the camera frame used as the world) is off by tens of centimetres.
HAND_TO_EYE_SIGMAS = 7.0
NOISE_FREE_TOL_MM = 1e-3


def _trial_hand_to_eye(rng, index: int) -> Trial:
    inclined = bool(index % 2)
    if index % 6 < 2:  # two in six noise-free
        cam_mm = pointer_mm = 0.0
    else:
        cam_mm, pointer_mm = float(rng.uniform(0.2, 2.0)), float(rng.uniform(0.1, 1.0))
    p = synthetic.make_three_point(rng, camera_noise_mm=cam_mm, pointer_noise_mm=pointer_mm,
                                   inclined=inclined)
    tol = max(HAND_TO_EYE_SIGMAS * math.hypot(cam_mm, pointer_mm), NOISE_FREE_TOL_MM)
    label = (f"{'inclined' if inclined else 'flat'} board, camera {cam_mm:.2f} mm, "
             f"pointer {pointer_mm:.2f} mm noise")
    return Trial(args=(p.cam_points, p.base_points), truth=(p.base_T_cam_true, p.check_cam),
                 tol={"mapping": tol}, label=label)


def _three_point_frame(p_origin, p_x, p_xy) -> np.ndarray:
    """parent_T_frame: origin at p_origin, x towards p_x, z normal to the plane of the three."""
    x = (p_x - p_origin) / np.linalg.norm(p_x - p_origin)
    z = np.cross(x, p_xy - p_origin)
    z /= np.linalg.norm(z)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p_origin
    return T


def _hand_to_eye_substitutes(args) -> dict:
    # Scored on its own: its calls of frame_from_three_points on the camera's and the base's
    # three points get the true frames, so an error there costs its points once.
    return {"frame_from_three_points": [
        (tuple(np.asarray(points, dtype=float)), _three_point_frame(*np.asarray(points, float)))
        for points in args]}


def _measure_hand_to_eye(value, trial: Trial) -> dict[str, float]:
    T = as_output_pose(value)
    truth, check_cam = trial.truth
    if not math.isfinite(pose_errors(T, truth)["rotation"]):
        raise OutputError("returned a rotation block that is not a proper rotation (det +1)")
    diff = geo.transform_points(T, check_cam) - geo.transform_points(truth, check_cam)
    return {"mapping": float(np.sqrt(np.mean(np.sum(diff**2, axis=1)))) * 1000.0}


HAND_TO_EYE = FunctionSpec(
    name="hand_to_eye_from_three_points", points=2.0, n_trials=18, practice_trials=6,
    make_trial=_trial_hand_to_eye, measure=_measure_hand_to_eye,
    checks=(Check("mapping", "mm", 1.0, ((1.0, 1.0), (2.0, 0.5)),
                  "base_T_cam = base_T_world @ inv(cam_T_world); RMS error of the map over "
                  "12 board points"),),
    signature="hand_to_eye_from_three_points(cam_points (3, 3), base_points (3, 3)) -> "
              "base_T_cam (4, 4)",
    substitutes=_hand_to_eye_substitutes,
)

# --------------------------------------------------------------------------- per-axis RMSE


def _trial_rmse(rng, index: int) -> Trial:
    n = int(rng.integers(3, 16))
    T = random_pose(rng)
    cam = rng.uniform(-0.5, 0.5, (n, 3)) + [0.0, 0.0, 1.0]
    # Errors larger along the camera's depth axis (as a stereo camera's are) and different on
    # x and y, so an answer that uses the base axes or mixes up the axes shows.
    sigma = np.sort(rng.uniform(0.5, 5.0, 3)) / 1000.0
    base = geo.transform_points(T, cam + rng.normal(0.0, 1.0, (n, 3)) * sigma)
    r_cam = (geo.transform_points(T, cam) - base) @ T[:3, :3]  # R^T r_i, row by row
    return Trial(args=(T, cam, base), truth=np.sqrt(np.mean(r_cam**2, axis=0)),
                 tol={"rmse": 1e-6}, label=f"{n} points")


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
    name="per_axis_rmse", points=2.0, n_trials=18, practice_trials=6, make_trial=_trial_rmse, measure=_measure_rmse,
    checks=(Check("rmse", "mm", 1.0, EXACT_BANDS,
                  "r_i = base_T_cam @ cam_i - base_i, turned onto the camera axes (R^T r_i); "
                  "sqrt(mean(r**2)) per camera axis"),),
    signature="per_axis_rmse(base_T_cam (4, 4), cam_points (N, 3), base_points (N, 3)) -> (3,) m "
              "along the camera axes",
)

SPECS = (FRAME_FROM_THREE_POINTS, REPROJECT, HAND_TO_EYE, PER_AXIS_RMSE)
