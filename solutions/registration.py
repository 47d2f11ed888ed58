"""Rigid registration of point sets, the three-point frame, and flange calibration.

Everything here is the same small problem: find the rigid motion ``dst_T_src`` (rotation R,
translation t, no scale) that maps points measured in one frame onto the same physical points
measured in another, ``dst_i ~= R @ src_i + t``, in the least-squares sense.

The closed form is Arun, Huang & Blostein (1987) / Kabsch (1976) / Umeyama (1991) without the
scale: centre both point sets, take the SVD of their cross-covariance, and build R from the
singular vectors, flipping the last one when the plain product would be a reflection (det -1).
That flip is what makes the answer correct for planar or noisy point sets, where the naive
``V @ U.T`` can come out as a mirror image.

Relation to OpenCV: ``cv2.estimateAffine3D(src, dst)`` fits a general 3x4 *affine* map (12
unknowns, RANSAC), which is not a rotation and absorbs noise as shear and scale. The overload
``cv2.estimateAffine3D(src, dst, force_rotation=True) -> (M, scale)`` is Umeyama's similarity:
its rotation ``M[:, :3]`` is the same as ours (a scale does not change the SVD), but its
translation ``M[:, 3]`` goes with the fitted scale, so it differs from the rigid one unless the
scale comes out exactly 1. ``fit_rigid`` is the rigid (scale = 1) case, and its ``robust`` mode
plays the part of RANSAC's inlier selection.

Conventions (see the project's DESIGN notes): points are (N, 3) float arrays in metres; a pose
is a (4, 4) float64 array and ``a_T_b`` maps b-coordinates to a-coordinates. Residuals are
"predicted minus measured" in the dst frame: ``r_i = dst_T_src @ src_i - dst_i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from robots import geometry as geo
from solutions import diagnostics, units

__all__ = [
    "COLLINEAR_TOL",
    "MAX_ROTATION_STD_DEG",
    "OUTLIER_K",
    "RigidFit",
    "calibrate_flange",
    "calibrate_flange_report",
    "calibrate_flange_with_offset",
    "fit_rigid",
    "fit_rigid_report",
    "frame_from_three_points",
    "per_axis_rmse",
    "residuals",
]

#: A point set counts as (nearly) collinear when the second singular value of its centred
#: coordinates is below this fraction of the first: its width across the best-fit line is
#: then under 0.1 % of its length, and the rotation about that line is not determined.
COLLINEAR_TOL = 1e-3

#: A fit is refused when the rotation it found is this uncertain (degrees, one standard
#: deviation about the worst-determined axis, from the noise its own residuals show): points
#: spread over little more than their noise leave the rotation to the noise.
MAX_ROTATION_STD_DEG = 5.0

#: Rigid motions preserve distances: when the best scaled fit (Umeyama's similarity) has a
#: scale beyond this factor and explains the points far better (25 x smaller squared residual)
#: than the rigid fit, the sets are in different units.
SCALE_MISMATCH = 1.2

#: Point sets spread over more than this (m) are not a lab's: probably millimetres.
MAX_PLAUSIBLE_SPREAD_M = 50.0

#: Robust mode flags a point when its residual exceeds OUTLIER_K robust scales (see
#: fit_rigid_report): a gross-error threshold, about 6 sigma for noise along one axis.
OUTLIER_K = 6.0

# The robust scale is 1.4826 * median(|r|): for normally distributed errors along one axis
# (depth noise of an RGB-D camera) this is the standard deviation.
_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class RigidFit:
    """A rigid fit and its diagnostics.

    ``residuals`` (N, 3) and ``residual_norms`` (N,) cover every input point, including
    outliers and zero-weight points, as ``dst_T_src @ src_i - dst_i`` in the dst frame (m).
    ``rms`` and the per-axis RMSEs are over the points the fit used (``inlier_mask``: positive
    weight and not flagged), unweighted, in metres; ``per_axis_rmse`` is along the dst axes,
    ``per_axis_rmse_src`` along the src axes (for a flange calibration: the camera axes,
    where a depth camera's error lives on z). ``src_spread`` (3,) is the RMS spread of the
    source points used along their principal axes (m, descending): a small second value means
    nearly collinear points, a small third value a (harmless) planar set.
    """

    dst_T_src: np.ndarray
    residuals: np.ndarray
    residual_norms: np.ndarray
    rms: float
    per_axis_rmse: np.ndarray
    per_axis_rmse_src: np.ndarray
    outlier_indices: tuple[int, ...]
    inlier_mask: np.ndarray
    src_spread: np.ndarray


# --------------------------------------------------------------------------- validation


def _as_points(points, name: str) -> np.ndarray:
    p = diagnostics.as_array(points, name, "an (N, 3) array of points in metres")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) (metres), got {p.shape}")
    bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
    if bad.size:
        raise ValueError(
            f"{name}[{bad[0]}] contains NaN or inf ({bad.size} bad row(s) in all); drop the "
            "failed measurements from both point sets before fitting"
        )
    return p


def _as_pair(src, dst, src_name: str, dst_name: str) -> tuple[np.ndarray, np.ndarray]:
    src, dst = _as_points(src, src_name), _as_points(dst, dst_name)
    if len(src) != len(dst):
        raise ValueError(
            f"{src_name} has {len(src)} points but {dst_name} has {len(dst)}; they must be the "
            "same physical points in the same order"
        )
    return src, dst


def _as_weights(weights, n: int) -> np.ndarray:
    if weights is None:
        return np.ones(n)
    w = diagnostics.as_array(weights, "weights", f"({n},) non-negative weights, one per point")
    if w.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), one per point, got {w.shape}")
    bad = np.flatnonzero(~np.isfinite(w) | (w < 0))
    if bad.size:
        raise ValueError(f"weights[{bad[0]}] = {w[bad[0]]}: weights must be finite and >= 0")
    return w


def _check_spread(centred: np.ndarray, name: str) -> np.ndarray:
    """RMS spread of centred (weighted) points along their principal axes (the singular values
    of the sqrt(w)-scaled centred coordinates, m); raise if they are (nearly) collinear."""
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] <= 0.0 or sv[1] < COLLINEAR_TOL * sv[0]:
        ratio = 0.0 if sv[0] <= 0.0 else sv[1] / sv[0]
        raise ValueError(
            f"{name} are (nearly) collinear: singular values (RMS spread along the principal "
            f"axes) {np.array2string(sv, precision=3)} m, ratio s2/s1 = {ratio:.2e} < "
            f"{COLLINEAR_TOL:g}; the rotation about their common line cannot be determined. "
            "Use points that span a plane or a volume (at least 3 not on one line)"
        )
    return sv


# --------------------------------------------------------------------------- the fit


def _kabsch(src, dst, w, src_name="src", dst_name="dst") -> tuple[np.ndarray, np.ndarray]:
    """Weighted rigid fit of dst ~= R src + t over the points with w > 0. Returns (T, sv)."""
    used = w > 0
    if used.sum() < 3:
        raise ValueError(
            f"a rigid fit needs at least 3 points with positive weight, got {int(used.sum())}; "
            "measure more points"
        )
    src, dst, w = src[used], dst[used], w[used]
    w = w / w.sum()
    src_mean, dst_mean = w @ src, w @ dst
    # sqrt(w) scaling makes the SVD of the centred sets the weighted spread.
    src_c = (src - src_mean) * np.sqrt(w)[:, None]
    dst_c = (dst - dst_mean) * np.sqrt(w)[:, None]
    sv = _check_spread(src_c, src_name)
    _check_spread(dst_c, dst_name)
    H = src_c.T @ dst_c  # cross-covariance, src axes x dst axes
    U, _, Vt = np.linalg.svd(H)
    # Flip the least significant direction if V U^T would be a reflection: this gives the
    # best *proper* rotation (Umeyama 1991), not merely a re-signed wrong one.
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = dst_mean - R @ src_mean
    return T, sv


def _deletion_test(src, dst, w, fit_mask, k, threshold_m, extent, names):
    """Test the worst-fitting point against a fit made without it.

    Returns the index of the point to flag, or ``None`` when it passes. Judging a
    point by a fit that excludes it (a deletion residual) avoids masking: an outlier pulls a
    fit that includes it towards itself and spreads its error over the other points.
    """
    T, _ = _kabsch(src, dst, np.where(fit_mask, w, 0.0), *names)
    norms = np.linalg.norm(geo.transform_points(T, src) - dst, axis=1)
    candidate = int(np.flatnonzero(fit_mask)[np.argmax(norms[fit_mask])])
    others = fit_mask.copy()
    others[candidate] = False
    T_without, _ = _kabsch(src, dst, np.where(others, w, 0.0), *names)
    norms = np.linalg.norm(geo.transform_points(T_without, src) - dst, axis=1)
    if threshold_m is not None:
        return candidate if norms[candidate] > threshold_m else None
    scale = _MAD_TO_SIGMA * np.median(norms[others])
    # Exact data leaves residuals of rounding size; never call rounding an outlier.
    scale = max(scale, 1e-9 * extent)
    return candidate if norms[candidate] > k * scale else None


def fit_rigid_report(src, dst, weights=None, robust: bool = False, *, k: float = OUTLIER_K,
                     threshold_m: float | None = None, src_name: str = "src",
                     dst_name: str = "dst") -> RigidFit:
    """Rigid fit ``dst ~= dst_T_src @ src`` with residuals, RMSE and (optionally) outliers.

    Parameters
    ----------
    src, dst : (N, 3) the same N physical points measured in the src and dst frames (m).
    weights : (N,) non-negative, optional. The fit minimises sum_i w_i |R src_i + t - dst_i|^2;
        a zero weight is the same as leaving the point out.
    robust : if True, flag outliers one at a time, worst first: refit without the point that
        fits worst and flag it if its residual against that fit exceeds ``k`` robust scales,
        where scale = 1.4826 * median residual norm of the remaining points. Repeat until the
        worst remaining point passes. The scale equals the noise standard deviation when the
        error lies along one axis (an RGB-D camera's depth) and is about 2.3 sigma for
        isotropic 3D noise, so ``k`` = 6 only catches gross errors: on the real Aubo capture
        it flags the 12 mm point, not the next-worst one at 7.6 mm (5.4 scales).
    k : outlier threshold in robust scales (default ``OUTLIER_K`` = 6).
    threshold_m : an absolute outlier threshold in metres instead of ``k`` (like the RANSAC
        threshold of ``cv2.estimateAffine3D``), for when the sensor noise is known.
    src_name, dst_name : names used in error messages.

    Raises ``ValueError`` for complex values, mismatched shapes, NaN/inf, fewer than 3
    points, (nearly) collinear points (the message gives the singular values), points spread
    over too little against the noise the fit leaves (the rotation uncertain by more than
    ``MAX_ROTATION_STD_DEG``), and in robust mode for fewer than 5 points or when more than
    half of the points would be flagged. Warns (``UserWarning``, naming the likely cause) when
    a scaled fit explains the points far better than a rigid one (millimetres passed as
    metres) or a mirror image far better than any rotation (a flipped axis).
    """
    src, dst = _as_pair(src, dst, src_name, dst_name)
    n = len(src)
    if n < 3:
        raise ValueError(
            f"a rigid fit needs at least 3 non-collinear points, got {n}; measure more points"
        )
    w = _as_weights(weights, n)
    used = w > 0
    fit_mask = used.copy()
    if diagnostics.check_flag(robust, "robust"):
        threshold_m = diagnostics.check_number(threshold_m, "threshold_m", above=0.0,
                                               unit="metres", allow_none=True)
        k = diagnostics.check_number(k, "k", above=0.0, unit="robust scales")
        n_used = int(used.sum())
        if n_used < 5:
            raise ValueError(
                f"robust mode needs at least 5 weighted points to tell an outlier from the fit, "
                f"got {n_used}; measure more points or use robust=False"
            )
        extent = float(np.ptp(dst[used], axis=0).max())
        while (flag := _deletion_test(src, dst, w, fit_mask, k, threshold_m, extent,
                                      (src_name, dst_name))) is not None:
            fit_mask[flag] = False
            if 2 * fit_mask.sum() < n_used or fit_mask.sum() < 4:
                raise ValueError(
                    f"robust fit would flag more than half of the {n_used} points as outliers: "
                    "there is no consistent majority. Check that src and dst list the same "
                    "points in the same order and units"
                )
    T, sv = _kabsch(src, dst, np.where(fit_mask, w, 0.0), src_name, dst_name)
    r = geo.transform_points(T, src) - dst
    norms = np.linalg.norm(r, axis=1)
    _check_fit_is_meaningful(src, dst, np.where(fit_mask, w, 0.0), norms, src_name, dst_name)
    r_in = r[fit_mask]
    r_in_src = r_in @ T[:3, :3]  # R^T r: the same residual vectors along the src axes
    return RigidFit(
        dst_T_src=T,
        residuals=r,
        residual_norms=norms,
        rms=float(np.sqrt(np.mean(norms[fit_mask] ** 2))),
        per_axis_rmse=np.sqrt(np.mean(r_in**2, axis=0)),
        per_axis_rmse_src=np.sqrt(np.mean(r_in_src**2, axis=0)),
        outlier_indices=tuple(int(i) for i in np.flatnonzero(used & ~fit_mask)),
        inlier_mask=fit_mask,
        src_spread=sv,
    )


def _check_fit_is_meaningful(src, dst, w, norms, src_name, dst_name) -> None:
    """Refuse a fit whose rotation is left to the noise; warn when the data look like a mirror
    image or mixed units. Judged from the data themselves (their spreads and the residuals the
    fit leaves), so it holds at any scale.

    For isotropic noise sigma per axis the rotation's information matrix is
    ``sum_i w_i [p_i]x^T [p_i]x`` (p_i the centred source points): with the RMS spreads
    s1 >= s2 >= s3 along the principal axes and N points, the worst-determined rotation (about
    the long axis) has standard deviation ``sigma / sqrt(N (s2^2 + s3^2))`` rad.
    """
    used = w > 0
    n = int(used.sum())
    wn = w[used] / w[used].sum()
    src_c = src[used] - wn @ src[used]
    dst_c = dst[used] - wn @ dst[used]
    s_src = np.linalg.svd(src_c * np.sqrt(wn)[:, None], compute_uv=False)
    spread_src = float(np.sqrt(np.sum(s_src**2)))
    spread_dst = float(np.sqrt(wn @ np.sum(dst_c**2, axis=1)))
    # Per-axis noise from the weighted residuals, 3n observations less the 6 fitted parameters.
    sse = float(wn @ norms[used] ** 2) * n
    sigma = np.sqrt(sse / max(3 * n - 6, 1))
    # Mixed units: a rigid motion keeps distances, so when a scaled fit (Umeyama's similarity)
    # explains the points far better than the rigid one, the sets differ by that scale.
    H = (src_c * wn[:, None]).T @ dst_c
    U, sh, Vt = np.linalg.svd(H)
    mirrored = np.linalg.det(Vt.T @ U.T) < 0
    trace_rh = sh[0] + sh[1] - sh[2] if mirrored else float(np.sum(sh))
    var_src, var_dst = spread_src**2, spread_dst**2
    sse_rigid = float(wn @ norms[used] ** 2)
    scale = trace_rh / max(var_src, 1e-300)
    sse_scaled = max(var_dst - trace_rh**2 / max(var_src, 1e-300), 0.0)
    if (not SCALE_MISMATCH ** -1 < scale < SCALE_MISMATCH
            and sse_rigid > 25.0 * max(sse_scaled, 1e-30 * var_dst)):
        named = units.describe_scale(scale if scale > 1 else 1.0 / max(scale, 1e-300))
        if named is not None:
            big, small = (dst_name, src_name) if scale > 1 else (src_name, dst_name)
            cause = f"{big} look like {named[0]} and {small} like metres"
        else:
            cause = ("they are in different units, or are not the same points in the same "
                     "order")
        geo.warn_caller(
            f"{dst_name} match {src_name} scaled by {scale:.4g} (RMS spread {spread_dst:.4g} vs "
            f"{spread_src:.4g}), but a rigid motion keeps distances: {cause}. Convert both to "
            f"metres (divide millimetres by 1000, centimetres by 100); the rigid fit leaves "
            f"{np.sqrt(sse_rigid):.4g} RMS in the units given")
        return  # the residual is the unit error, not noise: no noise-based test below
    if min(spread_src, spread_dst) > MAX_PLAUSIBLE_SPREAD_M:
        geo.warn_caller(
            f"{src_name} and {dst_name} spread over {spread_src:.4g} m (RMS): far larger than a "
            "workcell. They look like millimetres: divide them by 1000 (cobotlab works in metres)")
    # Mirror image: the plain SVD product V U^T is a reflection that fits far better than the
    # best proper rotation (for planar or noisy sets the two fit about equally well, harmless).
    if mirrored:
        sse_proper = sse_rigid
        sse_mirror = max(sse_proper - 4.0 * sh[2], 0.0)
        if sse_proper > 25.0 * max(sse_mirror, 1e-30) and sse_proper > 1e-18 * spread_src**2:
            geo.warn_caller(
                f"{src_name} and {dst_name} fit a mirror image far better than any rotation "
                f"(RMS residual {np.sqrt(sse_mirror) * 1000:.3g} mm as a reflection, "
                f"{np.sqrt(sse_proper) * 1000:.3g} mm as the best rotation, det -1): one set is in "
                "a left-handed frame or has one axis flipped (e.g. image y up instead of down, "
                "depth negated, or x and y swapped). Fix the sign or order of that axis")
            return  # the residual is the mirror, not noise
    rot_std_deg = np.degrees(sigma / np.sqrt(n * (s_src[1] ** 2 + s_src[2] ** 2)))
    if rot_std_deg > MAX_ROTATION_STD_DEG:
        raise ValueError(
            f"{src_name} spread over too little against their noise: RMS spread "
            f"{np.array2string(s_src * 1000, precision=3)} mm along the principal axes, but the "
            f"fit leaves {sigma * 1000:.3g} mm of noise per axis, so its rotation is uncertain "
            f"by about {rot_std_deg:.0f} deg (limit {MAX_ROTATION_STD_DEG:g} deg). Spread the "
            f"points over many times the noise (e.g. 10 cm or more in at least two directions), "
            f"or measure them more precisely; check also that {src_name} and {dst_name} are "
            "the same points in the same units"
        )


def fit_rigid(src, dst, weights=None, robust: bool = False, **options) -> np.ndarray:
    """Least-squares rigid motion ``dst_T_src`` (4, 4) with ``dst_i ~= dst_T_src @ src_i``.

    ``src`` and ``dst`` are (N, 3) arrays of the same physical points in two frames (m);
    rotation and translation only, no scale (Arun/Kabsch/Umeyama; the SVD sign fix makes the
    rotation proper even for planar sets). ``weights`` (N,) are non-negative per-point weights.
    With ``robust=True`` outliers are flagged and left out (see ``fit_rigid_report``, which
    also returns them by index; ``options`` are passed on to it).

    This is what ``cv2.estimateAffine3D`` would give if it were restricted to rotations and
    translations. Raises ``ValueError`` for fewer than 3 points, NaN, mismatched shapes,
    (nearly) collinear points or points spread over little more than their noise; warns for
    mixed units and mirror images (see ``fit_rigid_report``).
    """
    return fit_rigid_report(src, dst, weights, robust, **options).dst_T_src


# --------------------------------------------------------------------------- residual metrics


def _frame_rotation(expressed_in, dst_T_src: np.ndarray) -> np.ndarray | None:
    """Rotation dst_R_frame for residuals expressed in another frame (None: the dst frame)."""
    if expressed_in is None or (isinstance(expressed_in, str) and expressed_in == "dst"):
        return None
    if isinstance(expressed_in, str):
        if expressed_in == "src":
            return dst_T_src[:3, :3]
        raise ValueError(f"expressed_in must be 'dst', 'src' or a pose, got {expressed_in!r}")
    M = diagnostics.as_array(expressed_in, "expressed_in",
                             "'dst', 'src', a (4, 4) pose or a (3, 3) rotation")
    if M.shape == (4, 4):
        return geo.as_pose(M, "expressed_in")[:3, :3]
    return geo.as_rotation(M, "expressed_in")


def residuals(dst_T_src, src, dst, expressed_in=None) -> np.ndarray:
    """Per-point residuals ``dst_T_src @ src_i - dst_i``, shape (N, 3), metres.

    The vectors are along the dst axes by default. ``expressed_in`` gives them along other
    axes: ``"src"`` (for ``base_T_cam`` this is the camera frame), or a pose ``dst_T_frame``
    (4, 4) / rotation (3, 3) whose axes to use. Only the direction changes, not the length.
    """
    T = geo.as_pose(dst_T_src, "dst_T_src")
    src, dst = _as_pair(src, dst, "src", "dst")
    r = geo.transform_points(T, src) - dst
    R = _frame_rotation(expressed_in, T)
    return r if R is None else r @ R


def per_axis_rmse(dst_T_src, src, dst, expressed_in=None) -> np.ndarray:
    """Root-mean-square residual along each axis, shape (3,), metres.

    Axes of the dst frame by default; ``expressed_in`` as in ``residuals`` (``"src"`` gives
    the camera axes for a ``base_T_cam`` fit, where an RGB-D camera's depth error is on z).
    """
    r = residuals(dst_T_src, src, dst, expressed_in)
    if len(r) == 0:
        raise ValueError("per_axis_rmse needs at least one point")
    return np.sqrt(np.mean(r**2, axis=0))


# --------------------------------------------------------------------------- three-point frame


def frame_from_three_points(p_origin, p_x, p_xy, *, min_distance_m: float = 1e-6,
                            min_angle_deg: float = 1.0) -> np.ndarray:
    """The frame defined by an origin, a point on its +x axis and a point in its x-y plane.

    All three points are given in a parent frame (m); the result is ``parent_T_frame``:
    origin at ``p_origin``, x along ``p_x - p_origin``, z = x cross (p_xy - p_origin)
    normalised (so ``p_xy`` lies on the +y side), y = z cross x. The frame is right-handed
    and orthonormal; ``p_xy`` need not be exactly perpendicular to the x edge.

    Typical use: three corners of a board measured by a robot's pointer tip give
    ``base_T_world`` in one shot.

    Raises ``ValueError`` if ``p_x`` or ``p_xy`` is within ``min_distance_m`` of the origin
    (coincident points) or if the two edges are within ``min_angle_deg`` of being parallel
    (collinear points: the x-y plane is undetermined); the message gives the distance or
    angle.
    """
    min_distance_m = diagnostics.check_number(min_distance_m, "min_distance_m", minimum=0.0,
                                              unit="metres")
    min_angle_deg = diagnostics.check_number(min_angle_deg, "min_angle_deg", minimum=0.0,
                                             unit="degrees")
    points = []
    for name, p in (("p_origin", p_origin), ("p_x", p_x), ("p_xy", p_xy)):
        a = diagnostics.as_array(p, name, "a 3-vector (m)")
        if a.shape != (3,):
            raise ValueError(f"{name} must be a 3-vector (m), got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{name} contains NaN or inf: {a}")
        points.append(a)
    o, px, pxy = points
    edge_x, edge_xy = px - o, pxy - o
    for name, edge in (("p_x", edge_x), ("p_xy", edge_xy)):
        dist = np.linalg.norm(edge)
        if dist < min_distance_m:
            raise ValueError(
                f"{name} coincides with p_origin (distance {dist:.3g} m < {min_distance_m:g} m); "
                "measure three distinct points, well apart"
            )
    x = edge_x / np.linalg.norm(edge_x)
    z = np.cross(x, edge_xy / np.linalg.norm(edge_xy))
    # |x cross u| = sin(angle); atan2 keeps precision for angles near 0 and 180 degrees.
    angle = np.degrees(np.arctan2(np.linalg.norm(z), np.dot(x, edge_xy) / np.linalg.norm(edge_xy)))
    if min(angle, 180.0 - angle) < min_angle_deg:
        raise ValueError(
            f"the three points are (nearly) collinear: the angle between origin->p_x and "
            f"origin->p_xy is {angle:.3g} deg (needs at least {min_angle_deg:g} deg away from "
            "0 and 180); pick p_xy well off the x axis, ideally near the +y axis"
        )
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = o
    return T


# --------------------------------------------------------------------------- flange calibration


_FLANGE_MIN_POINTS = 4


def calibrate_flange_report(cam_points, base_points, robust: bool = False, **options) -> RigidFit:
    """``calibrate_flange`` with its diagnostics: a ``RigidFit`` with dst = base, src = cam.

    ``residuals`` / ``residual_norms`` are per pose (base frame, m), ``per_axis_rmse_src`` is
    the RMSE along the camera axes, ``outlier_indices`` the poses flagged in robust mode.
    """
    cam, base = _as_pair(cam_points, base_points, "cam_points", "base_points")
    robust = diagnostics.check_flag(robust, "robust")
    n = len(cam)
    if n < _FLANGE_MIN_POINTS:
        raise ValueError(
            f"flange calibration needs at least {_FLANGE_MIN_POINTS} poses, got {n}: 3 "
            "non-collinear points fix base_T_cam exactly but leave no redundancy, so a bad "
            "measurement cannot show up in the residuals. Use 10 or more poses spread over "
            "the camera's view in all three directions"
        )
    try:
        return fit_rigid_report(cam, base, robust=robust, src_name="cam_points",
                                dst_name="base_points", **options)
    except ValueError as err:
        if "collinear" not in str(err):
            raise
        raise ValueError(
            f"{err}. For a flange calibration this means the flange positions lie on one line "
            "(e.g. the robot moved along a single axis): the camera's rotation about that line "
            "is unobservable. Move the flange to positions that span a plane or, better, a volume"
        ) from None


def calibrate_flange(cam_points, base_points, robust: bool = False, **options) -> np.ndarray:
    """Eye-on-base (eye-to-hand) calibration from a marker on the flange centre: ``base_T_cam``.

    A camera fixed in the workcell sees a marker (e.g. a small checkerboard) whose centre is
    the flange centre (the tool0 origin). At each of n >= 4 robot positions:

    * ``cam_points[i]`` (n, 3): the marker centre in the camera's optical frame (m), e.g.
      from the aligned depth image of an RGB-D camera;
    * ``base_points[i]`` (n, 3): the tool0 position in the robot base frame (m), from the
      controller (the translation of ``base_T_flange``).

    Then ``base_points[i] = base_T_cam @ cam_points[i]``, a rigid fit with src = cam and
    dst = base. The flange orientation does not enter, which is why the marker must sit on
    the flange centre; if it does not, use ``calibrate_flange_with_offset``. ``robust=True``
    leaves out outlier poses (``calibrate_flange_report`` names them; ``options`` as in
    ``fit_rigid_report``).

    Unlike OpenCV's ``calibrateHandEye`` this needs no target orientation, only positions,
    and no inversion: the poses go in as the controller reports them (base_T_flange).
    """
    return calibrate_flange_report(cam_points, base_points, robust, **options).dst_T_src


def _orientation_spread_deg(rotations: np.ndarray) -> np.ndarray:
    """How well varied orientations reveal a point fixed in the flange, per direction (deg).

    After eliminating the translation, the offset p enters through (R_i - R_mean) p; the
    singular values of that stack over sqrt(n) are about the RMS rotation (rad) about the
    least and most observed directions. Returned ascending, in degrees.
    """
    d = rotations - rotations.mean(axis=0)
    sv = np.linalg.svd(d.reshape(-1, 3), compute_uv=False) / np.sqrt(len(rotations))
    return np.degrees(np.sort(sv))


def calibrate_flange_with_offset(cam_points, base_T_flange, *, min_spread_deg: float = 1.0,
                                 ) -> tuple[np.ndarray, np.ndarray]:
    """Flange calibration that also finds the marker's offset from the flange centre.

    Inputs: ``cam_points`` (n, 3), the marker centre in the camera frame (m), and
    ``base_T_flange`` (n, 4, 4), the full flange poses from the controller. Unknowns:
    ``base_T_cam`` = (R_C, t_C) and ``flange_p_marker`` p (the marker centre in the flange
    frame, m). Each pose gives three equations

        R_F_i @ p + t_F_i = R_C @ c_i + t_C        (the marker centre in the base frame)

    solved by nonlinear least squares over (R_C as a rotation vector, t_C, p), started from the
    zero-offset fit ``calibrate_flange(cam_points, t_F)``. Returns ``(base_T_cam,
    flange_p_marker)``.

    The offset is only visible through orientation changes: with one fixed orientation R_F,
    R_F p + t_F = R_C c + t_C can be rewritten with p = 0 and t_C - R_F p, so the offset merges
    into the result's translation. Likewise, rotating only about one axis hides the offset
    along that axis. ``ValueError`` is raised when the RMS orientation change about the least
    varied direction is below ``min_spread_deg`` (and for n < 4, NaN, non-rotations,
    mismatched lengths, collinear positions).
    """
    cam = _as_points(cam_points, "cam_points")
    poses = geo.as_poses(base_T_flange, "base_T_flange")
    min_spread_deg = diagnostics.check_number(min_spread_deg, "min_spread_deg", minimum=0.0,
                                              unit="degrees")
    if len(poses) != len(cam):
        raise ValueError(
            f"cam_points has {len(cam)} points but base_T_flange has {len(poses)} poses; give "
            "one flange pose per marker measurement"
        )
    R_F, t_F = poses[:, :3, :3], poses[:, :3, 3]
    spread = _orientation_spread_deg(R_F)
    if spread[0] < min_spread_deg:
        if spread[-1] < min_spread_deg:
            why = (f"all flange orientations are the same (RMS change {spread[-1]:.3g} deg). "
                   "A fixed orientation cannot separate the marker offset from the translation "
                   "of the result: R_F p + t_F = R_C c + t_C holds for any p once t_C absorbs "
                   "R_F p")
        else:
            why = (f"the flange orientations vary about one axis only (RMS change "
                   f"{spread[0]:.3g} deg about the least varied direction, {spread[-1]:.3g} deg "
                   "about the most): the offset along that axis merges into the translation "
                   "of the result")
        raise ValueError(
            f"marker offset is unobservable: {why}. Add orientation changes of at least "
            f"{min_spread_deg:g} deg (ideally 10-30 deg) about two or more different axes, or, "
            "if the marker really is on the flange centre, use calibrate_flange"
        )
    # The zero-offset start; it warns about mixed units and mirror images (its base_points
    # are the translations of base_T_flange).
    start = calibrate_flange(cam, t_F)
    R0 = start[:3, :3]

    def residual(x):
        # Rotation as a small correction on the start: R_C = exp(x[:3]) R0, away from the
        # rotation vector's singularity at 180 degrees.
        R_C = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        t_C, p = x[3:6], x[6:9]
        marker_base = np.einsum("nij,j->ni", R_F, p) + t_F
        return (cam @ R_C.T + t_C - marker_base).ravel()

    x0 = np.concatenate([np.zeros(3), start[:3, 3], np.zeros(3)])
    sol = least_squares(residual, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    if not np.all(np.isfinite(sol.x)):
        raise ValueError("the offset fit diverged; check that cam_points and base_T_flange match")
    base_T_cam = geo.make_pose(
        geo.project_to_so3(Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R0), sol.x[3:6]
    )
    return base_T_cam, sol.x[6:9].copy()
