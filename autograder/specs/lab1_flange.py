"""Lab 1 (camera intrinsics and flange calibration): the graded functions and their scoring.

Three pure functions, all about the rigid fit ``dst ~= dst_T_src @ src`` of a flange
calibration (src = camera frame, dst = robot base frame):

* ``fit_rigid(src, dst) -> dst_T_src``: the SVD (Kabsch / Arun) fit. Scored by how far the
  fitted map moves the measured points from where the true map puts them, with a tolerance
  from the noise level. Of every six problems (:data:`FIT_LAYOUT`), one is degenerate and must
  raise ``ValueError`` as the lab asks (exactly collinear points, or only two points; a fit
  without the check returns some pose and earns nothing there), three have *planar* flange
  positions (one height, as on one layer of the real Aubo capture) and two fill a volume. On
  a planar set the cross-covariance has rank 2 and a fit without the reflection fix returns
  a mirror image (det -1) on 71 % of problems (measured over 2000), so with 9 planar
  problems of 18 it keeps full credit on 0.29^9 ~ 1e-5 of draws.
* ``per_point_residuals(dst_T_src, src, dst) -> (N,)``: |dst_T_src @ src_i - dst_i| (m).
* ``per_axis_rmse(dst_T_src, src, dst) -> (3,)``: the RMS residual along each axis of the
  *src* (camera) frame (m), where an RGB-D camera's depth error shows up on z.

The last two are exact formulas on given inputs, so their tolerance is a small multiple of
float64 rounding (``EXACT_TOL``, in mm).
"""

from __future__ import annotations

import math

import numpy as np

from autograder import synthetic
from autograder.spec_types import (
    EXACT_BANDS,
    Check,
    FunctionSpec,
    OutputError,
    Trial,
    as_output_pose,
    pose_errors,
    random_pose,
)
from robots import geometry as geo

# fit_rigid's problems, by index % 6: degenerate (expects ValueError), 3 planar, 2 volume.
FIT_LAYOUT = ("degenerate", "planar", "planar", "planar", "volume", "volume")
EXACT_MM = 1e-6  # see autograder.checks.EXACT_TOL: ~1e7 times float64 rounding on metre scales


