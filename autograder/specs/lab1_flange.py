"""Lab 1 (camera intrinsics and flange calibration), private side: the problem generators and
the code mistakes.

The scoring is public, in :mod:`autograder.scoring.lab1_flange`; this module draws the
problems, computes their truths and holds the classic wrong versions of each function, and is
never given to students.

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
from autograder.spec_types import CodeMistake, Trial, random_pose
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


# --------------------------------------------------------------------------- code mistakes


def _pose(R, t) -> np.ndarray:
    # Not geo.make_pose: a mistake may return a mirror image (det -1) as the student's would.
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _kabsch(src, dst, reflection_fix: bool = True, degenerate_check: bool = True) -> np.ndarray:
    """dst_T_src by the SVD of the cross-covariance, as the lab asks (the notebook's test of
    a degenerate set: fewer than 3 points, or a second singular value below 1e-3 of the
    first); the flags switch off the two steps students leave out."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    if degenerate_check:
        if len(src) < 3:
            raise ValueError("fewer than 3 points")
        s = np.linalg.svd(a, compute_uv=False)
        if s[1] < 1e-3 * s[0]:
            raise ValueError("collinear points")
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) if reflection_fix else 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst.mean(axis=0) - R @ src.mean(axis=0))


def _fit_no_reflection_fix(src, dst):
    return _kabsch(src, dst, reflection_fix=False)


def _fit_no_degenerate_check(src, dst):
    return _kabsch(src, dst, degenerate_check=False)


def _fit_inverse(src, dst):
    return geo.invert(_kabsch(src, dst))


def _fit_swapped(src, dst):
    return _kabsch(dst, src)


def _fit_transposed(src, dst):
    T = _kabsch(src, dst)
    T[:3, :3] = T[:3, :3].T
    return T


def _fit_uncentred(src, dst):
    # H = sum src_i dst_i^T of the raw points: step 1 of the lab (centre both sets) left out,
    # so H mixes the centroids' offset into the rotation; t still maps centroid to centroid
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    if len(src) < 3:
        raise ValueError("fewer than 3 points")
    U, _, Vt = np.linalg.svd(src.T @ dst)
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return _pose(R, dst.mean(axis=0) - R @ src.mean(axis=0))


def _fit_translation_mm(src, dst):
    T = _kabsch(src, dst)
    T[:3, 3] *= 1000.0
    return T


def _residuals_squared(T, src, dst):
    return _true_point_residuals(T, src, dst) ** 2


def _residuals_inverse_pose(T, src, dst):
    return _true_point_residuals(geo.invert(T), src, dst)


def _residuals_transposed(T, src, dst):
    T = np.array(T, dtype=float)
    T[:3, :3] = T[:3, :3].T
    return _true_point_residuals(T, src, dst)


def _residuals_mm(T, src, dst):
    return _true_point_residuals(T, src, dst) * 1000.0


def _rmse_dst_axes(T, src, dst):
    return np.sqrt(np.mean(_true_residuals(T, src, dst) ** 2, axis=0))


def _rmse_r_not_transposed(T, src, dst):
    r = _true_residuals(T, src, dst)
    return np.sqrt(np.mean((r @ T[:3, :3].T) ** 2, axis=0))


def _rmse_no_sqrt(T, src, dst):
    return _true_axis_rmse(T, src, dst) ** 2


def _rmse_one_for_all_axes(T, src, dst):
    return np.full(3, np.sqrt(np.mean(_true_axis_rmse(T, src, dst) ** 2)))


