"""Lab 1 (flange calibration): classic mistakes in fit_rigid, per_point_residuals and
per_axis_rmse (see ``mistake_corpus``)."""

from __future__ import annotations

import numpy as np

from mistake_corpus import pose as _pose
from mistake_corpus import register

mistake = register("lab1_flange")


def _check_points(src, dst):
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise ValueError(f"src and dst must both have shape (N, 3), got {src.shape} and "
                         f"{dst.shape}")
    if len(src) < 3:
        raise ValueError(f"a rigid fit needs at least 3 points, got {len(src)}")


def _check_spread(centred):
    spread = np.linalg.svd(centred, compute_uv=False)
    if spread[1] < 1e-3 * spread[0]:
        raise ValueError("the points are (nearly) collinear")


# --------------------------------------------------------------------------- fit_rigid


@mistake("fit_rigid", "inverse/transpose", "I built H as dst_c^T @ src_c, the transpose of "
         "the cross-covariance, so V U^T came out as R^T")
def fit_covariance_transposed(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - src_mean, dst - dst_mean
    _check_spread(src_c)
    U, _, Vt = np.linalg.svd(dst_c.T @ src_c)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst_mean - R @ src_mean)


@mistake("fit_rigid", "none", "I took the translation as dst_mean - src_mean and forgot to "
         "rotate the src centroid by R", names=r"rotate.{0,20}centroid|R @ c_src|R c_src")
def fit_translation_unrotated(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - src_mean, dst - dst_mean
    _check_spread(src_c)
    U, _, Vt = np.linalg.svd(src_c.T @ dst_c)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst_mean - src_mean)


@mistake("fit_rigid", "none", "I used the median of each point set as its centre, not the "
         "mean", names=r"median")
def fit_median_centre(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mid, dst_mid = np.median(src, axis=0), np.median(dst, axis=0)
    src_c, dst_c = src - src_mid, dst - dst_mid
    _check_spread(src_c)
    U, _, Vt = np.linalg.svd(src_c.T @ dst_c)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst_mid - R @ src_mid)


@mistake("fit_rigid", "none", "in the reflection fix I put d on the first diagonal entry, "
         "diag([d, 1, 1]), instead of the last (the smallest singular value's)",
         names=r"last column|smallest singular|diag")
def fit_reflection_fix_wrong_axis(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - src_mean, dst - dst_mean
    _check_spread(src_c)
    U, _, Vt = np.linalg.svd(src_c.T @ dst_c)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([d, 1.0, 1.0]) @ U.T
    return _pose(R, dst_mean - R @ src_mean)


@mistake("fit_rigid", "uncentred", "my collinearity test took the singular values of the "
         "raw points, not of the centred ones, so a line away from the origin passed it")
def fit_collinear_test_uncentred(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - src_mean, dst - dst_mean
    _check_spread(src)
    U, _, Vt = np.linalg.svd(src_c.T @ dst_c)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst_mean - R @ src_mean)


@mistake("fit_rigid", "none", "I computed t from R before the reflection fix and did not "
         "recompute it after fixing R", names=r"before the (reflection|fix)|recompute")
def fit_translation_before_fix(src, dst):
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    _check_points(src, dst)
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - src_mean, dst - dst_mean
    _check_spread(src_c)
    U, _, Vt = np.linalg.svd(src_c.T @ dst_c)
    R = Vt.T @ U.T
    t = dst_mean - R @ src_mean
    if np.linalg.det(R) < 0:
        R = Vt.T @ np.diag([1.0, 1.0, -1.0]) @ U.T
    return _pose(R, t)


# --------------------------------------------------------------------------- per_point_residuals


@mistake("per_point_residuals", "none", "I took the norm over axis=0, down the points, "
         "instead of axis=1, across x, y, z", names=r"\baxis\b")
def residuals_norm_axis0(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    return np.linalg.norm(src @ R.T + t - dst, axis=0)


@mistake("per_point_residuals", "none", "I rotated the src points but forgot to add the "
         "translation", names=r"(forgot|without|no).{0,20}translation|\+ t\b")
def residuals_no_translation(dst_T_src, src, dst):
    R = dst_T_src[:3, :3]
    return np.linalg.norm(src @ R.T - dst, axis=1)


@mistake("per_point_residuals", "absolute for squared", "I summed the absolute x, y, z "
         "differences (an L1 norm) instead of the Euclidean distance")
def residuals_l1_norm(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    return np.abs(src @ R.T + t - dst).sum(axis=1)


@mistake("per_point_residuals", "none", "I divided each distance by the number of points, "
         "as if averaging", names=r"divid|number of points|mean")
def residuals_divided_by_n(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    return np.linalg.norm(src @ R.T + t - dst, axis=1) / len(src)


@mistake("per_point_residuals", "units m/mm", "I divided by 1000 to get metres, but the "
         "points were in metres already")
def residuals_divided_by_1000(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    return np.linalg.norm(src @ R.T + t - dst, axis=1) / 1000.0


# --------------------------------------------------------------------------- per_axis_rmse


@mistake("per_axis_rmse", "none", "I used np.std per axis, which subtracts the mean "
         "residual first: that is not the RMS", names=r"std|standard deviation|mean residual")
def rmse_std(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    along_src = (src @ R.T + t - dst) @ R
    return np.std(along_src, axis=0)


@mistake("per_axis_rmse", "none", "I took the median of the squared residuals instead of "
         "their mean", names=r"median")
def rmse_median(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    along_src = (src @ R.T + t - dst) @ R
    return np.sqrt(np.median(along_src ** 2, axis=0))


@mistake("per_axis_rmse", "none", "I divided the sum of squares by N - 1, as for a sample "
         "variance, instead of by N", names=r"N\s*-\s*1|n\s*-\s*1|ddof|Bessel")
def rmse_n_minus_one(dst_T_src, src, dst):
    R, t = dst_T_src[:3, :3], dst_T_src[:3, 3]
    along_src = (src @ R.T + t - dst) @ R
    return np.sqrt(np.sum(along_src ** 2, axis=0) / (len(src) - 1))
