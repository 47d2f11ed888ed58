"""Lab 1 (camera intrinsics and flange calibration), private side: the problem generators.

The scoring is public, in :mod:`autograder.scoring.lab1_flange`; this module draws the
problems and computes their truths, and is never given to students.

* ``fit_rigid``: of every six problems (:data:`FIT_LAYOUT`), one is degenerate and must
  raise ``ValueError`` as the lab asks (exactly collinear points, or only two points; a fit
  without the check returns some pose and earns nothing there), three have *planar* flange
  positions (one height, as on one layer of the real Aubo capture) and two fill a volume. On
  a planar set the cross-covariance has rank 2 and a fit without the reflection fix returns
  a mirror image (det -1) on 71 % of problems (measured over 2000), so with 9 planar
  problems of 18 it keeps full credit on 0.29^9 ~ 1e-5 of draws.
* ``per_point_residuals``: |dst_T_src @ src_i - dst_i| (m); ``per_axis_rmse``: the RMS
  residual along each axis of the *src* (camera) frame (m), where an RGB-D camera's depth
  error shows up on z. Exact formulas, so their tolerance is a small multiple of float64
  rounding (``EXACT_MM``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from autograder import synthetic
from autograder.scoring import lab1_flange as scoring
from autograder.spec_types import Trial, random_pose
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


def _true_point_residuals(T, src, dst) -> np.ndarray:
    return np.linalg.norm(_true_residuals(T, src, dst), axis=1)


def _true_axis_rmse(T, src, dst) -> np.ndarray:
    r_src = _true_residuals(T, src, dst) @ T[:3, :3]  # R^T r_i: along the src (camera) axes
    return np.sqrt(np.mean(r_src**2, axis=0))


def _trial_point_residuals(rng, index: int) -> Trial:
    T, src, dst, label = _residual_problem(rng)
    return Trial(args=(T, src, dst), truth=_true_point_residuals(T, src, dst),
                 tol={"residuals": EXACT_MM}, label=label)


def _trial_axis_rmse(rng, index: int) -> Trial:
    T, src, dst, label = _residual_problem(rng)
    return Trial(args=(T, src, dst), truth=_true_axis_rmse(T, src, dst),
                 tol={"rmse": EXACT_MM}, label=label)


FIT_RIGID = replace(scoring.FIT_RIGID, make_trial=_trial_fit_rigid)
PER_POINT_RESIDUALS = replace(scoring.PER_POINT_RESIDUALS, make_trial=_trial_point_residuals)
PER_AXIS_RMSE = replace(scoring.PER_AXIS_RMSE, make_trial=_trial_axis_rmse)

SPECS = (FIT_RIGID, PER_POINT_RESIDUALS, PER_AXIS_RMSE)

# What computes a graded quantity (a truth): never in a student's copy.
ANSWERS = (_true_residuals, _true_point_residuals, _true_axis_rmse, _degenerate_fit,
           _trial_fit_rigid, _trial_point_residuals, _trial_axis_rmse)