FIT_MISTAKES = (
    CodeMistake("its rotation has determinant -1 on this planar set: a mirror image, not a "
                "rotation; flip the sign of the last column of V when det(V U^T) < 0",
                _fit_no_reflection_fix),
    CodeMistake("it fitted a degenerate set (collinear points, or fewer than 3): no rigid map "
                "is determined there, raise ValueError", _fit_no_degenerate_check),
    CodeMistake("this is src_T_dst, the inverse of dst_T_src: the fit maps src points onto "
                "dst points (dst_i = R src_i + t)", _fit_inverse),
    CodeMistake("src and dst are swapped: fit_rigid(src, dst) returns the map taking src "
                "points onto dst points", _fit_swapped),
    CodeMistake("its rotation is R^T: with H = sum (src_i - c_src)(dst_i - c_dst)^T = U S V^T "
                "the rotation is V U^T", _fit_transposed),
    CodeMistake("its translation is in millimetres: the course works in metres (divide by "
                "1000; the points are in metres already)", _fit_translation_mm),
    CodeMistake("the cross-covariance is of the raw points, not the centred ones: subtract "
                "each set's centroid before H = sum (src_i - c_src)(dst_i - c_dst)^T",
                _fit_uncentred),
)
RESIDUAL_MISTAKES = (
    CodeMistake("these are squared distances: the residual is the distance |R src_i + t - "
                "dst_i| itself (take the square root)", _residuals_squared),
    CodeMistake("the inverse pose was applied: dst_T_src maps src points into dst "
                "(R src_i + t), to compare with dst_i", _residuals_inverse_pose),
    CodeMistake("the src points were rotated by R^T: map them with R src_i + t (for rows "
                "of points in numpy, src @ R.T + t)", _residuals_transposed),
    CodeMistake("these are in millimetres: the course works in metres (divide by 1000)",
                _residuals_mm),
)


def rmse_mistakes(src: str, dst: str) -> tuple[CodeMistake, ...]:
    """The classic mistakes of a per-axis RMSE along the ``src`` frame's axes of the
    residuals of a ``dst``_T_``src`` map (lab 1: src and dst; lab 4: camera and base)."""
    return (
        CodeMistake(f"the RMS is taken along the {dst} axes: rotate the residuals into the "
                    f"{src} frame first (R^T r_i; for rows in numpy, r @ R)", _rmse_dst_axes),
        CodeMistake(f"the residuals were rotated by R, not R^T: into the {src} frame they go "
                    "with R^T r_i (for rows in numpy, r @ R)", _rmse_r_not_transposed),
        CodeMistake("this is the mean square: the RMS is its square root", _rmse_no_sqrt),
        CodeMistake("one RMS is repeated on every axis: take the RMS of each axis on its own "
                    "(the mean over the points, axis=0)", _rmse_one_for_all_axes),
    )


FIT_RIGID = replace(scoring.FIT_RIGID, make_trial=_trial_fit_rigid, code_mistakes=FIT_MISTAKES,
                    reference=_kabsch)
PER_POINT_RESIDUALS = replace(scoring.PER_POINT_RESIDUALS, make_trial=_trial_point_residuals,
                              code_mistakes=RESIDUAL_MISTAKES,
                              reference=_true_point_residuals)
PER_AXIS_RMSE = replace(scoring.PER_AXIS_RMSE, make_trial=_trial_axis_rmse,
                        code_mistakes=rmse_mistakes("src", "dst"), reference=_true_axis_rmse)

SPECS = (FIT_RIGID, PER_POINT_RESIDUALS, PER_AXIS_RMSE)

# What computes a graded quantity (a truth, a fit, a mistaken answer): never in a student's
# copy.
ANSWERS = (_true_residuals, _true_point_residuals, _true_axis_rmse, _degenerate_fit,
           _trial_fit_rigid, _trial_point_residuals, _trial_axis_rmse, _kabsch,
           _fit_no_reflection_fix, _fit_no_degenerate_check, _fit_inverse, _fit_swapped,
           _fit_transposed, _fit_translation_mm, _fit_uncentred, _residuals_squared, _residuals_inverse_pose,
           _residuals_transposed, _residuals_mm, _rmse_dst_axes, _rmse_r_not_transposed,
           _rmse_no_sqrt, _rmse_one_for_all_axes)
