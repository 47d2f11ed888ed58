"""Reference visual servoing: PBVS, IBVS, the staged approach-to-grasp, pick-and-place.

Conventions
-----------
* A *twist* is a (6,) array ``(vx, vy, vz, wx, wy, wz)``: the linear velocity (m/s) of a frame's
  origin and its angular velocity (rad/s), both expressed in that frame (a body twist). A
  camera twist is in the camera optical frame; :func:`cam_twist_to_flange` moves it to the
  flange for an eye-in-hand camera through the calibration ``flange_T_cam``.
* Image features for IBVS are *normalised* coordinates ``x = X / Z, y = Y / Z`` (pixels with K
  and distortion removed, ``cv2.undistortPoints``), so the gain does not depend on the focal
  length.
* The control laws return a camera twist; a loop applies it for one control period ``dt``
  (s) with :func:`integrate_twist`. With gain ``lambda`` (1/s) the error shrinks by about
  ``1 - lambda dt`` per iteration.

Errors: a lost target, a target leaving the image and a growing error raise the
:class:`~robots.perception.ServoError` subclasses defined in :mod:`robots.perception` (so lab
code can catch them without this module); every robot loop here stops the robot first.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from robots.geometry import as_pose, as_real_array, compose, invert, make_pose, transform_points
from robots.perception import (
    NORMALISED_MAX,
    ServoDivergedError,
    ServoError,
    ServoTimeoutError,
    TargetLostError,
    TargetOutOfViewError,
    check_normalised,
)
from robots.safety import ANGULAR_SPEED_MAX, check_angular_speed
from solutions.units import UNIT_RATIO

__all__ = [
    "ConvergenceMonitor",
    "ServoDivergedError",
    "ServoError",
    "ServoResult",
    "ServoTimeoutError",
    "TargetLostError",
    "TargetOutOfViewError",
    "cam_twist_to_flange",
    "decoupled_velocity",
    "ibvs_velocity",
    "integrate_twist",
    "interaction_matrix",
    "normalised_projection",
    "pbvs_error",
    "pbvs_velocity",
    "saturate",
    "simulate_servo",
    "twist_transform",
]


# --------------------------------------------------------------------------- kinematics


def _points(points, dim: int, name: str, what: str) -> np.ndarray:
    """``points`` as a finite float64 (N, dim) array (a single (dim,) point is (1, dim));
    ValueError naming ``name``, the expected shape and what came. Nothing is reshaped: a
    flattened, transposed or (N, other) array is refused."""
    arr = as_real_array(points, name)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != dim:
        hint = ""
        if arr.ndim == 2 and arr.shape[0] == dim:
            hint = f"; transposed? pass {name}.T (shape {arr.shape[::-1]})"
        elif arr.ndim == 2 and dim == 2 and arr.shape[1] == 3:
            hint = ("; these look like camera-frame points (X, Y, Z): pass "
                    "normalised_projection(points) and their Z as depths")
        elif arr.ndim == 1 and arr.size % dim == 0:
            hint = f"; for a flat vector use {name}.reshape(-1, {dim}) if that is its layout"
        raise ValueError(f"{name} must have shape (N, {dim}) ({what}), got shape {arr.shape}"
                         f"{hint}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is not finite ({arr[bad[0]]}); drop that feature")
    return arr


def _finite_number(value, name: str, what: str) -> float:
    """A real, finite scalar as float; ValueError naming ``name`` otherwise."""
    if type(value) is float or type(value) is int:  # the common case, cheaply
        if math.isfinite(value):
            return float(value)
        raise ValueError(f"{name} must be a finite number ({what}), got {value}")
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be a finite number ({what}), got the string {value!r}")
    if isinstance(value, (bool, np.bool_)) or value is None:
        raise ValueError(f"{name} must be a finite number ({what}), got {value!r}")
    arr = as_real_array(value, name)
    if arr.shape != ():
        raise ValueError(f"{name} must be a single number ({what}), got shape {arr.shape}")
    value = float(arr)
    if not np.isfinite(value):
        raise ValueError(f"{name} must be a finite number ({what}), got {value}")
    return value


def _twist(twist, name: str) -> np.ndarray:
    """A finite (6,) twist; ValueError naming ``name`` otherwise."""
    arr = as_real_array(twist, name)
    if arr.shape not in ((6,), (6, 1)):
        raise ValueError(f"{name} must be a twist of 6 numbers (vx, vy, vz, wx, wy, wz), got "
                         f"shape {arr.shape}")
    arr = arr.reshape(6)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} is not finite ({arr}); a twist must be finite m/s and rad/s")
    return arr


def normalised_projection(points_cam) -> np.ndarray:
    """Normalised image coordinates (N, 2) ``(X / Z, Y / Z)`` of camera-frame points (N, 3).

    ``points_cam`` must be (N, 3) (or one (3,) point), metres, finite: a (3, N) array or an
    (N, 2) one is refused, not reshaped. A point with Z <= 0 raises TargetOutOfViewError.

    A (3, 3) array is the one shape where (N, 3) and a transposed (3, N) cannot be told apart
    by the shape. Rows are points here, always; the array is refused (``ValueError`` naming
    ``points_cam``, with the fix) whenever its columns read as three points in front of the
    camera (and differ from its rows): as rows too, the answer would rest on a guess; not as
    rows, it is transposed. Three points as rows whose columns put a point behind the camera
    (the usual case: X and Y of both signs about the optical axis) pass. Pass 4 or more
    points (IBVS needs 4 to avoid ambiguous poses anyway), or the three one by one as (3,).
    """
    pts = _points(points_cam, 3, "points_cam", "camera-frame points X, Y, Z in metres")
    if pts.shape == (3, 3):
        _refuse_ambiguous_square(pts)
    return _normalised_projection(pts)


def _refuse_ambiguous_square(pts: np.ndarray) -> None:
    """``ValueError`` when a (3, 3) ``points_cam`` reads as three points in front of the camera
    as columns, whether or not it does as rows (see ``normalised_projection``)."""
    rows_ok, columns_ok = bool(np.all(pts[:, 2] > 0)), bool(np.all(pts[2, :] > 0))
    if not columns_ok or np.array_equal(pts, pts.T):
        return  # only the rows reading can be meant (or both are the same)
    depths = f"(depths as rows {pts[:, 2].tolist()}, as columns {pts[2, :].tolist()})"
    if not rows_ok:
        raise ValueError(
            "points_cam has shape (3, 3) and read as rows (N, 3), as cobotlab expects, puts a "
            f"point behind the camera, while read as columns all three are in front {depths}: "
            "transposed? pass points_cam.T (shape (3, 3), one point per row)")
    raise ValueError(
        "points_cam has shape (3, 3): three points as rows (N, 3), as cobotlab expects, or "
        f"three points as columns (3, N)? Both readings put every point in front of the camera "
        f"{depths}, so the shape cannot tell. Give one point per row (if they are columns, "
        "transposed? pass points_cam.T) and project them one at a time "
        "(normalised_projection(p) for each (3,) point p), or add a fourth point")


def _normalised_projection(pts: np.ndarray) -> np.ndarray:
    """``normalised_projection`` of points already validated as (N, 3) rows (the loops here
    produce them with ``transform_points``, so the (3, 3) ambiguity cannot arise)."""
    if np.any(pts[:, 2] <= 0):
        k = int(np.flatnonzero(pts[:, 2] <= 0)[0])
        raise TargetOutOfViewError(f"points_cam[{k}] is behind the camera (z = {pts[k, 2]:.4g} "
                                   "<= 0)")
    return pts[:, :2] / pts[:, 2:3]


def interaction_matrix(points_xy, depths) -> np.ndarray:
    """The (2N, 6) interaction matrix L of N point features: ``d(x, y)/dt = L @ v_cam``.

    ``points_xy`` (N, 2) are normalised coordinates (not reshaped: camera-frame points (N, 3)
    are refused, give ``normalised_projection`` of them; pixels, beyond +-10, are refused
    naming K^-1), ``depths`` (N,) their depths Z (m, > 0; one number is used for every
    point), ``v_cam`` the camera's body twist. Per point (Chaumette & Hutchinson 2006)::

        [ -1/Z   0    x/Z   x y     -(1 + x^2)   y ]
        [  0    -1/Z  y/Z   1 + y^2  -x y        -x ]
    """
    xy = _points(points_xy, 2, "points_xy", "normalised image coordinates x = X/Z, y = Y/Z")
    return _interaction_matrix(check_normalised(xy, "points_xy"), depths, "points_xy", "depths")


def _interaction_matrix(points_xy, depths, xy_name: str, z_name: str) -> np.ndarray:
    xy = _points(points_xy, 2, xy_name, "normalised image coordinates x = X/Z, y = Y/Z")
    Z = as_real_array(depths, z_name)
    if Z.ndim > 1 or (Z.ndim == 1 and len(Z) not in (1, len(xy))):
        raise ValueError(f"{z_name} must be one depth per feature, shape ({len(xy)},), or one "
                         f"number for all, got shape {Z.shape}")
    Z = np.broadcast_to(Z.reshape(-1), (len(xy),))
    bad = np.flatnonzero(~(np.isfinite(Z) & (Z > 0)))
    if bad.size:
        raise ValueError(f"{z_name}[{bad[0]}] is {Z[bad[0]]}: depths must be positive finite "
                         "metres")
    _refuse_millimetre_depth(float(Z.max()), z_name)
    x, y = xy[:, 0], xy[:, 1]
    L = np.zeros((len(xy), 2, 6))
    L[:, 0] = np.column_stack([-1 / Z, 0 * Z, x / Z, x * y, -(1 + x * x), y])
    L[:, 1] = np.column_stack([0 * Z, -1 / Z, y / Z, 1 + y * y, -x * y, -x])
    return L.reshape(-1, 6)


#: IBVS refuses an interaction matrix whose smallest singular value is below this fraction of
#: its largest: exactly degenerate features (identical or collinear points) give ~1e-16,
#: while a legitimately small, distant target (1 cm at 2 m) is conditioned around 1e-5.
IBVS_RANK_TOL = 1e-8


def _degenerate_features(xy: np.ndarray, name: str) -> str:
    """Why the features ``xy`` (N, 2) give a rank-deficient interaction matrix, naming them."""
    n = len(xy)
    scale = max(float(np.abs(xy).max()), 1e-3)
    for i in range(n):
        same = [j for j in range(i + 1, n) if np.linalg.norm(xy[j] - xy[i]) <= 1e-9 * scale]
        if same:
            listed = ", ".join(f"{name}[{k}]" for k in [i, *same])
            return f"{listed} coincide (identical features: repeated points, or a target point "\
                   "listed twice)"
    centred = xy - xy.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-12):
        return (f"{name}[0..{n - 1}] are collinear (all {n} features on one image line: a "
                "target whose points lie on a line, or seen edge-on)")
    return (f"{name}[0..{n - 1}] are in a singular configuration (e.g. 3 points on the "
            "singular cylinder); use 4 or more non-collinear points")


def ibvs_velocity(s, s_star, depths, gain: float = 1.0, depths_star=None,
                  mode: str = "current") -> np.ndarray:
    """Camera twist ``v = -gain L^+ (s - s*)`` for point features (Chaumette & Hutchinson).

    ``s``, ``s_star``: (N, 2) current and desired normalised coordinates; ``depths`` (N,) the
    current depths (m; from the depth image or a pose estimate). ``mode``: "current" uses L at
    the current features, "desired" at the desired ones (needs ``depths_star``), "mean" the
    average of both (the best-behaved choice for large rotations). At least 3 points are
    needed for all 6 degrees of freedom (4 to avoid the ambiguous cases).

    Pixels where normalised coordinates belong (beyond +-10, see
    ``robots.perception.check_normalised``) raise ``ValueError`` naming ``s`` or ``s_star`` and
    the fix (K^-1). Never returns a non-finite twist: NaN or inf in any argument raises
    ``ValueError`` naming it, and so does a rank-deficient interaction matrix (smallest singular value below
    ``IBVS_RANK_TOL`` of the largest: identical or collinear features), naming the features.
    A negative gain is accepted (it drives the features away: the classic sign mistake, which
    the convergence monitor catches).
    """
    if mode not in ("current", "desired", "mean"):
        raise ValueError(f"mode must be 'current', 'desired' or 'mean', got {mode!r}")
    s = check_normalised(_points(s, 2, "s", "current normalised image coordinates"), "s")
    s_star = check_normalised(_points(s_star, 2, "s_star", "desired normalised image coordinates"),
                              "s_star")
    if s.shape != s_star.shape:
        raise ValueError(f"s has {len(s)} points but s_star {len(s_star)}; they must pair up")
    if len(s) < 3:
        raise ValueError(f"IBVS on 6 DOF needs at least 3 point features (4 is safer), got {len(s)}")
    gain = _finite_number(gain, "gain", "1/s")
    if mode == "current":
        L = _interaction_matrix(s, depths, "s", "depths")
        at = [("s", s)]
    else:
        if depths_star is None:
            raise ValueError(f"mode={mode!r} needs depths_star, the depths at the goal")
        L = _interaction_matrix(s_star, depths_star, "s_star", "depths_star")
        at = [("s_star", s_star)]
        if mode == "mean":
            L = 0.5 * (L + _interaction_matrix(s, depths, "s", "depths"))
            at.append(("s", s))
    U, sv, Vt = np.linalg.svd(L, full_matrices=False)
    if not sv[-1] > IBVS_RANK_TOL * sv[0]:
        reasons = [_degenerate_features(xy, name) for name, xy in at]
        raise ValueError(
            f"the interaction matrix is rank-deficient (singular values down to "
            f"{sv[-1]:.2g}, {sv[0]:.2g} at most), so the twist is not determined: "
            f"{'; '.join(dict.fromkeys(reasons))}")
    e = (s - s_star).reshape(-1)
    return -gain * (Vt.T @ ((U.T @ e) / sv))


def pbvs_error(cam_T_target, camd_T_target) -> np.ndarray:
    """PBVS error (6,): ``(t, theta u)`` of ``camd_T_cam``, the current camera in the desired one.

    ``cam_T_target`` is the measured target pose, ``camd_T_target`` where it should be seen
    from the goal. Metres and radians; zero exactly at the goal.
    """
    camd_T_cam = compose(as_pose(camd_T_target, "camd_T_target"),
                         invert(as_pose(cam_T_target, "cam_T_target")))
    return np.concatenate([camd_T_cam[:3, 3], Rotation.from_matrix(camd_T_cam[:3, :3]).as_rotvec()])


def pbvs_velocity(cam_T_target, camd_T_target, gain: float = 1.0) -> np.ndarray:
    """Camera twist of the PBVS law ``v = -gain R^T t, w = -gain theta u`` (with
    ``(R, t) = camd_T_cam``): the camera's origin heads straight for the goal and the distance
    to it shrinks exactly exponentially, the rotation error likewise.

    Both poses are validated (``as_pose``: NaN, inf, non-rotations raise ``ValueError`` naming
    them) and ``gain`` must be finite, so the twist is always finite."""
    gain = _finite_number(gain, "gain", "1/s")
    cam_T_target = as_pose(cam_T_target, "cam_T_target")
    camd_T_target = as_pose(camd_T_target, "camd_T_target")
    e = pbvs_error(cam_T_target, camd_T_target)
    camd_T_cam = compose(camd_T_target, invert(cam_T_target))
    return np.concatenate([-gain * camd_T_cam[:3, :3].T @ e[:3], -gain * e[3:]])


def decoupled_velocity(features, desired, depth: float, gain: float = 1.0) -> np.ndarray:
    """Camera twist of the decoupled law on ``(x, y, area, angle)`` for a camera looking
    roughly straight at a planar blob (a wrist camera above a part).

    ``features`` / ``desired``: ``(x, y, a, alpha)``: the blob centroid in normalised
    coordinates, its area in normalised units (pixels^2 / (fx fy)) and its orientation (rad;
    NaN for a round blob, which leaves the rotation about the optical axis alone). ``depth``
    is the blob's current depth Z (m).

    Areas in pixels^2 are refused (``ValueError`` naming the argument and the fix, divide by
    fx fy), by two rules: an area above ``(2 NORMALISED_MAX)^2`` = 400 does not fit in the
    widest image whose normalised coordinates stay within +-``NORMALISED_MAX`` (the bound
    ``check_normalised`` puts on x and y); and an area ratio whose implied goal depth
    ``Z* = Z sqrt(a / a*)`` is more than ``UNIT_RATIO`` (30) times nearer or farther than
    the current one is one area in pixels^2 and the other normalised (their ratio is fx fy,
    1e4-1e6), not a servo goal. Both areas in pixels^2 below 400 give the right twist, since
    only their ratio counts. Each feature drives one motion:
    ``vx = gain Z (x - x*)``, ``vy = gain Z (y - y*)``, ``vz = gain (Z - Z*) = gain Z (1 - sqrt(a/a*))``
    (the area goes as 1/Z^2, so ``Z* = Z sqrt(a / a*)``), ``wz = -gain (alpha - alpha*)``
    wrapped to (-pi/2, pi/2] (a blob's axis has no head). ``wx = wy = 0``.
    """
    f = as_real_array(features, "features")
    d = as_real_array(desired, "desired")
    for name, arr in (("features", f), ("desired", d)):
        if arr.shape != (4,):
            raise ValueError(f"{name} must be (x, y, area, angle), shape (4,), got shape "
                             f"{arr.shape}")
        if not np.all(np.isfinite(arr[:3])) or arr[2] <= 0 or np.isinf(arr[3]):
            raise ValueError(f"{name} {arr} needs finite x, y, a positive area and a finite "
                             "angle (NaN for a round blob)")
        if abs(arr[3]) > 2 * math.pi:  # NaN compares False: a round blob passes
            raise ValueError(
                f"{name}[3], the blob's orientation, is {arr[3]:g}: more than a full turn in "
                "radians, so it looks like degrees (cv2.fitEllipse and cv2.minAreaRect give "
                f"degrees). Pass radians: np.radians({arr[3]:g}) = {math.radians(arr[3]):.4g}")
        check_normalised(arr[:2], f"{name}[:2]")  # the centroid (x, y)
        if arr[2] > _MAX_NORMALISED_AREA:
            raise ValueError(
                f"{name}[2], the blob's area, is {arr[2]:.4g}: in normalised units (pixels^2 / "
                f"(fx fy)) no blob inside the image exceeds {_MAX_NORMALISED_AREA:g} (a square "
                f"+-{NORMALISED_MAX:g} wide), so this looks like pixels^2. Divide it by fx * fy "
                "(from K), as the centroid is normalised with K^-1")
    depth = _finite_number(depth, "depth", "metres")
    if not depth > 0:
        raise ValueError(f"depth must be positive finite metres, got {depth}")
    _refuse_millimetre_depth(depth, "depth")
    gain = _finite_number(gain, "gain", "1/s")
    depth_ratio = math.sqrt(f[2] / d[2])  # Z* / Z
    if not 1.0 / UNIT_RATIO <= depth_ratio <= UNIT_RATIO:
        big, small = ("features", "desired") if f[2] > d[2] else ("desired", "features")
        raise ValueError(
            f"features[2] = {f[2]:.4g} and desired[2] = {d[2]:.4g}, the blob's areas, put the "
            f"goal {depth_ratio:.4g} times as far as the current depth (Z* = Z sqrt(a / a*)), "
            f"beyond a factor {UNIT_RATIO:g}: {big}[2] looks like pixels^2 and {small}[2] "
            f"normalised. Give both areas in normalised units (pixels^2 / (fx fy))")
    v = np.zeros(6)
    v[0] = gain * depth * (f[0] - d[0])
    v[1] = gain * depth * (f[1] - d[1])
    v[2] = gain * depth * (1.0 - depth_ratio)
    if np.isfinite(f[3]) and np.isfinite(d[3]):
        da = (f[3] - d[3] + np.pi / 2) % np.pi - np.pi / 2
        v[5] = -gain * da
    return v


def saturate(twist, max_linear: float, max_angular: float) -> np.ndarray:
    """Scale the whole twist down (direction kept) so |v| <= max_linear (m/s) and
    |w| <= max_angular (rad/s).

    The limits must be numbers >= 0 (inf: no limit); a negative or NaN limit raises
    ``ValueError`` (a negative one would reverse the twist), as does a non-finite twist. A
    finite ``max_angular`` above a turn per second warns that it looks like deg/s
    (``robots.safety.check_angular_speed``)."""
    twist = _twist(twist, "twist")
    limits = []
    for name, limit in (("max_linear", max_linear), ("max_angular", max_angular)):
        if (type(limit) is float or type(limit) is int) and limit >= 0:  # cheaply
            limits.append(float(limit))
            continue
        if isinstance(limit, (bool, np.bool_)) or limit is None or isinstance(limit, (str, bytes)):
            raise ValueError(f"{name} must be a number >= 0, got {limit!r}")
        value = as_real_array(limit, name)
        if value.shape != () or not value >= 0:
            raise ValueError(f"{name} must be a single number >= 0 (inf for no limit), got "
                             f"{limit!r}")
        limits.append(float(value))
    max_linear, max_angular = limits
    check_angular_speed(max_angular, "max_angular")
    scale = 1.0
    nv, nw = np.linalg.norm(twist[:3]), np.linalg.norm(twist[3:])
    if nv > max_linear:
        scale = min(scale, max_linear / nv)
    if nw > max_angular:
        scale = min(scale, max_angular / nw)
    return twist * scale


def twist_transform(a_T_b) -> np.ndarray:
    """The (6, 6) adjoint mapping a body twist of frame b to the same rigid motion's twist of
    frame a, for a and b rigidly attached: ``w_a = R w_b``, ``v_a = R v_b + t x (R w_b)``."""
    T = as_pose(a_T_b, "a_T_b")
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    W = np.zeros((6, 6))
    W[:3, :3] = R
    W[:3, 3:] = tx @ R
    W[3:, 3:] = R
    return W


def cam_twist_to_flange(v_cam, flange_T_cam) -> np.ndarray:
    """The flange body twist that moves an eye-in-hand camera with body twist ``v_cam``.

    An angular speed above a turn per second raises ``ValueError`` (deg/s, as in
    :func:`integrate_twist`)."""
    v_cam = _twist(v_cam, "v_cam")
    _refuse_deg_per_s(v_cam, "v_cam")
    return twist_transform(as_pose(flange_T_cam, "flange_T_cam")) @ v_cam


def integrate_twist(a_T_frame, twist, dt: float) -> np.ndarray:
    """The frame's pose after moving with constant body twist ``twist`` for ``dt`` seconds:
    ``a_T_frame @ exp(dt * twist^)`` (exact SE(3) exponential).

    Angular rates in deg/s are refused (``ValueError`` naming ``twist`` and the conversion),
    by two rules on the rotational part w (rad/s):

    * the speed: |w| above ``ANGULAR_SPEED_MAX``, a turn per second, is faster than any
      cobot's wrist and than every servo limit here (``saturate`` warns beyond it too);
      30 deg/s given as rad/s is 4.8 turns a second;
    * the rotation per step, |w| dt, above pi: the exponential of a turn beyond half a turn
      is the same pose as a shorter turn the other way, so no control step means it (a
      period in milliseconds given as seconds is often caught here too).

    Speeds under a turn per second in deg/s (6 deg/s or less read as rad/s) cannot be told
    from rad/s and pass.
    """
    from scipy.linalg import expm

    twist = _twist(twist, "twist")
    dt = _finite_number(dt, "dt", "seconds")
    _check_angular_rate(twist, dt)
    xi = twist * dt
    M = np.zeros((4, 4))
    w = xi[3:]
    M[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    M[:3, 3] = xi[:3]
    step = expm(M)
    step[:3, :3] = Rotation.from_matrix(step[:3, :3]).as_matrix()  # re-orthonormalise
    step[3] = [0, 0, 0, 1]
    return compose(as_pose(a_T_frame, "a_T_frame"), step)


def _refuse_deg_per_s(twist: np.ndarray, name: str) -> float:
    """The angular speed |w| (rad/s) of ``twist``; ``ValueError`` naming ``name`` above
    ``ANGULAR_SPEED_MAX``, a turn per second: deg/s."""
    speed = math.sqrt(twist[3] ** 2 + twist[4] ** 2 + twist[5] ** 2)
    if speed > ANGULAR_SPEED_MAX:
        w = [round(v, 6) for v in twist[3:].tolist()]
        raise ValueError(
            f"{name}'s angular part {w} turns at {speed:.4g} rad/s, more than a turn per second "
            f"({ANGULAR_SPEED_MAX:.4g} rad/s, faster than any cobot): it looks like deg/s. "
            f"Twists are m/s and rad/s: convert with np.radians({name}[3:]) "
            f"({math.radians(speed):.4g} rad/s), or saturate it (saturate({name}, max_linear, "
            "max_angular))")
    return speed


#: The servo laws refuse a depth beyond this (metres) as millimetres: a cobot's camera sees
#: its target within its reach (under 2 m), while any depth beyond 5 cm in millimetres is
#: larger than this.
SERVO_DEPTH_MAX_M = 50.0


def _refuse_millimetre_depth(depth: float, name: str) -> None:
    if depth > SERVO_DEPTH_MAX_M:
        raise ValueError(
            f"{name} reaches {depth:.4g} m, beyond {SERVO_DEPTH_MAX_M:g} m, where no target of a "
            f"servoing arm is: it looks like millimetres. Pass metres ({name} / 1000)")


def _check_angular_rate(twist: np.ndarray, dt: float) -> None:
    """The two rules of ``integrate_twist`` on the rotational part of ``twist`` (rad/s)."""
    speed = _refuse_deg_per_s(twist, "twist")
    w = [round(v, 6) for v in twist[3:].tolist()]
    if speed * abs(dt) > math.pi:
        raise ValueError(
            f"twist's angular part {w} ({speed:.4g} rad/s) for dt = {dt:g} s turns "
            f"{math.degrees(speed * abs(dt)):.4g} deg in one step, more than half a turn: the "
            "step would end as a shorter turn the other way. Use a smaller dt (seconds, not "
            "milliseconds) or saturate the twist")


#: The largest blob area in normalised units (pixels^2 / (fx fy)): a square spanning the
#: whole +-NORMALISED_MAX window that ``check_normalised`` allows for x and y.
_MAX_NORMALISED_AREA = (2.0 * NORMALISED_MAX) ** 2


# --------------------------------------------------------------------------- convergence


@dataclass
class ConvergenceMonitor:
    """Decides after each iteration whether a servo has converged, diverged or timed out.

    ``update(error)`` takes the current error norm (any unit; the tolerances use the same) and
    returns True once it is below ``tolerance``. It raises ServoDivergedError when the error
    is NaN, or has grown to more than ``divergence_factor`` times the smallest value seen (and
    above 10 x ``tolerance``, so noise at the goal is not mistaken for divergence), and ServoTimeoutError after ``max_iterations`` updates.
    """

    tolerance: float
    max_iterations: int = 100
    divergence_factor: float = 3.0
    history: list = field(default_factory=list)

    def __post_init__(self):
        if not (self.tolerance > 0 and self.max_iterations >= 1 and self.divergence_factor > 1):
            raise ValueError("need tolerance > 0, max_iterations >= 1, divergence_factor > 1")

    def update(self, error: float) -> bool:
        error = float(error)
        self.history.append(error)
        if not np.isfinite(error):
            raise ServoDivergedError(f"servo error became {error} at iteration {len(self.history)}")
        if error <= self.tolerance:
            return True
        best = min(self.history)
        # Near the goal the error jitters with image noise; only a real blow-up counts.
        if error > self.divergence_factor * best and error > 10.0 * self.tolerance:
            raise ServoDivergedError(
                f"servo error grew to {error:.4g}, {error / best:.1f}x its best {best:.4g} "
                f"(iteration {len(self.history)}); check the gain's sign, the calibration and "
                "the desired features")
        if len(self.history) >= self.max_iterations:
            raise ServoTimeoutError(
                f"servo did not converge in {self.max_iterations} iterations (error {error:.4g}, "
                f"tolerance {self.tolerance:.4g}); raise the gain or max_iterations")
        return False


@dataclass
class ServoResult:
    """Outcome of a servo run: ``converged``, ``iterations``, ``errors`` (feature error per
    iteration), ``final_pose`` (the last camera pose), ``time_s`` (simulated seconds)."""

    converged: bool
    iterations: int
    errors: list
    final_pose: np.ndarray
    time_s: float
    position_error_m: float = float("nan")
    rotation_error_deg: float = float("nan")
    #: Why ``converged`` is False although the error fell below its tolerance (empty otherwise).
    message: str = ""


# --------------------------------------------------------------------------- pure kinematics


#: simulate_servo's IBVS reports the goal reached when the final camera pose error (the
#: 6-vector of translation, m, and rotation, rad) is at most this many times
#: ``sqrt(N) * tolerance / sigma_min(L*)``: the largest pose change a feature error of
#: ``tolerance`` rms can hide, to first order, with L* the interaction matrix at the goal.
#: Measured on the test and benchmark offsets (10 cm / 20 deg, 180 runs, depth errors, both
#: L modes): the pose error is at most 0.12 of that bound (median 0.01).
GOAL_REACHED_FACTOR = 10.0


def _intrinsics_or_none(intrinsics):
    from robots.interfaces import Intrinsics

    if intrinsics is None or isinstance(intrinsics, Intrinsics):
        return intrinsics
    if isinstance(intrinsics, np.ndarray) or isinstance(intrinsics, (list, tuple)):
        raise ValueError(
            f"intrinsics must be a robots.interfaces.Intrinsics (or None), got a "
            f"{type(intrinsics).__name__} of shape {np.shape(intrinsics)}: build one from a "
            "camera matrix with Intrinsics.from_K(K, width, height, dist)")
    missing = [a for a in ("fx", "fy", "cx", "cy", "width", "height")
               if not hasattr(intrinsics, a)]
    if missing:
        raise ValueError(f"intrinsics must be a robots.interfaces.Intrinsics (or None), got "
                         f"{type(intrinsics).__name__} (no {', '.join(missing)})")
    return intrinsics


def simulate_servo(method: str, world_T_cam, world_T_camd, target_points, intrinsics=None,
                   gain: float = 2.0, dt: float = 0.2, max_iterations: int = 200,
                   tolerance: float | None = None, max_linear: float = 0.25,
                   max_angular: float = 1.0, depth_error: float = 0.0,
                   ibvs_mode: str = "current") -> ServoResult:
    """Servo a free-flying camera by integrating its twist (no robot, no images).

    ``method``: "ibvs" (point features of ``target_points`` (N, 3), world frame) or "pbvs"
    (the target frame is the world frame: the camera measures ``cam_T_world`` exactly).
    ``world_T_cam``: start camera pose; ``world_T_camd``: the goal. ``intrinsics`` (optional,
    an :class:`~robots.interfaces.Intrinsics`) checks every point stays inside the image
    (TargetOutOfViewError otherwise).
    ``depth_error``: relative error of the depths given to IBVS (an estimate, not the truth).
    ``tolerance``: rms feature error (normalised units) for IBVS, default 1e-4; metres plus
    radians for PBVS, default 1e-4. Returns a :class:`ServoResult` with the final camera pose
    error to the goal.

    ``converged`` is True only when the goal is reached: for IBVS the features reaching
    theirs is not enough (features that do not fix the pose, such as 3 points with several
    poses giving one image, can match 10 cm from the goal), so the final pose must also be
    within ``GOAL_REACHED_FACTOR`` times what a feature error of ``tolerance`` can hide;
    otherwise ``converged`` is False and ``message`` says why. Degenerate targets (identical
    or collinear points) raise ValueError before any motion.
    """
    if method not in ("ibvs", "pbvs"):
        raise ValueError(f"method must be 'ibvs' or 'pbvs', got {method!r}")
    T = as_pose(world_T_cam, "world_T_cam")
    Td = as_pose(world_T_camd, "world_T_camd")
    pts = _points(target_points, 3, "target_points", "world-frame points in metres")
    intrinsics = _intrinsics_or_none(intrinsics)
    gain = _finite_number(gain, "gain", "1/s")
    dt = _finite_number(dt, "dt", "seconds")
    if not dt > 0:
        raise ValueError(f"dt must be positive seconds, got {dt}")
    depth_error = _finite_number(depth_error, "depth_error", "relative error")
    if not depth_error > -1:
        raise ValueError(f"depth_error must be > -1 (a relative error), got {depth_error}")
    tolerance = 1e-4 if tolerance is None else _finite_number(tolerance, "tolerance",
                                                              "the error to stop at")
    if isinstance(max_iterations, (bool, np.bool_)) or int(max_iterations) != max_iterations:
        raise ValueError(f"max_iterations must be a whole number, got {max_iterations!r}")
    monitor = ConvergenceMonitor(tolerance, int(max_iterations))
    goal_pts = transform_points(invert(Td), pts)
    s_star = _normalised_projection(goal_pts)
    z_star = goal_pts[:, 2]
    if method == "ibvs":  # a degenerate target raises here, naming its points
        if len(pts) < 3:
            raise ValueError(f"IBVS on 6 DOF needs at least 3 target_points (4 is safer), got "
                             f"{len(pts)}")
        sv_star = np.linalg.svd(interaction_matrix(s_star, z_star), compute_uv=False)
        if not sv_star[-1] > IBVS_RANK_TOL * sv_star[0]:
            raise ValueError("the target's features seen from the goal give a rank-deficient "
                             "interaction matrix, so IBVS cannot reach it: "
                             + _degenerate_features(s_star, "target_points"))
    converged, k = False, 0
    while not converged:
        cam_pts = transform_points(invert(T), pts)
        s = _normalised_projection(cam_pts)
        if intrinsics is not None:
            u = s[:, 0] * intrinsics.fx + intrinsics.cx
            v = s[:, 1] * intrinsics.fy + intrinsics.cy
            if np.any((u < 0) | (u > intrinsics.width - 1) | (v < 0) | (v > intrinsics.height - 1)):
                raise TargetOutOfViewError(f"a feature left the image at iteration {k}")
        if method == "ibvs":
            err = float(np.sqrt(np.mean(np.sum((s - s_star) ** 2, axis=1))))
            depths = cam_pts[:, 2] * (1.0 + depth_error)
            v = ibvs_velocity(s, s_star, depths, gain, depths_star=z_star, mode=ibvs_mode)
        else:
            cam_T_world = invert(T)
            e = pbvs_error(cam_T_world, invert(Td))
            err = float(np.linalg.norm(e[:3]) + np.linalg.norm(e[3:]))
            v = pbvs_velocity(cam_T_world, invert(Td), gain)
        converged = monitor.update(err)
        if converged:
            break
        T = integrate_twist(T, saturate(v, max_linear, max_angular), dt)
        k += 1
    delta = compose(invert(Td), T)
    position_error = float(np.linalg.norm(delta[:3, 3]))
    rotation_error = float(np.linalg.norm(Rotation.from_matrix(delta[:3, :3]).as_rotvec()))
    reached, message = True, ""
    if method == "ibvs":
        allowed = GOAL_REACHED_FACTOR * np.sqrt(len(pts)) * tolerance / sv_star[-1]
        if np.hypot(position_error, rotation_error) > allowed:
            reached = False
            message = (
                f"the features reached their goal (rms error {err:.2g} <= {tolerance:.2g}) but "
                f"the camera is {position_error * 1e3:.1f} mm and "
                f"{np.degrees(rotation_error):.2f} deg from the goal pose, more than that "
                f"error can hide ({allowed:.2g}): these {len(pts)} features do not fix the "
                "pose (3 points have up to 4 poses with the same image); use 4 or more "
                "points, not all collinear")
    return ServoResult(reached, k, monitor.history, T, k * dt, position_error,
                       float(np.degrees(rotation_error)), message)


def offset_start(world_T_camd, centre_world, translation_m: float, rotation_deg: float,
                 rng: np.random.Generator) -> np.ndarray:
    """A start camera pose ``translation_m`` and ``rotation_deg`` away from the goal, in seeded
    random directions, with the rotation taken about ``centre_world`` (the target's centre) so
    the target stays in view: the usual way to state "a 10 cm / 20 degree offset"."""
    Td = as_pose(world_T_camd, "world_T_camd")
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction /= np.linalg.norm(direction)
    c = np.asarray(centre_world, dtype=float).reshape(3)
    R = Rotation.from_rotvec(np.radians(rotation_deg) * axis).as_matrix()
    orbit = compose(make_pose(t=c), make_pose(R), make_pose(t=-c))
    return compose(make_pose(t=translation_m * direction), orbit, Td)


# --------------------------------------------------------------------------- on a robot


def _undistorted(uv, intrinsics) -> np.ndarray:
    import cv2

    return cv2.undistortPoints(np.asarray(uv, float).reshape(-1, 1, 2), intrinsics.K,
                               intrinsics.dist).reshape(-1, 2)


def check_in_view(uv, intrinsics, margin_px: float = 5.0) -> None:
    """Raise TargetOutOfViewError if any pixel (N, 2) is within ``margin_px`` of the border."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    w, h = intrinsics.width, intrinsics.height
    out = (uv[:, 0] < margin_px) | (uv[:, 0] > w - 1 - margin_px) | \
          (uv[:, 1] < margin_px) | (uv[:, 1] > h - 1 - margin_px)
    if np.any(out):
        k = int(np.flatnonzero(out)[0])
        raise TargetOutOfViewError(
            f"feature {k} at pixel ({uv[k, 0]:.0f}, {uv[k, 1]:.0f}) is within {margin_px} px of "
            f"the {w}x{h} image border; the servo stopped before the target leaves the image")


def run_servo(robot, camera, flange_T_cam, step, tolerance: float, gain: float = 2.0,
              dt: float = 0.2, max_iterations: int = 60, max_linear: float = 0.1,
              max_angular: float = 0.5, divergence_factor: float = 3.0) -> ServoResult:
    """The eye-in-hand servo loop on a real or simulated robot.

    Each iteration: ``frame = camera.capture()``; ``error, v_cam = step(frame, gain)`` (the
    caller's measurement and control law; it raises TargetLostError / TargetOutOfViewError);
    convergence / divergence / timeout checks (:class:`ConvergenceMonitor`); the twist is
    saturated, turned into a flange twist with the calibration ``flange_T_cam`` and applied for
    ``dt`` seconds as a straight ``robot.move_to``. On any error the robot is stopped and the
    error re-raised. ``time_s`` is the simulated (frame timestamp) time from first to last image.
    """
    monitor = ConvergenceMonitor(tolerance, max_iterations, divergence_factor)
    flange_T_cam = as_pose(flange_T_cam, "flange_T_cam")
    t0 = None
    try:
        while True:
            frame = camera.capture()
            t0 = frame.timestamp if t0 is None else t0
            error, v_cam = step(frame, gain)
            if monitor.update(error):
                return ServoResult(True, len(monitor.history) - 1, monitor.history,
                                   compose(robot.flange_pose(), flange_T_cam),
                                   frame.timestamp - t0)
            v_cam = saturate(v_cam, max_linear, max_angular)
            v_flange = cam_twist_to_flange(v_cam, flange_T_cam)
            current = robot.flange_pose()
            target = integrate_twist(current, v_flange, dt)
            dist = np.linalg.norm(target[:3, 3] - current[:3, 3])
            speed = float(np.clip(dist / dt, 1e-3, robot.safety.max_speed))
            robot.move_to(target, speed=speed)
    except BaseException:
        robot.stop()
        raise


def _check_target_in_view(det, intrinsics, margin_px, required_points) -> None:
    """Raise TargetOutOfViewError if the detected corners come within ``margin_px`` of the
    image border, or if ``required_points`` (target frame, m) project outside the image."""
    if margin_px is not None:
        check_in_view(det.corners_px, intrinsics, margin_px)
    if required_points is not None and det.cam_T_target is not None:
        from robots.perception import project

        check_in_view(project(transform_points(det.cam_T_target, required_points),
                              intrinsics), intrinsics, 0.0)


def ibvs_step(detect, camd_T_target, intrinsics, depth: str = "image", margin_px: float = 5.0,
              min_points: int = 4, required_points=None):
    """A ``step`` for :func:`run_servo`: IBVS on the detected points of a target.

    ``detect(frame)`` returns a :class:`~robots.capture.Detection` (corner pixels, their object
    points in the target frame and ``cam_T_target``) or None. The desired feature of each
    detected point is its projection from ``camd_T_target`` (4, 4), so a board seen only in
    part (ChArUco corners come with ids) still servos on the points it shows. ``depth``:
    "image" reads each point's depth from the depth image (median of a 5x5 box), "pose" takes
    it from the detection's pose. The error is the rms feature error, normalised units.
    ``margin_px``: detected points closer than this to the border raise TargetOutOfViewError
    (None: no check, for boards seen in part). ``required_points`` (M, 3), target frame:
    points that must stay in the image (e.g. all of a board's corners), checked through the
    detected pose.
    """
    from robots.perception import depth_at

    camd_T_target = as_pose(camd_T_target, "camd_T_target")
    if depth not in ("image", "pose"):
        raise ValueError(f"depth must be 'image' or 'pose', got {depth!r}")

    def step(frame, gain):
        det = detect(frame)
        if det is None or len(det.corners_px) < min_points:
            raise TargetLostError("the target is not detected in the image; servo stopped")
        _check_target_in_view(det, intrinsics, margin_px, required_points)
        s = _undistorted(det.corners_px, intrinsics)
        goal = transform_points(camd_T_target, det.object_points)
        s_star, z_star = _normalised_projection(goal), goal[:, 2]
        z = depth_at(frame, det.corners_px) if depth == "image" and frame.depth is not None \
            else np.full(len(s), np.nan)
        if not np.all(np.isfinite(z)):
            if det.cam_T_target is None:
                raise TargetLostError("no depth at the features and no pose to estimate it")
            z = transform_points(det.cam_T_target, det.object_points)[:, 2]
        err = float(np.sqrt(np.mean(np.sum((s - s_star) ** 2, axis=1))))
        return err, ibvs_velocity(s, s_star, z, gain, depths_star=z_star, mode="mean")

    return step


def pbvs_step(detect, camd_T_target, intrinsics, margin_px: float = 5.0, required_points=None):
    """A ``step`` for :func:`run_servo`: PBVS on the detection's ``cam_T_target``. The error is
    metres + radians (``|t| + |theta u|`` of ``camd_T_cam``). ``margin_px`` and
    ``required_points`` as in :func:`ibvs_step`."""
    camd_T_target = as_pose(camd_T_target, "camd_T_target")

    def step(frame, gain):
        det = detect(frame)
        if det is None or det.cam_T_target is None:
            raise TargetLostError("the target is not detected in the image; servo stopped")
        _check_target_in_view(det, intrinsics, margin_px, required_points)
        e = pbvs_error(det.cam_T_target, camd_T_target)
        return (float(np.linalg.norm(e[:3]) + np.linalg.norm(e[3:])),
                pbvs_velocity(det.cam_T_target, camd_T_target, gain))

    return step


def move_in_steps(robot, base_T_flange, speed: float = 0.2, max_step_m: float = 0.3,
                  max_step_deg: float = 60.0) -> None:
    """``robot.move_to`` split into straight segments no longer than the safety limits allow
    (each at most ``max_step_m`` and ``max_step_deg``)."""
    from scipy.spatial.transform import Slerp

    target = as_pose(base_T_flange, "base_T_flange")
    start = robot.flange_pose()
    dist = np.linalg.norm(target[:3, 3] - start[:3, 3])
    angle = np.degrees(np.linalg.norm(
        Rotation.from_matrix(start[:3, :3].T @ target[:3, :3]).as_rotvec()))
    n = max(1, int(np.ceil(max(dist / max_step_m, angle / max_step_deg))))
    slerp = Slerp([0, 1], Rotation.from_matrix([start[:3, :3], target[:3, :3]]))
    for k in range(1, n + 1):
        s = k / n
        waypoint = make_pose(slerp([s]).as_matrix()[0], (1 - s) * start[:3, 3] + s * target[:3, 3])
        robot.move_to(target if k == n else waypoint, speed=min(speed, robot.safety.max_speed))


# --------------------------------------------------------------------------- staged pick-and-place

STAGES = ("search", "approach", "coarse", "precise", "grasp", "lift", "place", "done")
# The smallest tool-axis tilt (deg) the flange rise of the staged controller acts on. With the
# exact calibration it reads 0.0-0.2 deg on every simulated arm (the piece's top, measured from
# two heights, is not quite the same point), and acting on that alone moved the grasp about
# 1 mm off a piece it would have hit within 0.8 mm.
TOOL_AXIS_RESOLUTION_DEG = 0.5
# A larger tilt is taken for a measurement of the wrong point (a neighbour's top), not used:
# a calibration this far off needs redoing, not a correction at the last moment.
TOOL_AXIS_MAX_TILT_DEG = 5.0
DOWN = np.diag([1.0, -1.0, -1.0])  # a tool frame whose z axis points straight down

# Per-arm options of the staged controller in the simulator's chess cell: where each arm's
# wrist camera looks for the board (base frame, m), straight down from ``overview_height_m``
# over each ``search_xy`` in turn. The simulator lays the board's centre 0.5 x reach + 5 cm in
# front of the base (sim_backends.world), so the first point is over it and the others 8 cm
# nearer and further. The Cobotta's board lies at 0.24 m, beyond the 0.21 m at which that
# 342 mm-reach arm can still hold its camera 0.39 m up, so its search looks from 0.20 m (its
# third point, 0.22 m, is out of reach and skipped). The height fits the whole board into the
# camera's field of view with a margin (0.44 m of board and frame in the 54-degree vertical
# field from 0.62 m; the Cobotta's 0.28 m board from 0.38 m). A real cell passes its own.
ARM_OPTIONS = {
    # The Panda's search poses are the controller's defaults. Its wrist camera sits further
    # off the tool axis than the others': 0.2 m over a piece, the point under the cup is seen
    # at v = 212 of 240 px (the other arms: 152), and with a 2 deg calibration error the servo
    # ran the piece into the image border (2 of 40 seeds; benchmarks/servo.py). From 0.25 m it
    # is seen at v = 196 and 40 of 40 seeds succeed.
    "panda": {"overview_height_m": 0.63, "search_xy": ((0.48, 0.0), (0.4, 0.0), (0.56, 0.0)),
              "hover_m": 0.25},
    "aubo_i5": {"overview_height_m": 0.63, "search_xy": ((0.49, 0.0), (0.41, 0.0), (0.57, 0.0))},
    "ur10e": {"overview_height_m": 0.63, "search_xy": ((0.70, 0.0), (0.62, 0.0), (0.78, 0.0))},
    # With its camera turned a quarter turn (flange x along -y) the Cobotta holds the camera
    # 2-4 cm lower than with the default heading, but keeps that heading over the whole
    # board: with the default one (flange x along +x) its IK reaches the tool-down pose over
    # only 5 of the 8 files on most ranks (measured), and turning the flange between the
    # search and the pick turns the calibration's rotation error with it (measured: the
    # piece then expected half a 30 mm square off, and its neighbour picked).
    "cobotta": {"overview_height_m": 0.39, "view_yaw_rad": -np.pi / 2,
                "search_xy": ((0.20, 0.0), (0.18, 0.0), (0.22, 0.0))},
}


def overview_base_T_cam(x_m: float, y_m: float, height_m: float, yaw_rad: float = 0.0):
    """Camera pose (4, 4) in the base frame looking straight down from ``height_m`` over the
    base point (``x_m``, ``y_m``), metres. With ``yaw_rad`` = 0 the image top points away from
    the robot (base +x) and the image x axis along base -y; ``yaw_rad`` turns the camera about
    the vertical."""
    down = np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
    return make_pose(Rotation.from_euler("z", yaw_rad).as_matrix() @ down, [x_m, y_m, height_m])


def move_to_view(robot, base_T_flange, speed: float = 0.25) -> None:
    """Move the flange to ``base_T_flange``: in straight segments (:func:`move_in_steps`) when
    the arm can, else joint-interpolated (a "move J") to an IK solution, for a robot that
    offers ``solve_ik`` (the simulator).

    A straight line is not always possible for a long transfer: the UR10e starts folded
    behind its base, and the line to the board passes its shoulder singularity. The IK is
    seeded with the base joint turned towards the target (joint 0 is the vertical base axis
    on every supported arm), so the solution keeps the arm's elbow and wrist configuration.
    The joint path is cut into moves within ``robot.safety.max_joint_step``.
    """
    try:
        move_in_steps(robot, base_T_flange, speed)
        return
    except (RuntimeError, ValueError):
        if not hasattr(robot, "solve_ik"):
            raise
    target = as_pose(base_T_flange, "base_T_flange")
    move_joints_in_steps(robot, robot.solve_ik(target, ik_seed_facing(robot, target)))


def ik_seed_facing(robot, base_T_flange, min_turn_rad: float = 0.0) -> np.ndarray:
    """The robot's current joint angles (rad) with joint 0, the vertical base axis on every
    supported arm, turned so the arm faces ``base_T_flange``'s position (about the base z
    axis), when that turn exceeds ``min_turn_rad``: an IK seed that keeps the elbow and wrist
    configuration instead of reaching over backwards."""
    seed = np.asarray(robot.joint_positions(), dtype=float).copy()
    here, there = robot.flange_pose()[:3, 3], np.asarray(base_T_flange, dtype=float)[:3, 3]
    turn = (np.arctan2(there[1], there[0]) - np.arctan2(here[1], here[0]) + np.pi) \
        % (2 * np.pi) - np.pi
    if abs(turn) > min_turn_rad:
        seed[0] += turn
    return seed


def move_joints_in_steps(robot, q) -> None:
    """Joint-interpolated move to the joint angles ``q`` (rad), cut into moves within
    ``robot.safety.max_joint_step`` and at most 0.5 rad/s (or the safety limit if lower)."""
    q0 = np.asarray(robot.joint_positions(), dtype=float)
    q1 = np.asarray(q, dtype=float)
    n = max(1, int(np.ceil(np.abs(q1 - q0).max() / (0.9 * robot.safety.max_joint_step))))
    joint_speed = min(0.5, robot.safety.max_joint_speed)
    for s in np.linspace(0.0, 1.0, n + 1)[1:]:
        robot.move_joints(q0 + s * (q1 - q0), speed=joint_speed)


def aside_joints(robot) -> np.ndarray:
    """The robot's current joint angles (rad) with joint 0, the vertical base axis on every
    supported arm, turned a quarter turn (+90 deg, or -90 deg when that leaves the joint's
    limits): the arm swung to the side of the work area, out of a fixed camera's view of it.
    Checked in the simulator's chess cell on the Panda, UR10e, Aubo-i5 and Cobotta."""
    q = np.asarray(robot.joint_positions(), dtype=float).copy()
    low, high = np.asarray(robot.joint_limits(), dtype=float)[0]
    q[0] += np.pi / 2 if q[0] + np.pi / 2 <= high else -np.pi / 2
    if not low <= q[0] <= high:
        raise ValueError(f"joint 0 cannot turn a quarter turn either way from {q[0]:.2f} rad "
                         "within its limits; give park_joints explicitly")
    return q


@dataclass
class StageEvent:
    """One line of the stage log: entered ``stage`` at host time ``time_s`` (perf_counter) after
    ``iterations`` servo iterations in the previous stage, because ``reason``."""

    stage: str
    time_s: float
    iterations: int
    reason: str


@dataclass
class PickPlaceResult:
    """What :func:`pick_and_place` did: ``log`` of stage transitions, total servo
    ``iterations``, simulated ``time_s`` of the servo stages, the estimated positions (base
    frame, m) of the piece top and of the destination square, and ``grasped``."""

    log: list
    iterations: int
    time_s: float
    piece_top_base: np.ndarray
    destination_base: np.ndarray
    grasped: bool


def _plane_heights(cloud):
    """Height (H, W) of each point above the dominant plane (the board) in a camera cloud."""
    from solutions.perception import heights_above_plane

    if np.all(np.isfinite(cloud), axis=2).sum() < 100:
        raise TargetLostError("the depth image is empty; nothing to servo on")
    return heights_above_plane(cloud, np.random.default_rng(0), np.random.default_rng(1))[0]


def measure_piece_top(frame, intrinsics, predicted_uv, min_height_m: float = 0.008,
                      search_px: float = 60.0):
    """The top of the piece nearest ``predicted_uv`` in a close-up RGB-D frame.

    Heights are measured from the dominant plane (the board) fitted in this very frame, so the
    measurement needs no calibration. Returns ``(top_cam (3,) m, top_uv (2,) px, area)`` with
    the top's area in normalised units (pixels^2 / (fx fy)); raises TargetLostError when no
    piece is within ``search_px`` of the prediction.
    """
    from robots.perception import project

    tops = _piece_tops(frame, intrinsics, min_height_m)
    if not tops:
        raise TargetLostError("no piece stands on the board in view")
    d = [np.linalg.norm(centroid - np.asarray(predicted_uv, float)) for _, _, centroid in tops]
    k = int(np.argmin(d))
    if d[k] > search_px:
        raise TargetLostError(f"no piece within {search_px:.0f} px of where it was expected")
    top_cam, pixels, _ = tops[k]
    return top_cam, project(top_cam, intrinsics)[0], pixels / (intrinsics.fx * intrinsics.fy)


def _piece_tops(frame, intrinsics, min_height_m: float = 0.008):
    """Every piece standing on the board in a close-up RGB-D frame: a list of (top point in
    the camera frame (3,) m, pixel count of the top, centroid (2,) px of the whole blob).
    The top is the blob's highest 6 mm."""
    import cv2

    from robots.perception import point_cloud

    cloud = point_cloud(frame.depth, intrinsics)
    h = _plane_heights(cloud)
    mask = (np.nan_to_num(h, nan=-1) > min_height_m).astype(np.uint8)
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    tops = []
    for k in range(1, count):
        if stats[k, cv2.CC_STAT_AREA] < 10:
            continue
        blob = labels == k
        top = blob & (h > np.nanmax(h[blob]) - 0.006)
        tops.append((cloud[top].mean(axis=0), int(top.sum()), centroids[k]))
    return tops


def nearest_pieces_m(frame, intrinsics, point_cam, min_height_m: float = 0.008):
    """Distances (m, sorted, across the camera's optical axis) from ``point_cam`` (3,), a
    piece top expected in the camera frame, to the tops of the pieces seen in a close-up
    RGB-D frame: how clearly the expectation singles one piece out."""
    tops = _piece_tops(frame, intrinsics, min_height_m)
    point = np.asarray(point_cam, float)
    return np.sort([float(np.linalg.norm(top[:2] - point[:2])) for top, _, _ in tops])


class StagedPickAndPlace:
    """The staged approach-to-grasp controller for an eye-in-hand RGB-D camera and a suction
    cup: search -> approach -> coarse -> precise -> grasp -> lift -> place.

    ``method``: "open_loop" (look-then-move: the piece's position from the overview image,
    mapped through the calibration, then a blind move), "pbvs" (position-based servo on the
    piece's 3-D top point, measured in each close-up frame) or "ibvs" (decoupled image-based
    law on the top's (x, y, area) in each frame). ``flange_T_cam`` is the calibration the
    controller believes (it may be wrong: that is the point of the benchmark).
    ``view_yaw_rad``: the overview camera's turn (rad) about the vertical from its default
    heading (image top away from the robot); the later stages keep the flange heading the
    search ends with. (A round suction cup does not care about the heading, but a small arm
    reaches the board with some headings only.)
    ``overview_camera`` and ``base_T_overview_cam``: a fixed RGB-D camera that sees the board
    and its calibration (eye-to-hand). With them, the search and the coarse alignment are
    position-based on the fixed camera (the board and the piece found in its image, mapped to
    the base, the wrist moved over the piece) and only the precise alignment uses the wrist
    camera; without them, the wrist camera also searches from ``search_xy``.
    ``park_joints``: where the arm waits (joint angles, rad) while the fixed camera looks, so
    that it hides neither board nor pieces; by default :func:`aside_joints`, the arm swung a
    quarter turn about its base axis. (At its home pose the Aubo-i5 holds its wrist over ranks
    1-3, in the fixed camera's line of sight.)
    ``check_tool_axis`` (pbvs, ibvs): before the descent, raise the flange along its axis and
    back, and correct the descent by the tool-axis tilt the camera sees
    (:meth:`_tool_axis_offset`); False descends along the calibration's axis.
    Every stage has an iteration budget; ``log`` records each transition.
    """

    def __init__(self, cell, flange_T_cam, square_m: float, method: str = "ibvs",
                 overview_height_m: float = 0.63, search_xy=((0.48, 0.0), (0.4, 0.0), (0.56, 0.0)),
                 hover_m: float = 0.2, gain: float = 2.5, dt: float = 0.2,
                 tolerance_m: float = 5e-4, max_iterations: int = 40, on_stage=None,
                 view_yaw_rad: float = 0.0, overview_camera=None, base_T_overview_cam=None,
                 park_joints=None, check_tool_axis: bool = True):
        if method not in ("open_loop", "pbvs", "ibvs"):
            raise ValueError(f"method must be 'open_loop', 'pbvs' or 'ibvs', got {method!r}")
        self.cell, self.robot, self.camera = cell, cell.robot, cell.camera
        if self.robot.tool is None or not hasattr(self.robot.tool, "grasp"):
            raise ValueError("pick-and-place needs a suction cup or gripper on the robot")
        self.flange_T_cam = as_pose(flange_T_cam, "flange_T_cam")
        self.square_m, self.method = float(square_m), method
        self.overview_height_m, self.search_xy = overview_height_m, search_xy
        self.hover_m, self.gain, self.dt = hover_m, gain, dt
        self.tolerance_m, self.max_iterations = tolerance_m, max_iterations
        self.log: list[StageEvent] = []
        self.iterations, self.servo_time = 0, 0.0
        self._stage_iterations = 0
        self.on_stage = on_stage  # called as on_stage(stage_name, controller) on each transition
        self.view_yaw_rad = float(view_yaw_rad)
        if (overview_camera is None) != (base_T_overview_cam is None):
            raise ValueError("give overview_camera and base_T_overview_cam together (the fixed "
                             "camera and its eye-to-hand calibration), or neither")
        self.overview_camera = overview_camera
        self.base_T_overview_cam = (None if base_T_overview_cam is None
                                    else as_pose(base_T_overview_cam, "base_T_overview_cam"))
        self.park_joints = park_joints
        self.check_tool_axis = bool(check_tool_axis)

    # ----- bookkeeping

    def _enter(self, stage: str, reason: str) -> None:
        self.log.append(StageEvent(stage, time.perf_counter(), self._stage_iterations, reason))
        self._stage_iterations = 0
        if self.on_stage is not None:
            self.on_stage(stage, self)

    def _base_T_cam(self) -> np.ndarray:
        return compose(self.robot.flange_pose(), self.flange_T_cam)

    def _tcp_down_at(self, point_base, above_m: float) -> np.ndarray:
        """Flange pose putting the TCP ``above_m`` over a base point, tool pointing down, with
        the flange's current yaw kept."""
        yaw_x = self.robot.flange_pose()[:3, 0].copy()
        yaw_x[2] = 0.0
        yaw_x /= np.linalg.norm(yaw_x)
        R = np.column_stack([yaw_x, np.cross([0, 0, -1.0], yaw_x), [0, 0, -1.0]])
        base_T_tcp = make_pose(R, np.asarray(point_base, float) + [0, 0, above_m])
        return compose(base_T_tcp, invert(self.robot.tool.flange_T_tcp))

    # ----- stages

    def _board_and_pieces(self, frame, intrinsics, base_T_cam):
        """(base_T_chess, {square: (piece, top in base)}) seen in ``frame``, or None."""
        from robots.perception import detect_chess_board
        from solutions.perception import detect_pieces

        board = detect_chess_board(frame, intrinsics, self.square_m,
                                   white_side_cam=invert(base_T_cam)[:3, 3])
        if board is None:
            return None
        pieces = detect_pieces(frame, intrinsics, board.cam_T_chess, self.square_m)
        return compose(base_T_cam, board.cam_T_chess), {
            p.square: (p, transform_points(base_T_cam, p.top_cam[None])[0]) for p in pieces}

    def search(self):
        """Find the board: in the fixed overview camera's image when there is one (the arm
        parked out of its view first), else by looking down from the wrist camera's overview
        poses until it is found. Returns (base_T_chess, pieces) with the pieces' tops in the
        base frame."""
        if self.overview_camera is not None:
            park = aside_joints(self.robot) if self.park_joints is None else self.park_joints
            move_joints_in_steps(self.robot, park)
            cam = self.overview_camera
            found = self._board_and_pieces(cam.capture(), cam.intrinsics, self.base_T_overview_cam)
            if found is None:
                raise TargetLostError("the fixed overview camera sees no chess board; check "
                                      "that nothing hides it and that it is the calibrated one")
            return found
        return self._wrist_search()

    def _wrist_search(self):
        intr = self.camera.intrinsics
        for x, y in self.search_xy:
            base_T_cam = overview_base_T_cam(x, y, self.overview_height_m, self.view_yaw_rad)
            try:
                move_to_view(self.robot, compose(base_T_cam, invert(self.flange_T_cam)), 0.25)
            except (RuntimeError, ValueError):
                continue  # unreachable overview: try the next one
            found = self._board_and_pieces(self.camera.capture(), intr, self._base_T_cam())
            if found is not None:
                return found
        raise TargetLostError("search found no chess board from any overview pose; "
                              "check search_xy / overview_height_m for this arm")

    def _servo_over(self, point_base, above_m: float, measure) -> None:
        """Coarse move over a point, then (pbvs/ibvs) servo until the measured point sits where
        the calibration says it must be seen when the TCP is ``above_m`` over it."""
        move_to_view(self.robot, self._tcp_down_at(point_base, above_m), 0.25)
        if self.method == "open_loop":
            return  # look-then-move: no image is used after the search
        self._enter("precise", "over the target (position from the overview image)")
        from robots.perception import project

        # Where the point must appear: TCP above_m over it, expressed in the camera frame.
        p_star = transform_points(invert(self.flange_T_cam) @ self.robot.tool.flange_T_tcp,
                                  [[0, 0, above_m]])[0]
        x_star = p_star[:2] / p_star[2]
        predicted = None

        def step(frame, gain):
            nonlocal predicted
            if predicted is None:  # first frame: where the overview estimate says it is
                cam = transform_points(invert(self._base_T_cam()), [point_base])[0]
                predicted = project(cam, self.camera.intrinsics)[0]
            p, uv, area = measure(frame, predicted)
            predicted = uv
            check_in_view(uv, self.camera.intrinsics, 5.0)
            if self.method == "pbvs":
                v = np.zeros(6)
                v[:3] = gain * (p - p_star)
                return float(np.linalg.norm(p - p_star)), v
            a_star = area * (p[2] / p_star[2]) ** 2
            v = decoupled_velocity([p[0] / p[2], p[1] / p[2], area, np.nan],
                                   [x_star[0], x_star[1], a_star, np.nan], p[2], gain)
            return float(np.linalg.norm(p - p_star)), v

        result = run_servo(self.robot, self.camera, self.flange_T_cam, step, self.tolerance_m,
                           self.gain, self.dt, self.max_iterations, max_linear=0.05,
                           max_angular=0.3)
        self.iterations += result.iterations
        self._stage_iterations = result.iterations
        self.servo_time += result.time_s

    def _singles_out(self, top_base) -> bool:
        """Seen from the hover pose over ``top_base`` (a piece top in the base frame, from the
        fixed camera), is one piece clearly the one meant? Pieces stand a square apart, so
        when the next piece is at least half a square further from the expected top than the
        nearest, the nearest is the piece unless the expectation is off by 3/4 of a square;
        when it is not, the expectation may be off by half a square (a 2 deg calibration
        error of a camera 0.7 m away) and the neighbour may be the piece meant."""
        move_to_view(self.robot, self._tcp_down_at(top_base, self.hover_m), 0.25)
        expected = transform_points(invert(self._base_T_cam()), [top_base])[0]
        d = nearest_pieces_m(self.camera.capture(), self.camera.intrinsics, expected)
        return len(d) > 0 and (len(d) == 1 or d[1] - d[0] >= self.square_m / 2)

    def _tool_axis_offset(self, rise_m: float = 0.08):
        """The piece top's offset (3,) m, in the flange frame, from the tool axis as the wrist
        camera sees it, measured by raising the flange ``rise_m`` along its axis and back.

        After the precise stage the piece sits where the calibration says the tool axis
        passes, but a calibration rotated by theta tilts that axis by theta: at 0.3 m from the
        camera 2 deg is 10 mm. The rise shows the true axis: a fixed point moves in the camera
        frame by ``rise_m`` along the flange's +z expressed in the camera frame, u. The axis
        then runs along u through the flange origin (still taken from the calibration: its
        translation error, and its rotation error times the camera's offset from the flange,
        stay). Returns (offset, tilt between u and the calibration's axis in degrees), or
        (None, reason) when the rise is impossible, the piece is not found again, or the
        measurement is not a unit vector or tilts more than ``TOOL_AXIS_MAX_TILT_DEG``.
        """
        from robots.perception import project

        intr = self.camera.intrinsics
        flange_T_cam = self.flange_T_cam
        cam_T_flange = invert(flange_T_cam)
        flange_T_tcp = self.robot.tool.flange_T_tcp
        on_axis = transform_points(cam_T_flange, [[*flange_T_tcp[:2, 3], 0.0]])[0]
        # Where the precise stage left the piece: the TCP hover_m over it, per the calibration.
        expected = transform_points(cam_T_flange @ flange_T_tcp, [[0, 0, self.hover_m]])[0]
        low, _, _ = measure_piece_top(self.camera.capture(), intr, project(expected, intr)[0])
        here = self.robot.flange_pose()
        try:
            self.robot.move_to(compose(here, make_pose(t=[0, 0, -rise_m])), speed=0.1)
        except (RuntimeError, ValueError) as err:
            return None, f"no room to rise {rise_m * 100:.0f} cm ({err})"
        # Predicted along the calibration's axis: over such a rise the image of a piece off
        # the camera's axis moves about a square, so the pixel where it was last seen may lie
        # nearer a neighbour.
        try:
            high, _, _ = measure_piece_top(self.camera.capture(), intr,
                                           project(low + rise_m * cam_T_flange[:3, 2], intr)[0])
        except TargetLostError:
            # From higher up a tall piece's silhouette can merge with its neighbours' (the
            # back rank) into one blob whose centre lies elsewhere.
            high = None
        self.robot.move_to(here, speed=0.1)
        if high is None:
            return None, f"the piece was not found again {rise_m * 100:.0f} cm higher"
        u = (high - low) / rise_m
        if abs(np.linalg.norm(u) - 1.0) > 0.05:
            return None, f"the rise measured {np.linalg.norm(u):.2f} of its length"
        u /= np.linalg.norm(u)
        tilt = np.degrees(np.arccos(np.clip(u @ cam_T_flange[:3, 2], -1.0, 1.0)))
        if tilt > TOOL_AXIS_MAX_TILT_DEG:
            return None, (f"a {tilt:.1f} deg tilt is more than a calibration error; another "
                          "piece's top was measured")
        v = low - on_axis
        offset_cam = v - (v @ u) * u
        return flange_T_cam[:3, :3] @ offset_cam, tilt

    def _descend_and_grasp(self, top_above_m: float, offset=None) -> bool:
        """Straight down to 12 mm over the expected contact (shifted by ``offset`` (3,) m in
        the flange frame, its z ignored), then a guarded descent: 2 mm steps down the tool
        axis, trying the vacuum at each, at most 24 mm further."""
        tool = self.robot.tool
        fast = top_above_m - 0.012
        dx, dy = (0.0, 0.0) if offset is None else offset[:2]
        self.robot.move_to(compose(self.robot.flange_pose(), make_pose(t=[dx, dy, fast])),
                           speed=0.1)  # flange z is the tool axis
        for _ in range(12):
            if tool.grasp():
                return True
            self.robot.move_to(compose(self.robot.flange_pose(), make_pose(t=[0, 0, 0.002])),
                               speed=0.02)
        return tool.grasp()

    def run(self, from_square: str, to_square: str) -> PickPlaceResult:
        from robots.perception import square_centre

        self._enter("search", "start")
        base_T_chess, pieces = self.search()
        if from_square not in pieces:
            raise ValueError(f"no piece found on {from_square}; pieces seen: {sorted(pieces)}")
        if to_square in pieces:
            raise ValueError(f"{to_square} is occupied; capture moves are not supported")
        piece, top_base = pieces[from_square]
        dest = transform_points(base_T_chess, square_centre(to_square, self.square_m)[None])[0]

        self._enter("approach", f"board found, {piece.colour} {piece.kind} on {from_square}")
        source = "fixed camera" if self.overview_camera is not None else "wrist overview"
        self._enter("coarse", f"moving over the piece (position from the {source})")
        if self.overview_camera is not None and not self._singles_out(top_base):
            self._enter("search", f"the fixed camera's {from_square} is as near another piece: "
                                  "looking again with the wrist camera")
            base_T_chess, pieces = self._wrist_search()
            if from_square not in pieces:
                raise ValueError(f"no piece found on {from_square} by the wrist camera; "
                                 f"pieces seen: {sorted(pieces)}")
            piece, top_base = pieces[from_square]
            self._enter("coarse", "moving over the piece (position from the wrist overview)")
        intr = self.camera.intrinsics
        self._servo_over(top_base, self.hover_m,
                         lambda frame, uv: measure_piece_top(frame, intr, uv))
        offset, reason = None, "aligned over the piece"
        if self.method != "open_loop" and self.check_tool_axis:
            offset, detail = self._tool_axis_offset()
            if offset is None:
                reason += f"; tool axis not checked: {detail}"
            elif detail < TOOL_AXIS_RESOLUTION_DEG:
                offset = None
                reason += (f"; the tool axis seen {detail:.1f} deg off the calibration's, within "
                           "what the rise can tell: no shift")
            else:
                reason += (f"; the tool axis seen {detail:.1f} deg off the calibration's, "
                           f"{np.linalg.norm(offset[:2]) * 1e3:.1f} mm shift")
        self._enter("grasp", reason)
        grasped = self._descend_and_grasp(self.hover_m, offset)
        if not grasped:
            self.robot.stop()
            raise ServoError(f"the suction cup found nothing to hold over {from_square}")
        base_T_tcp_grasp = self.robot.tcp_pose()
        self._enter("lift", "holding the piece")
        self.robot.move_to(compose(make_pose(t=[0, 0, 0.08]), self.robot.flange_pose()), speed=0.1)
        self._enter("place", f"carrying to {to_square}")
        # Move the piece by the board displacement from its square to the new one, relative to
        # where the cup actually took it: whatever offset the grasp had (calibration error),
        # the piece keeps, so it lands as centred as it stood. Only the board's rotation
        # estimate matters here, not its position.
        shift = base_T_chess[:3, :3] @ (square_centre(to_square, self.square_m)
                                        - square_centre(from_square, self.square_m))
        shift[2] = 0.0
        place = base_T_tcp_grasp.copy()
        place[:3, 3] += shift + [0, 0, 0.001]
        flange_T_tcp = self.robot.tool.flange_T_tcp
        above = compose(make_pose(t=[0, 0, self.hover_m]), place)
        move_to_view(self.robot, compose(above, invert(flange_T_tcp)), 0.25)
        self.robot.move_to(compose(place, invert(flange_T_tcp)), speed=0.05)
        self.robot.tool.release()
        self.robot.move_to(compose(make_pose(t=[0, 0, 0.06]), self.robot.flange_pose()), speed=0.1)
        self._enter("done", f"released on {to_square}")
        return PickPlaceResult(self.log, self.iterations, self.servo_time, top_base, dest, grasped)


def pick_and_place(cell, from_square: str, to_square: str, method: str = "ibvs",
                   flange_T_cam=None, square_m: float | None = None, **options) -> PickPlaceResult:
    """Move the piece on ``from_square`` to ``to_square`` with the staged controller.

    ``cell``: a Workcell with an eye-in-hand RGB-D camera and a suction cup. ``flange_T_cam``:
    the hand-eye calibration (a (4, 4) array, a CalibrationResult or a YAML path); in the
    simulator it defaults to the camera's nominal (design) mount, on a real robot it is
    required. ``square_m`` defaults to the simulator's board (0.05 m; 0.03 on the Cobotta).
    Options go to :class:`StagedPickAndPlace`; ``overview_height_m`` and ``search_xy`` default
    to the arm's entry in :data:`ARM_OPTIONS` (the simulator's layout). A simulated cell with
    an overview camera (``create_workcell(..., overview_camera=True)``) searches and aligns
    coarsely with it, calibrated as ``truth.base_T_overview_cam`` unless
    ``base_T_overview_cam`` is given. Raises ServoError (the robot stopped) if a stage fails.
    """
    from robots.calibration_io import CalibrationResult, load_calibration

    if flange_T_cam is None:
        truth = getattr(cell, "truth", None)
        if truth is None or getattr(truth, "nominal_flange_T_cam", None) is None:
            raise ValueError("give flange_T_cam: the hand-eye calibration of the wrist camera")
        flange_T_cam = truth.nominal_flange_T_cam
    elif isinstance(flange_T_cam, (str, bytes)) or hasattr(flange_T_cam, "__fspath__"):
        flange_T_cam = load_calibration(flange_T_cam).pose
    elif isinstance(flange_T_cam, CalibrationResult):
        flange_T_cam = flange_T_cam.pose
    if square_m is None:
        square_m = 0.03 if cell.robot.name == "cobotta" else 0.05
    options = {**ARM_OPTIONS.get(cell.robot.name, {}), **options}
    overview = getattr(cell, "cameras", {}).get("overview")
    if overview is not None and options.get("overview_camera") is None:
        options["overview_camera"] = overview
        if options.get("base_T_overview_cam") is None:
            options["base_T_overview_cam"] = cell.truth.base_T_overview_cam
    controller = StagedPickAndPlace(cell, flange_T_cam, square_m, method, **options)
    try:
        return controller.run(from_square, to_square)
    except BaseException:
        cell.robot.stop()
        raise
