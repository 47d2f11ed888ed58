"""Lab 5 (a depth camera calibrated by the robot's flange; a rectangle's pose from its shape):
how its graded functions are scored.

Conventions (DESIGN.md): metres inside, millimetres and degrees only in the errors shown;
camera optical frame (x right, y down, z forward); pixel (u, v) = (column, row); ``a_T_b``
poses.

* ``backproject(depth_raw, K, depth_scale)``: every pixel with a measurement against its true
  3-D point (mm, float32 rounding allowed), and every hole (raw == 0) must be NaN;
* ``fit_plane_ransac(points, inlier_m, iterations, seed)``: the normal's direction (deg; it
  must point towards the camera, so one pointing away is 180 deg off) and how far the
  returned centre lies from the true plane (mm), on point clouds with outliers;
* ``fit_flange_circle(rim_points, radius_m)``: the centre (mm) and the normal (deg, towards
  the camera) of the flange face from points on partial arcs of its rim.

The centre and the normal of these two are one answer: each check ``requires`` the others
(:class:`autograder.spec_types.Check`), so a right point with a constant normal, or a point
anywhere on the plane, earns nothing (the median of the points with the normal (0, 0, -1)
earned 1.42 / 2 on fit_plane_ransac before; the mean of the rim 0.49 / 2 on fit_flange_circle);
* ``base_T_cam_from_flanges(cam_centres, base_T_flanges)``: the pose's rotation (deg) and
  translation (mm);
* ``rectangle_pose(corners_px, width_m, height_m, K)``: the pose's rotation (deg) and
  translation (mm).

The noisy functions' tolerances are set per problem from its noise (how, in
autograder/specs/lab5_depth.py, which draws the problems); this module never computes an
answer.
"""

from __future__ import annotations

import math

import numpy as np

from autograder.spec_types import Check, FunctionSpec, OutputError, Trial, measure_pose

# Noisy problems: full credit within the tolerance, half within three times it (a method that
# is right but sloppy, e.g. too few RANSAC iterations), nothing beyond.
NOISY_BANDS = ((1.0, 1.0), (3.0, 0.5))
# The plane's tolerances are no noise sd but the width of RANSAC's own ambiguity (a plane
# anywhere in the inlier band over the face: up to 17 deg on a 40 mm face with a 3 mm band),
# so three times them says nothing (51 deg: the constant normal (0, 0, -1) on most faces,
# 9 mm: the housing 6.5 mm behind): full credit within them, none beyond.
PLANE_BANDS = ((1.0, 1.0),)


# --------------------------------------------------------------------------- back-projection


def _measure_backproject(value, trial: Trial) -> dict[str, float]:
    truth = trial.truth  # (H, W, 3) metres, NaN where the raw depth is 0
    h, w = truth.shape[:2]
    try:
        P = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OutputError(f"returned {type(value).__name__}, expected a numpy array of shape "
                          f"({h}, {w}, 3)") from None
    if P.shape != truth.shape:
        why = "one point (x, y, z) per pixel, indexed [row v, column u]"
        if P.ndim == 2 and P.shape[1] == 3 and P.shape[0] in (h * w, int(np.sum(truth[..., 2] > 0))):
            why = "one point per pixel in the image's layout, not a flat list of points"
        elif P.shape == (w, h, 3):
            why = ("rows first: the image is indexed depth[v, u] (row v, column u), not "
                   "depth[u, v]")
        elif P.shape == (3, h, w):
            why = "the (x, y, z) axis last, e.g. np.stack([x, y, z], axis=-1)"
        raise OutputError(f"returned shape {P.shape}, expected ({h}, {w}, 3): {why}")
    if np.isinf(P).any():
        raise OutputError("returned inf (a division by zero depth?)")
    valid = ~np.isnan(truth[..., 2])
    lost = int(np.isnan(P[valid]).any(axis=1).sum())
    if lost:
        raise OutputError(f"returned NaN at {lost} pixels that have a depth measurement "
                          "(raw > 0): only the holes (raw == 0) are NaN")
    err = np.linalg.norm(P[valid] - truth[valid], axis=1)
    holes_not_nan = int(np.sum(~np.isnan(P[~valid][:, 2])))
    return {"points": float(err.max()) * 1000.0 if err.size else 0.0,
            "holes": float(holes_not_nan)}