def _planar(p: synthetic.FlangeProblem, rng, sigma_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The same problem with every flange position at one height (a planar point set)."""
    base = p.base_points.copy()
    base[:, 2] = base[0, 2]
    R, t = p.base_T_cam_true[:3, :3], p.base_T_cam_true[:3, 3]
    cam = (base - t) @ R  # R^T (b - t), row-wise
    cam += rng.normal(0.0, sigma_mm / 1000.0, cam.shape)
    return cam, base


# A fit's rotation about the points' long axis is known to about sigma / (spread across it):
# a set spread less than 25 sigma across (a few points of a plane that happen to line up)
# is nearly collinear, so the rotation is uncertain by degrees and the instructors' fit
# refuses it (solutions.registration.fit_rigid: over 5 deg). Such draws are redrawn.
MIN_SPREAD_SIGMAS = 25.0


def _second_spread_mm(points: np.ndarray) -> float:
    """RMS spread (mm) of ``points`` along their second principal axis."""
    centred = points - points.mean(axis=0)
    return 1000.0 * float(np.linalg.svd(centred, compute_uv=False)[1]) / math.sqrt(len(points))


def _degenerate_fit(rng, index: int) -> Trial:
    """Collinear points (exactly, up to rounding: any rank test sees it) or two points,
    alternately: no rigid map is determined, so the answer is ValueError."""
    T = random_pose(rng)
    if (index // len(FIT_LAYOUT)) % 2 == 0:
        n = int(rng.integers(4, 12))
        direction = rng.normal(size=3)
        cam = rng.uniform(-0.2, 0.2, (1, 3)) + np.outer(rng.uniform(-0.2, 0.2, n),
                                                        direction / np.linalg.norm(direction))
        cam += [0.0, 0.0, 1.0]
        label = f"collinear set of {n} points"
    else:
        cam = rng.uniform(-0.2, 0.2, (2, 3)) + [0.0, 0.0, 1.0]
        label = "set of only 2 points"
    return Trial(args=(cam, geo.transform_points(T, cam)), truth=(T, cam),
                 tol={"mapping": 1.0}, label=label + " (expects ValueError)", raises="ValueError")


def _trial_fit_rigid(rng, index: int) -> Trial:
    shape = FIT_LAYOUT[index % len(FIT_LAYOUT)]
    if shape == "degenerate":
        return _degenerate_fit(rng, index)
    n = int(rng.integers(6, 16))
    sigma_mm = float(rng.uniform(0.5, 2.0))
    for _ in range(50):
        p = synthetic.make_flange(rng, n_points=n, noise_mm=sigma_mm, fixed_orientation=False)
        cam, base = p.cam_points, p.base_points
        if shape == "planar":
            cam, base = _planar(p, rng, sigma_mm)
        if _second_spread_mm(base) >= MIN_SPREAD_SIGMAS * sigma_mm:
            break
    # A least-squares rigid fit has 6 parameters, so the fitted map's error summed over the n
    # points has expectation 6 sigma^2 (3 axes each): RMS over points sigma*sqrt(6/n). Three
    # times that is > 5 standard deviations of the chi-square(6) tail: a correct fit passes.
    tol = 3.0 * sigma_mm * math.sqrt(6.0 / n)
    return Trial(args=(cam, base), truth=(p.base_T_cam_true, cam),
                 tol={"mapping": tol},
                 label=f"{shape} set of {n} points, {sigma_mm:.2f} mm noise")


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


# --------------------------------------------------------------------------- residuals


def _residual_problem(rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """A flange problem with RealSense-like depth noise and an outlier, and a pose to judge.

    The pose is the truth moved by a few millimetres and a fraction of a degree, as a fitted
    pose is: residuals then mix the noise with the pose error, in every axis.
    """
    n = int(rng.integers(8, 20))
    p = synthetic.make_flange(rng, n_points=n, noise_mm=0.5, depth_noise_mm=3.0,
                              fixed_orientation=bool(rng.integers(2)), n_outliers=1)
    nudge = geo.pose_from_rotvec(rng.normal(0.0, 0.005, 3), rng.normal(0.0, 0.003, 3))
    T = p.base_T_cam_true @ nudge
    return T, p.cam_points, p.base_points, f"{n} poses, one outlier"


def _true_residuals(T, src, dst) -> np.ndarray:
    return src @ T[:3, :3].T + T[:3, 3] - dst


def _trial_point_residuals(rng, index: int) -> Trial:
    T, src, dst, label = _residual_problem(rng)
    truth = np.linalg.norm(_true_residuals(T, src, dst), axis=1)
    return Trial(args=(T, src, dst), truth=truth, tol={"residuals": EXACT_MM}, label=label)


def _trial_axis_rmse(rng, index: int) -> Trial:
    T, src, dst, label = _residual_problem(rng)
    r_src = _true_residuals(T, src, dst) @ T[:3, :3]  # R^T r_i: along the src (camera) axes
    truth = np.sqrt(np.mean(r_src**2, axis=0))
    return Trial(args=(T, src, dst), truth=truth, tol={"rmse": EXACT_MM}, label=label)


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
    name="fit_rigid", points=4.0, n_trials=18, practice_trials=6, make_trial=_trial_fit_rigid,
    measure=_measure_fit,
    checks=(
        Check("mapping", "mm", 1.0, ((1.0, 1.0), (2.0, 0.5)),
              "RMS distance between your map and the true one over the measured points; "
              "planar sets need the reflection fix, collinear points or fewer than 3 a "
              "ValueError"),
    ),
    signature="fit_rigid(src: (N, 3), dst: (N, 3)) -> dst_T_src (4, 4)",
)
PER_POINT_RESIDUALS = FunctionSpec(
    name="per_point_residuals", points=2.0, n_trials=12, practice_trials=4, make_trial=_trial_point_residuals,
    measure=_measure_vector("residuals"),
    checks=(Check("residuals", "mm", 1.0, EXACT_BANDS,
                  "|dst_T_src @ src_i - dst_i| per point, in metres"),),
    signature="per_point_residuals(dst_T_src: (4, 4), src: (N, 3), dst: (N, 3)) -> (N,)",
)
PER_AXIS_RMSE = FunctionSpec(
    name="per_axis_rmse", points=2.0, n_trials=12, practice_trials=4, make_trial=_trial_axis_rmse,
    measure=_measure_vector("rmse"),
    checks=(Check("rmse", "mm", 1.0, EXACT_BANDS,
                  "RMS of the residuals along the x, y, z axes of the src (camera) frame: "
                  "rotate each residual by R^T first"),),
    signature="per_axis_rmse(dst_T_src: (4, 4), src: (N, 3), dst: (N, 3)) -> (3,) "
              "along the src axes",
)

SPECS = (FIT_RIGID, PER_POINT_RESIDUALS, PER_AXIS_RMSE)
