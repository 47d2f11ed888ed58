"""Lab 4 (stereo single-shot hand-to-eye), private side: problems, truths, tolerances and the
code mistakes (per_axis_rmse's are lab 1's, along the camera axes).

The scoring is public, in :mod:`autograder.scoring.lab4_stereo`; this module draws the problems
and computes their truths, and is never given to students:

* ``frame_from_three_points`` and ``per_axis_rmse``: random frames and point sets, exact
  formulas (float64-rounding tolerances of lab 0);
* ``reproject``: points seen by random rectified stereo pairs (focal length, principal
  points, baseline drawn per problem, the right principal point shifted as
  ``cv2.stereoRectify`` does without ``CALIB_ZERO_DISPARITY``), so both the homogeneous
  division and the ``(cx - cx') / Tx`` term of Q matter; float32 arithmetic is correct code
  and keeps full credit (the tolerance bounds its rounding, :func:`float32_bound_mm`);
* ``hand_to_eye_from_three_points``: ``autograder.synthetic.make_three_point`` experiments
  (flat and inclined boards, camera and pointer noise), with a tolerance set by the noise;
  its calls of ``frame_from_three_points`` get the true frames (:func:`_hand_to_eye_substitutes`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from autograder import synthetic
from autograder.scoring import lab4_stereo as scoring
from autograder.spec_types import EXACT_TOL, CodeMistake, Trial, random_pose
from autograder.specs.lab1_flange import rmse_mistakes
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


# --------------------------------------------------------------------------- per-axis RMSE


def _true_rmse(T, cam, base) -> np.ndarray:
    r_cam = (geo.transform_points(T, cam) - base) @ T[:3, :3]  # R^T r_i, row by row
    return np.sqrt(np.mean(r_cam**2, axis=0))


def _trial_rmse(rng, index: int) -> Trial:
    n = int(rng.integers(3, 16))
    T = random_pose(rng)
    cam = rng.uniform(-0.5, 0.5, (n, 3)) + [0.0, 0.0, 1.0]
    # Errors larger along the camera's depth axis (as a stereo camera's are) and different on
    # x and y, so an answer that uses the base axes or mixes up the axes shows.
    sigma = np.sort(rng.uniform(0.5, 5.0, 3)) / 1000.0
    base = geo.transform_points(T, cam + rng.normal(0.0, 1.0, (n, 3)) * sigma)
    return Trial(args=(T, cam, base), truth=_true_rmse(T, cam, base),
                 tol={"rmse": 1e-6}, label=f"{n} points")


# --------------------------------------------------------------------------- code mistakes


def _pose(R, t) -> np.ndarray:
    # Not geo.make_pose: a mistake may build a matrix that is no rotation, and it must
    # return it as the student's code would.
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _frame_left_handed(p_origin, p_x, p_xy):
    return _three_point_frame(*_points(p_origin, p_x, p_xy)) @ np.diag([1.0, -1.0, -1.0, 1.0])


def _frame_y_copied(p_origin, p_x, p_xy):
    o, px, pxy = _points(p_origin, p_x, p_xy)
    x = (px - o) / np.linalg.norm(px - o)
    y = (pxy - o) / np.linalg.norm(pxy - o)
    return _pose(np.column_stack([x, y, np.cross(x, y)]), o)


def _frame_inverse(p_origin, p_x, p_xy):
    return geo.invert(_three_point_frame(*_points(p_origin, p_x, p_xy)))


def _frame_transposed(p_origin, p_x, p_xy):
    T = _three_point_frame(*_points(p_origin, p_x, p_xy))
    T[:3, :3] = T[:3, :3].T
    return T


def _points(*points) -> list[np.ndarray]:
    return [np.asarray(p, dtype=float) for p in points]


def _reproject(u, v, d, Q) -> np.ndarray:
    X, Y, Z, W = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return np.array([X, Y, Z]) / W


def _reproject_by_z(u, v, d, Q):
    h = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return h[:3] / h[2]


def _reproject_no_shift(u, v, d, Q):
    Q = np.array(Q, dtype=float)
    Q[3, 3] = 0.0
    return _reproject(u, v, d, Q)


def _reproject_disparity_flipped(u, v, d, Q):
    return _reproject(u, v, -d, Q)


def _reproject_mm(u, v, d, Q):
    return _reproject(u, v, d, Q) * 1000.0


def _frames_of(cam_points, base_points) -> tuple[np.ndarray, np.ndarray]:
    """(base_T_world, cam_T_world): the frames the three points span, seen from each side."""
    return (_three_point_frame(*np.asarray(base_points, dtype=float)),
            _three_point_frame(*np.asarray(cam_points, dtype=float)))


def _hand_to_eye(cam_points, base_points) -> np.ndarray:
    """base_T_cam = base_T_world inv(cam_T_world): the right answer (the reference)."""
    base_T_world, cam_T_world = _frames_of(cam_points, base_points)
    return base_T_world @ geo.invert(cam_T_world)


def _hand_to_eye_inverse(cam_points, base_points):
    base_T_world, cam_T_world = _frames_of(cam_points, base_points)
    return cam_T_world @ geo.invert(base_T_world)


def _hand_to_eye_reversed(cam_points, base_points):
    base_T_world, cam_T_world = _frames_of(cam_points, base_points)
    return geo.invert(cam_T_world) @ base_T_world


def _hand_to_eye_not_inverted(cam_points, base_points):
    base_T_world, cam_T_world = _frames_of(cam_points, base_points)
    return base_T_world @ cam_T_world


FRAME_MISTAKES = (
    CodeMistake("the frame is left-handed or turned over: z = x cross (p_xy - p_origin) (in "
                "that order), then y = z cross x", _frame_left_handed),
    CodeMistake("p_xy - p_origin was used as the y axis: it is not perpendicular to x; build "
                "z = x cross (p_xy - p_origin) first, then y = z cross x", _frame_y_copied),
    CodeMistake("this is frame_T_parent, the inverse of parent_T_frame: the columns of R are "
                "the frame's axes in the parent, the translation is p_origin", _frame_inverse),
    CodeMistake("its rotation is transposed: the axes x, y, z are the columns of R "
                "(np.column_stack), not its rows", _frame_transposed),
)
REPROJECT_MISTAKES = (
    CodeMistake("it is divided by Z, not by W: Q @ [u, v, d, 1] = [X, Y, Z, W], the point is "
                "[X, Y, Z] / W", _reproject_by_z),
    CodeMistake("Q's last entry, (cx - cx')/Tx, was left out: use all of Q (it is not zero "
                "when the principal points differ)", _reproject_no_shift),
    CodeMistake("the disparity's sign is flipped: d = u_left - u_right, pass it as given",
                _reproject_disparity_flipped),
    CodeMistake("the point is in millimetres: the course works in metres (divide by 1000)",
                _reproject_mm),
)
HAND_TO_EYE_MISTAKES = (
    CodeMistake("this is cam_T_base, the inverse of base_T_cam: base_T_cam = base_T_world @ "
                "inv(cam_T_world)", _hand_to_eye_inverse),
    CodeMistake("the product is in reverse order: base_T_cam = base_T_world @ world_T_cam, "
                "left to right", _hand_to_eye_reversed),
    CodeMistake("cam_T_world was used as world_T_cam: invert it (base_T_cam = base_T_world @ "
                "inv(cam_T_world))", _hand_to_eye_not_inverted),
)

FRAME_FROM_THREE_POINTS = replace(scoring.FRAME_FROM_THREE_POINTS, make_trial=_trial_frame,
                                  code_mistakes=FRAME_MISTAKES, reference=_three_point_frame)
REPROJECT = replace(scoring.REPROJECT, make_trial=_trial_reproject,
                    code_mistakes=REPROJECT_MISTAKES, reference=_reproject)
HAND_TO_EYE = replace(scoring.HAND_TO_EYE, make_trial=_trial_hand_to_eye,
                      substitutes=_hand_to_eye_substitutes, code_mistakes=HAND_TO_EYE_MISTAKES,
                      reference=_hand_to_eye)
PER_AXIS_RMSE = replace(scoring.PER_AXIS_RMSE, make_trial=_trial_rmse,
                        code_mistakes=rmse_mistakes("camera", "base"), reference=_true_rmse)

SPECS = (FRAME_FROM_THREE_POINTS, REPROJECT, HAND_TO_EYE, PER_AXIS_RMSE)

# What computes a graded quantity (a truth, the true frames, a mistaken answer): never in a
# student's copy (the per-axis RMSE's mistakes are lab 1's, listed there).
ANSWERS = (_three_point_frame, _hand_to_eye_substitutes, _true_rmse, _trial_frame,
           _trial_reproject, _trial_hand_to_eye, _trial_rmse, _frame_left_handed,
           _frame_y_copied, _frame_inverse, _frame_transposed, _reproject, _reproject_by_z,
           _reproject_no_shift, _reproject_disparity_flipped, _reproject_mm, _frames_of,
           _hand_to_eye, _hand_to_eye_inverse, _hand_to_eye_reversed, _hand_to_eye_not_inverted)