BACKPROJECT = FunctionSpec(
    name="backproject", points=2.0, n_trials=12, practice_trials=4, make_trial=None,
    measure=_measure_backproject,
    checks=(
        Check("points", "mm", 0.8, ((1.0, 1.0),),
              "z = raw * depth_scale (metres); x = (u - cx) z / fx, y = (v - cy) z / fy with "
              "u the column and v the row"),
        Check("holes", "pixels", 0.2, ((1.0, 1.0),),
              "pixels with raw == 0 have no measurement: NaN, not a point at z = 0"),
    ),
    signature="backproject(depth_raw (H, W) integer units, K (3, 3), depth_scale m/unit) -> "
              "(H, W, 3) metres, NaN where depth_raw == 0",
    parameters="depth_raw, K, depth_scale",
    forbidden=("robots.perception.point_cloud", "robots.perception.deproject"),
)


# --------------------------------------------------------------------------- centre and normal


def _as_centre_normal(value) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), unit normal (3,)) from a student's return value, or OutputError."""
    expected = "expected a pair (centre (3,) metres, unit normal (3,))"
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        got = f"{len(value)} values" if isinstance(value, (tuple, list)) else \
            type(value).__name__
        raise OutputError(f"returned {got}, {expected}")
    out = []
    for what, part in zip(("centre", "normal"), value):
        try:
            v = np.asarray(part, dtype=float)
        except (TypeError, ValueError):
            raise OutputError(f"the {what} is not numbers; {expected}") from None
        if v.size != 3:
            raise OutputError(f"the {what} has shape {v.shape}, {expected}")
        v = v.reshape(3)
        if not np.all(np.isfinite(v)):
            raise OutputError(f"the {what} holds NaN or inf")
        out.append(v)
    length = float(np.linalg.norm(out[1]))
    if abs(length - 1.0) > 1e-3:
        raise OutputError(f"the normal has length {length:.4g}, expected a unit vector "
                          "(divide by its norm)")
    return out[0], out[1] / length


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between unit vectors (deg), robust near 0 and 180 (atan2, not acos)."""
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b)))


def _measure_plane(value, trial: Trial) -> dict[str, float]:
    centre, normal = _as_centre_normal(value)
    true_centre, true_normal = trial.truth
    return {"normal": _angle_deg(normal, true_normal),
            "offset": abs(float((centre - true_centre) @ true_normal)) * 1000.0}


FIT_PLANE_RANSAC = FunctionSpec(
    name="fit_plane_ransac", points=2.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_plane,
    checks=(
        Check("normal", "deg", 0.5, PLANE_BANDS,
              "RANSAC over random triples, then a least-squares refit on the best inliers; "
              "the normal points towards the camera (normal @ centre < 0); counts only "
              "with the centre on the plane too", requires=("offset",)),
        Check("offset", "mm", 0.5, PLANE_BANDS,
              "the centre (mean of the inliers) lies on the plane: outliers (a surface "
              "behind, flying pixels) must not pull it; counts only with the normal right "
              "too", requires=("normal",)),
    ),
    signature="fit_plane_ransac(points (N, 3) m, inlier_m, iterations=500, seed=0) -> "
              "(centre (3,), unit normal (3,) towards the camera)",
    parameters="points, inlier_m, iterations=500, seed=0",
    forbidden=("solutions.perception.fit_plane_ransac",),
)


def _measure_circle(value, trial: Trial) -> dict[str, float]:
    centre, normal = _as_centre_normal(value)
    true_centre, true_normal = trial.truth
    d = centre - true_centre
    along = float(d @ true_normal)
    return {"centre": float(np.linalg.norm(d - along * true_normal)) * 1000.0,
            "depth": abs(along) * 1000.0,
            "normal": _angle_deg(normal, true_normal)}


FIT_FLANGE_CIRCLE = FunctionSpec(
    # Many cheap problems: the unrefined algebraic fit is off on about one problem in five
    # (the short arcs), so 48 problems catch it on >= 99 % of draws (1 - 0.79^48), and
    # check()'s 3 x 16 practice problems show it too (a check() that passes a bug the grader
    # then finds would surprise a student).
    name="fit_flange_circle", points=2.0, n_trials=48, practice_trials=16, make_trial=None,
    measure=_measure_circle,
    checks=(
        Check("centre", "mm", 0.5, NOISY_BANDS,
              "the centre within the flange's plane: a circle of the known radius by "
              "geometric least squares (|p - c| - r); the algebraic (Kasa) fit alone errs on "
              "a partial arc; counts only with the depth and the normal right too",
              requires=("depth", "normal")),
        Check("depth", "mm", 0.2, NOISY_BANDS,
              "the centre lies in the plane of the rim (SVD of the centred rim points); "
              "counts only with the centre in the plane and the normal right too",
              requires=("centre", "normal")),
        Check("normal", "deg", 0.3, NOISY_BANDS,
              "the rim's plane normal, pointing towards the camera (normal @ centre < 0); "
              "counts only with the centre right too", requires=("centre", "depth")),
    ),
    signature="fit_flange_circle(rim_points (N, 3) m, radius_m) -> (centre (3,), unit normal "
              "(3,) towards the camera)",
    parameters="rim_points, radius_m",
    forbidden=("solutions.perception.fit_flange",),
)


# --------------------------------------------------------------------------- poses


def _pose_checks(describe_rotation: str, describe_translation: str) -> tuple[Check, ...]:
    return (Check("rotation", "deg", 0.5, NOISY_BANDS, describe_rotation),
            Check("translation", "mm", 0.5, NOISY_BANDS, describe_translation))


BASE_T_CAM_FROM_FLANGES = FunctionSpec(
    name="base_T_cam_from_flanges", points=2.0, n_trials=9, practice_trials=3,
    make_trial=None, measure=measure_pose,
    checks=_pose_checks(
        "R from the SVD of the centred cross-covariance sum (cam_i - c_cam)(base_i - c_base)^T, "
        "reflection excluded: base_p = R cam_p + t",
        "t = c_base - R c_cam; the result is base_T_cam, not its inverse"),
    signature="base_T_cam_from_flanges(cam_centres (N, 3) m, base_T_flanges (N, 4, 4)) -> "
              "base_T_cam (4, 4)",
    parameters="cam_centres, base_T_flanges",
)

RECTANGLE_POSE = FunctionSpec(
    name="rectangle_pose", points=2.0, n_trials=12, practice_trials=4, make_trial=None,
    measure=measure_pose,
    checks=_pose_checks(
        "edge directions from the vanishing points of K^-1 [u, v, 1] corners, made orthogonal "
        "(nearest rotation): x along the top edge, y down the left edge, z = x cross y",
        "then t by least squares from the four viewing rays, with the corners at "
        "(+-width/2, +-height/2, 0)"),
    signature="rectangle_pose(corners_px (4, 2) TL, TR, BR, BL, width_m, height_m, K (3, 3)) "
              "-> cam_T_rect (4, 4)",
    parameters="corners_px, width_m, height_m, K",
    forbidden=("cv2.solvePnP", "cv2.solvePnPGeneric", "cv2.solvePnPRansac",
               "solutions.perception.rectangle_pose"),
)

SPECS = (BACKPROJECT, FIT_PLANE_RANSAC, FIT_FLANGE_CIRCLE, BASE_T_CAM_FROM_FLANGES,
         RECTANGLE_POSE)
