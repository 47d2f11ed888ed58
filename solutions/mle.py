"""Maximum-likelihood hand-eye calibration: absolute poses, and raw image corners.

Both estimators fit the hand-eye pose X *together with* the fixed pose Y of the board, so each
view is used once, as measured, rather than differenced into motions (which doubles the noise
and correlates neighbouring equations, the weakness of the AX = XB closed forms):

* eye_in_hand: ``X = flange_T_cam``, ``Y = base_T_target`` and
  ``base_T_flange_i @ X @ cam_T_target_i == Y``,
* eye_to_hand: ``X = base_T_cam``, ``Y = flange_T_target`` and
  ``base_T_flange_i @ Y == X @ cam_T_target_i``.

In both, the camera should see the board at ``cam_T_target_i = inv(X) @ H_i @ Y`` with
``H_i = inv(base_T_flange_i)`` (eye-in-hand) or ``H_i = base_T_flange_i`` (eye-to-hand).

``refine_hand_eye`` compares that prediction with the measured ``cam_T_target_i`` (the
solvePnP result): per pose a 6-vector, the rotation vector (rad) of ``R_meas @ R_pred^T`` and
the translation difference ``t_meas - t_pred`` (m), both in the camera frame, weighted by the
inverse of their covariance. The covariance is a sum of parts with unknown scales (variance
components): the camera's noise, isotropic (a pose tracker) or shaped like a solvePnP pose of a
flat board (depth and tilt several times worse than the rest, see ``_planar_target_shape``);
isotropic translation noise; and the robot's rotation noise, which moves the predicted board
by the lever arm from the flange to the board (a 0.001 rad wrist error is 1 mm at 1 m). The
scales, and which camera model fits, are estimated from the residuals by REML (restricted
maximum likelihood) unless given. A robust first fit sets aside suspect poses; each is named
an outlier, by index, only if the fitted noise model cannot explain it either.

``refine_reprojection`` minimises the corner reprojection error (pixels) instead: the exact
maximum-likelihood estimate under pixel noise when the robot poses are accurate.

Relation to OpenCV: ``cv2.calibrateHandEye`` takes (gripper2base, target2cam) =
(``base_T_flange``, ``cam_T_target``) for eye-in-hand and returns cam2gripper = ``flange_T_cam``
(= X here); for eye-to-hand it takes base2gripper = ``inv(base_T_flange)`` and returns
cam2base = ``base_T_cam`` (= X here). This module takes ``base_T_flange`` as is for both mounts.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist
from scipy.stats import f as f_dist

from robots import geometry as geo
from solutions import ax_yb_closed_forms as closed_forms
from solutions import diagnostics, units

__all__ = [
    "MOUNTS",
    "NOISE_MODELS",
    "OUTLIER_CHI2",
    "POSE_CANDIDATES",
    "ROBOT_WEIGHT_FRACTIONS",
    "CornerNoiseChoice",
    "HandEyeRefinement",
    "calibrate_from_corners",
    "check_corner_inputs",
    "fit_candidate",
    "pnp_poses",
    "cramer_rao_covariance",
    "pose_residuals",
    "refine_hand_eye",
    "refine_reprojection",
]

MOUNTS = ("eye_in_hand", "eye_to_hand")

#: A pose is a suspect when its squared normalised residual (chi-square with 6 degrees of
#: freedom for a good pose) exceeds this under the first, isotropic fit: the 99.99 % quantile.
OUTLIER_CHI2 = 27.86
#: The final outlier test uses the same 99.99 % level, on the law the statistic follows when the
#: noise is estimated from the same poses (see ``_outlier_limit``).
_OUTLIER_LEVEL = 0.9999
#: Scale of the robust loss on the squared normalised pose residual: the 95 % quantile of
#: chi-square(6), so good poses keep most of their weight.
LOSS_SCALE_CHI2 = 12.59
#: Camera-side noise models of ``refine_hand_eye`` ("auto" picks one by likelihood).
NOISE_MODELS = ("auto", "isotropic", "planar_target")
#: Half-width of the virtual board that shapes a PnP pose's covariance, as a fraction of the
#: viewing distance (a board filling a fair part of the image); see ``_planar_target_shape``.
_BOARD_HALF_WIDTH = 0.2
#: The noise model is re-estimated until its variances move by less than this fraction and the
#: board's middle by less than _SHIFT_TOL_M: weights a few per cent off cost no accuracy.
_NOISE_TOL = 0.1
_SHIFT_TOL_M = 0.01
_MAD_TO_SIGMA = 1.4826
_SIGMA_FLOOR_RAD = 1e-12
_SIGMA_FLOOR_M = 1e-12
#: Fewest views ``refine_reprojection(fit_intrinsics=True)`` accepts (Zhang's calibration needs
#: 3 views of a plane for a full K; one more leaves redundancy for the hand-eye pose).
_MIN_VIEWS_INTRINSICS = 4


@dataclass
class HandEyeRefinement:
    """Result of ``refine_hand_eye`` / ``refine_reprojection``.

    X, Y: the hand-eye pose and the board pose, (4, 4), metres (meaning depends on ``mount``:
    see the module docstring). ``rotation_sigma_rad`` / ``translation_sigma_m``: the camera-side
    noise standard deviations per axis used to weight the residuals (given or estimated);
    ``robot_rotation_sigma_rad``: the robot rotation noise used for the lever-arm term.
    ``weights``: the robust loss's weight of each pose (1 = full, near 0 = rejected);
    ``outlier_indices``: poses whose normalised residual exceeds ``OUTLIER_CHI2``.
    ``cost``: final value of the (robust) objective; ``n_iterations``: Gauss-Newton steps in
    all; ``converged``: whether the last solve met its tolerance before ``max_iter``.
    ``reprojection_rms_px``: RMS corner reprojection error (pixels) when corners were used,
    ``pixel_sigma_px`` the corner noise estimated from it. ``per_pose_chi2``: each pose's
    squared normalised residual (pose-based) or RMS reprojection error in pixels (corners).
    ``noise_model``: the camera-side noise model ``refine_hand_eye`` used ("isotropic" or
    "planar_target"); with "planar_target", ``rotation_sigma_rad`` is 0 (the PnP shape
    replaces it) and ``image_sigma_rad`` is the fitted scale of that shape: the corner noise in
    normalised image coordinates (pixels / focal length) of the virtual board that explains
    the residuals. It grows in proportion to the real pixel noise, but equals it only for a
    board like the virtual one (16 corners spanning 40 % of the viewing distance).
    ``board_scale``: the factor fitted on the board's stated corner positions (1 unless
    ``refine_reprojection(fit_board_scale=True)``). ``camera_matrix`` / ``dist_coeffs``: the
    intrinsics refined with the hand-eye fit (``refine_reprojection(fit_intrinsics=True)``),
    None when the given ones were kept; ``predicted_corners`` uses them when set.
    """

    X: np.ndarray
    Y: np.ndarray
    mount: str
    rotation_sigma_rad: float
    translation_sigma_m: float
    weights: np.ndarray
    outlier_indices: tuple[int, ...]
    cost: float
    n_iterations: int
    converged: bool
    robot_rotation_sigma_rad: float = 0.0
    reprojection_rms_px: float | None = None
    pixel_sigma_px: float | None = None
    per_pose_chi2: np.ndarray = field(default_factory=lambda: np.zeros(0))
    noise_model: str = "isotropic"
    image_sigma_rad: float | None = None
    board_scale: float = 1.0
    camera_matrix: np.ndarray | None = None
    dist_coeffs: np.ndarray | None = None

    @property
    def outlier_pose_indices(self) -> tuple[int, ...]:
        """Alias of ``outlier_indices`` (the name the benchmark and catalogue read)."""
        return self.outlier_indices


# --------------------------------------------------------------------------- shared pieces


def _check_mount(mount: str) -> None:
    diagnostics.check_choice(mount, "mount", MOUNTS)


def _validate(base_T_flange, cam_T_target, mount: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated (N, 4, 4) robot and camera poses; degeneracy checked as for AX = YB, and
    inverted or mis-paired poses refused (``solutions.diagnostics``)."""
    _check_mount(mount)
    A, C = closed_forms.validate_ax_yb(base_T_flange, cam_T_target, "base_T_flange",
                                       "cam_T_target")
    diagnostics.check_hand_eye_poses(A, C, mount)
    return A, C


def _rotation_sigma(value, name: str, allow_none: bool = False):
    """A rotation noise level in radians: a finite number >= 0 (None if ``allow_none``), and no
    more than pi (a larger one was given in degrees)."""
    value = diagnostics.check_number(value, name, minimum=0.0, unit="radians",
                                     allow_none=allow_none)
    return value if value is None else units.check_radians(value, name)


def _sigma_pair(value, name: str, positive: bool) -> np.ndarray:
    """(rotation_rad, translation_m) noise levels: finite, > 0 (``positive``) or >= 0, and the
    rotation no more than pi."""
    bound = "> 0" if positive else ">= 0"
    expected = (f"(rotation_rad, translation_m), both finite and {bound}, e.g. "
                "(np.radians(0.1), 0.0005)")
    sigma = diagnostics.as_array(value, name, expected)
    if sigma.shape != (2,) or not np.all(np.isfinite(sigma)) or np.any(
            sigma <= 0 if positive else sigma < 0):
        raise ValueError(f"{name} must be {expected}; or None to estimate them from the data; "
                         f"got {value!r}")
    units.check_radians(float(sigma[0]), f"{name}[0] (rotation)")
    return sigma


def _chain(A: np.ndarray, mount: str) -> np.ndarray:
    """H_i with cam_T_target_i = inv(X) @ H_i @ Y."""
    return geo.invert(A) if mount == "eye_in_hand" else A


def _initial_guess(A, C, mount, X0, Y0) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) to start from: given ones, the other one averaged from them, or Li's AX = YB."""
    H = _chain(A, mount)
    if X0 is None and Y0 is None:
        if mount == "eye_in_hand":
            return closed_forms.li_closed_form(A, geo.invert(C))
        flange_T_target, base_T_cam = closed_forms.li_closed_form(A, C)
        return base_T_cam, flange_T_target
    if X0 is not None:
        X0 = geo.as_pose(X0, "X0")
    if Y0 is not None:
        Y0 = geo.as_pose(Y0, "Y0")
    if Y0 is None:
        # Every view gives Y = inv(H_i) @ X @ C_i; average them.
        Y0 = _average_poses(geo.invert(H) @ X0 @ C)
    if X0 is None:
        # Every view gives X = H_i @ Y @ inv(C_i).
        X0 = _average_poses(H @ Y0 @ geo.invert(C))
    return X0, Y0


def _average_poses(T: np.ndarray) -> np.ndarray:
    return geo.make_pose(geo.chordal_mean_rotation(T), T[:, :3, 3].mean(axis=0))


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices of (N, 3) vectors."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _so3_log_and_inv_jacobian(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors r of (N, 3, 3) rotations and J_r^{-1}(r), the inverse right Jacobian:
    exp(r) @ exp(-phi) = exp(r - J_r^{-1}(r) phi) to first order in phi."""
    # log by atan2(sin, cos) of the antisymmetric part and the trace: accurate near 0 where
    # residuals live, and several times faster than Rotation.from_matrix for small stacks.
    v = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0],
                        R[:, 1, 0] - R[:, 0, 1]], axis=1)
    sin = np.linalg.norm(v, axis=1)
    cos = 0.5 * (R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2] - 1.0)
    theta = np.arctan2(sin, cos)
    if np.any(cos < -0.99):  # near 180 deg the antisymmetric part loses the axis
        r = Rotation.from_matrix(R).as_rotvec()
        theta = np.linalg.norm(r, axis=-1)
    else:
        r = v * np.where(sin > 1e-12, theta / np.maximum(sin, 1e-300), 1.0)[:, None]
    S = _skew(r)
    small = theta < 1e-6
    th = np.where(small, 1.0, theta)
    # 1/theta^2 - (1 + cos)/(2 theta sin), -> 1/12 as theta -> 0.
    c = np.where(small, 1.0 / 12.0, 1.0 / th**2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th)))
    Jinv = np.eye(3) + 0.5 * S + c[:, None, None] * (S @ S)
    return r, Jinv


def pose_residuals(X, Y, base_T_flange, cam_T_target, mount: str = "eye_in_hand"):
    """Per-pose residuals of measured ``cam_T_target`` against the prediction from X and Y.

    Returns (rotation (N, 3) rad, translation (N, 3) m): the rotation vector of
    ``R_meas @ R_pred^T`` and ``t_meas - t_pred``, both in the camera frame, with
    ``cam_T_target_pred_i = inv(X) @ H_i @ Y`` (see the module docstring).
    """
    _check_mount(mount)
    A = geo.as_poses(base_T_flange, "base_T_flange")
    C = geo.as_poses(cam_T_target, "cam_T_target")
    if len(A) != len(C):
        raise ValueError(f"base_T_flange has {len(A)} poses but cam_T_target has {len(C)}")
    X, Y = geo.as_pose(X, "X"), geo.as_pose(Y, "Y")
    P = geo.invert(X) @ _chain(A, mount) @ Y
    rot = Rotation.from_matrix(C[:, :3, :3] @ np.swapaxes(P[:, :3, :3], 1, 2)).as_rotvec()
    return rot, C[:, :3, 3] - P[:, :3, 3]


# --------------------------------------------------------------------------- pose-based MLE


class _PoseProblem:
    """Residuals, Jacobian and weights of the pose-based objective, vectorised over poses.

    State: Z = inv(X) (cam_T_flange or cam_T_base) and Y. Perturbations:
    Z <- [exp(phi_z), rho_z] @ Z (left, camera frame) and Y <- Y @ [exp(phi_y), rho_y] (right),
    12 parameters in the order (phi_z, rho_z, phi_y, rho_y).
    """

    def __init__(self, A, C, mount):
        self.A, self.C, self.mount = A, C, mount
        self.H = _chain(A, mount)
        self.R_meas, self.t_meas = C[:, :3, :3], C[:, :3, 3]

    def predict(self, Z, Y):
        return Z @ self.H @ Y

    def residuals(self, Z, Y):
        """(r (N, 6), J_r^{-1} (N, 3, 3), predicted poses (N, 4, 4))."""
        P = self.predict(Z, Y)
        r_rot, Jinv = _so3_log_and_inv_jacobian(self.R_meas @ np.swapaxes(P[:, :3, :3], 1, 2))
        return np.concatenate([r_rot, self.t_meas - P[:, :3, 3]], axis=1), Jinv, P

    def jacobian(self, P, Jinv):
        n = len(P)
        R_p, t_p = P[:, :3, :3], P[:, :3, 3]
        J = np.zeros((n, 6, 12))
        J[:, :3, 0:3] = -Jinv
        J[:, 3:, 0:3] = _skew(t_p)
        J[:, 3:, 3:6] = -np.eye(3)
        J[:, :3, 6:9] = -Jinv @ R_p
        J[:, 3:, 9:12] = -R_p
        return J

    def lever_arms(self, Z, P):
        """Flange origin -> board origin, in camera axes (m), per pose (N, 3)."""
        if self.mount == "eye_in_hand":
            flange_in_cam = np.broadcast_to(Z[:3, 3], (len(P), 3))
        else:
            flange_in_cam = self.A[:, :3, 3] @ Z[:3, :3].T + Z[:3, 3]
        return P[:, :3, 3] - flange_in_cam



def _planar_target_shape(C: np.ndarray) -> np.ndarray | None:
    """Covariance shape (N, 6, 6) of solvePnP poses of a flat board, per unit image noise.

    A pose found by PnP on a flat board is far from isotropic: depth and tilt come from the
    board's apparent size and foreshortening, so they are several times worse than the
    sideways position and the roll, and the origin (a corner of the board) inherits the tilt
    error through its offset from the board's middle. The board itself is not passed in, so the
    shape is built for a virtual one: a 4 x 4 grid in the target plane z = 0, centred where the
    optical axes meet that plane (median over views: a camera looks at the board) and
    ``2 * _BOARD_HALF_WIDTH`` times the viewing distance wide. Each view's Fisher information
    of its corner directions (normalised image coordinates, pixels / focal length, unit noise)
    is inverted into the covariance of ``_PoseProblem``'s residual (rotation vector and
    translation in camera axes). Only the shape is used; its scale, (pixel noise / focal
    length)^2, is estimated from the residuals, and the weights change little if the real board
    is half or twice the assumed size.

    Returns None when the poses do not look like views of a board in its z = 0 plane (most
    optical axes miss the plane, or a virtual corner would lie behind a camera).
    """
    R, t = C[:, :3, :3], C[:, :3, 3]
    eye = -np.einsum("nji,nj->ni", R, t)  # camera centre in target coordinates
    axis = R[:, 2, :]                      # optical axis in target coordinates
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = -eye[:, 2] / axis[:, 2]    # distance along the axis to the plane z = 0
    ahead = np.isfinite(reach) & (reach > 0)
    if 2 * ahead.sum() <= len(C):
        return None
    middle = np.median(eye[ahead, :2] + reach[ahead, None] * axis[ahead, :2], axis=0)
    half = _BOARD_HALF_WIDTH * float(np.median(reach[ahead]))
    grid = np.linspace(-half, half, 4)
    gx, gy = np.meshgrid(middle[0] + grid, middle[1] + grid)
    board = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    Rp = np.einsum("nij,kj->nki", R, board)  # (N, 16, 3) corner offsets from the origin
    p = Rp + t[:, None, :]
    if np.any(p[..., 2] < 0.1 * half):
        return None
    # d(x/z, y/z)/d p times d p/d(rotation, translation) = [-[R b]x, I].
    inv_z = 1.0 / p[..., 2]
    proj = np.zeros(p.shape[:2] + (2, 3))
    proj[..., 0, 0] = proj[..., 1, 1] = inv_z
    proj[..., :, 2] = -p[..., :2] * inv_z[..., None] ** 2
    D = np.empty(p.shape[:2] + (3, 6))
    D[..., :3] = -_skew(Rp)
    D[..., 3:] = np.eye(3)
    J = (proj @ D).reshape(len(C), -1, 6)
    return np.linalg.inv(np.swapaxes(J, 1, 2) @ J)


def _unit_parts(e: np.ndarray, camera_shape: np.ndarray | None) -> np.ndarray:
    """The unit covariance parts (3, N, 6, 6) of the pose residual, in camera axes.

    0: camera noise, isotropic rotation (a pose tracker; ``camera_shape`` None) or the
       planar-target PnP shape ``camera_shape``;
    1: isotropic translation (camera and robot translation noise together; robot translation
       noise stays isotropic in any frame);
    2: robot rotation noise delta, which moves the predicted board as (rotation, translation)
       = (delta, -[e]x delta), e being the flange-to-board lever arm in camera axes.
    """
    n = len(e)
    parts = np.zeros((3, n, 6, 6))
    if camera_shape is None:
        parts[0, :, :3, :3] = np.eye(3)
    else:
        parts[0] = camera_shape
    parts[1, :, 3:, 3:] = np.eye(3)
    Se = _skew(e)
    parts[2, :, :3, :3] = np.eye(3)
    parts[2, :, :3, 3:] = Se
    parts[2, :, 3:, :3] = np.swapaxes(Se, 1, 2)
    parts[2, :, 3:, 3:] = Se @ np.swapaxes(Se, 1, 2)
    return parts


def _covariance(variances: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Per-pose covariances sum_k v_k S_k, (N, 6, 6), from ``parts`` (K, N, 6, 6).

    One matrix product: np.tensordot costs several times more at this size."""
    return (np.asarray(variances, float) @ parts.reshape(len(parts), -1)).reshape(parts.shape[1:])


def _information(variances: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Per-pose information matrices inv(sum_k v_k S_k), (N, 6, 6)."""
    return np.linalg.inv(_covariance(variances, parts))


def _shift_parts(parts: np.ndarray, shift, board_axes) -> np.ndarray:
    """``parts`` with the camera part (0) moved to a board centred ``shift`` (m, along the
    target's x and y axes) away: residual (rho, tau) -> (rho, tau + [R d]x rho), R d being the
    shift in camera axes (``board_axes`` (N, 3, 2) = the target's x and y axes there)."""
    if board_axes is None or not np.any(shift):
        return parts
    T = np.broadcast_to(np.eye(6), (parts.shape[1], 6, 6)).copy()
    T[:, 3:, :3] = _skew(board_axes @ shift)
    return np.concatenate([(T @ parts[0] @ np.swapaxes(T, 1, 2))[None], parts[1:]])


def _reml_noise(parts, variances, r, J, keep, held=None, board_axes=None, shift=None,
                max_iter: int = 12, tol: float = _NOISE_TOL, likelihood: bool = True):
    """Noise model parameters by REML Fisher scoring at fixed residuals.

    The residual covariance of pose i is Sigma_i = sum_k v_k S_k,i (``parts``; see
    ``_unit_parts``). With ``board_axes`` given (planar-target model), the board's middle is a
    parameter too: the camera part is moved by ``shift`` d (m, in the target plane), which
    changes how the origin's translation error follows the tilt error (see
    ``_shift_parts``); it starts from the virtual board's centre and is fitted here, since
    where the camera looked is only a rough guess of it.

    Each step solves F dtheta = s with s_k = r'P D_k P r - tr(P D_k) and
    F_kl = tr(P D_k P D_l), D_k = d Sigma / d theta_k, P = W - W J H^-1 J' W (W = Sigma^-1,
    H = J' W J: the fit's 12 parameters use up part of the scatter). For the variances this
    is the iterated-MINQUE form of REML; a variance that would turn negative is held at a
    floor far below the residuals and the rest re-solved; those in ``held`` keep their value.
    A weak prior (standard deviation 0.5 m) keeps the shift defined when the data say nothing
    about it. Only the kept poses count.

    Returns (variances (K,), shift (2,), -2 log REML likelihood up to a constant (NaN unless
    ``likelihood``: only a comparison of models needs it), whether the steps converged within
    ``max_iter``).
    """
    base, rk, Jk = parts[:, keep], r[keep], J[keep]
    K, m = len(base), len(rk)
    axes = None if board_axes is None else board_axes[keep]
    n_shift = 0 if axes is None else 2
    # A component's "alone" scale: the variance that would explain the residuals by itself.
    alone = float(np.sum(rk**2)) / np.maximum(np.einsum("kmii->k", base), 1e-300)
    floor = 1e-8 * alone
    held = np.zeros(K, bool) if held is None else np.asarray(held, bool)
    v = np.where(held, variances, np.maximum(np.asarray(variances, float), floor))
    d = np.zeros(2) if shift is None else np.asarray(shift, float).copy()
    prior = 1.0 / 0.5**2
    Jf = Jk.reshape(-1, 12)

    frozen = np.concatenate([held, np.zeros(n_shift, bool)])
    lower = np.concatenate([floor, np.full(n_shift, -np.inf)])
    if n_shift:
        E = np.zeros((2, m, 6, 6))
        E[:, :, 3:, :3] = _skew(np.moveaxis(axes, 2, 0))

    def derivatives(v, d):
        if n_shift == 0:
            return base, base
        S = _shift_parts(base, d, axes)
        ES = v[0] * (E @ S[0])
        return S, np.concatenate([S, ES + np.swapaxes(ES, 2, 3)])

    converged = False
    last_step = np.zeros(2)
    for _ in range(max_iter):
        S, D = derivatives(v, d)
        W = np.linalg.inv(_covariance(v, S))
        WJ = W @ Jk
        WJ2 = WJ.reshape(-1, 12)
        Hinv = np.linalg.inv(Jf.T @ WJ2)
        Pr = (W @ rk[:, :, None])[:, :, 0] - WJ @ (Hinv @ (WJ2.T @ rk.reshape(-1)))
        G = (WJ2 @ Hinv).reshape(m, 6, 12) @ np.swapaxes(WJ, 1, 2)
        n_par = len(D)
        # Traces of products of symmetric blocks as dot products of the flattened arrays:
        # tr(A B) = sum(A * B') and D_k' = D_k.
        WD = W @ D
        DW = np.swapaxes(WD, 2, 3).reshape(n_par, -1)          # (W D_k)' = D_k W
        HM = Hinv @ (WJ2.T @ (D @ WJ).reshape(n_par, -1, 12))  # H^-1 J'W D_k W J
        F = ((WD - 2.0 * (G @ D)).reshape(n_par, -1) @ DW.T
             + np.einsum("kab,lba->kl", HM, HM))
        Df = D.reshape(n_par, -1)
        score = Df @ (Pr[:, :, None] * Pr[:, None, :] - W + G).reshape(-1)
        theta = np.concatenate([v, d[:n_shift]])
        if n_shift:
            F[K:, K:] += 2.0 * prior * np.eye(2)
            score[K:] -= 2.0 * prior * d
        new = _bounded_solve(F, F @ theta + score, lower, frozen, theta)
        new_v, new_d = new[:K], (new[K:] if n_shift else d)
        if n_shift:
            # Fisher scoring can overshoot on the shift: cap its step, and halve the whole
            # step when the shift turns back (the steps were zigzagging).
            step = new_d - d
            size = float(np.linalg.norm(step))
            if step @ last_step < 0:
                new_v, new_d = 0.5 * (v + new_v), d + 0.5 * step
            else:
                new_d = d + step * min(1.0, 0.05 / max(size, 1e-300))
            last_step = new_d - d
        # A variance below a hundredth of its "alone" scale hardly weighs; its wobble is ignored.
        moved = np.max(np.abs(new_v - v) / np.maximum(np.maximum(new_v, v), 1e-2 * alone))
        if n_shift:
            moved = max(moved, tol * float(np.max(np.abs(new_d - d))) / _SHIFT_TOL_M)
        v, d = new_v, new_d
        if moved < tol:
            converged = True
            break
    if not likelihood:
        return v, d, math.nan, converged
    S = _shift_parts(base, d, axes)
    cov = _covariance(v, S)
    W = np.linalg.inv(cov)
    WJ2 = (W @ Jk).reshape(-1, 12)
    H = Jf.T @ WJ2
    g = WJ2.T @ rk.reshape(-1)
    quad = float(np.einsum("mi,mij,mj->", rk, W, rk) - g @ np.linalg.solve(H, g))
    m2ll = float(np.sum(np.linalg.slogdet(cov)[1]) + np.linalg.slogdet(H)[1] + quad)
    if n_shift:
        m2ll += prior * float(d @ d)
    return v, d, m2ll, converged


@lru_cache(maxsize=512)
def _outlier_limit(n_directions: int, n_kept: int, n_noise_parameters: int) -> float:
    """Threshold of the outlier test (``_outliers``) for a pose tested in ``n_directions`` directions.

    With known noise the statistic of a good pose is chi-square(k) (k = 6: ``OUTLIER_CHI2``,
    its 99.99 % point). When the noise is estimated from the same data it is k F(k, dof)
    instead, dof = 6 n_kept - 12 - n_noise_parameters: heavier-tailed with few poses, so the
    same 99.99 % point lies higher (about 37 for 10 poses, 31 for 20).
    """
    if n_directions == 0:
        return np.inf
    if n_noise_parameters == 0:
        return float(chi2_dist.ppf(_OUTLIER_LEVEL, n_directions))
    dof = 6 * n_kept - 12 - n_noise_parameters
    if dof <= 0:
        return np.inf
    return float(n_directions * f_dist.ppf(_OUTLIER_LEVEL, n_directions, dof))


def _outliers(r, cov, J, keep, n_noise_parameters: int) -> np.ndarray:
    """Which poses fail the outlier test (statistic above its threshold), (N,) bool.

    Each pose's residual is normalised by its covariance *allowing for the fit*. A pose inside
    the fit pulled the fit towards itself (residual covariance Sigma_i - J_i H^-1 J_i'); one
    left out did not, and the fit's own error adds to its residual (Sigma_i + J_i H^-1 J_i'),
    H being the information of the kept poses. Either way the statistic of a good pose follows
    the same law, so a pose set aside early is judged fairly when it is tested again.
    Directions in which a kept pose retains less than 5 % of its own noise variance (it largely
    decides the fit there) cannot show an error and are left out of its test.
    """
    info = np.linalg.inv(cov)
    WJ = info[keep] @ J[keep]
    Hinv = np.linalg.inv(J[keep].reshape(-1, 12).T @ WJ.reshape(-1, 12))
    fit = J @ Hinv @ np.swapaxes(J, 1, 2)
    Q = np.where(keep[:, None, None], cov - fit, cov + fit)
    # Whitened by Sigma_i, Q's eigenvalues are the share of the noise left in each direction.
    Linv = np.linalg.inv(np.linalg.cholesky(cov))
    lam, U = np.linalg.eigh(Linv @ Q @ np.swapaxes(Linv, 1, 2))
    proj = np.einsum("nji,nj->ni", U, (Linv @ r[:, :, None])[:, :, 0])
    usable = lam > 0.05
    stat = np.sum(np.where(usable, proj**2 / np.where(usable, lam, 1.0), 0.0), axis=1)
    n_kept = int(keep.sum())
    limit = np.array([_outlier_limit(int(k), n_kept, n_noise_parameters) for k in usable.sum(axis=1)])
    return stat > limit


def _solve_small(A: list, b: list) -> list:
    """x with A x = b for a system of a handful of unknowns (lists of floats): Gaussian
    elimination with partial pivoting, as LAPACK's gesv does. Plain floats, because the REML
    steps solve one such system per iteration and numpy's per-call overhead was most of the
    cost. ``np.linalg.LinAlgError`` when A is singular."""
    n = len(b)
    M = [list(row) + [b[i]] for i, row in enumerate(A)]
    for c in range(n):
        p = max(range(c, n), key=lambda i: abs(M[i][c]))
        if M[p][c] == 0.0:
            raise np.linalg.LinAlgError("singular matrix")
        M[c], M[p] = M[p], M[c]
        for i in range(c + 1, n):
            f = M[i][c] / M[c][c]
            if f:
                M[i] = [a - f * u for a, u in zip(M[i], M[c])]
    x = [0.0] * n
    for i in reversed(range(n)):
        x[i] = (M[i][n] - sum(M[i][j] * x[j] for j in range(i + 1, n))) / M[i][i]
    return x


def _bounded_solve(F, rhs, lower, held, held_value) -> np.ndarray:
    """Solve F x = rhs for the entries not ``held`` (those keep ``held_value``), holding at
    ``lower`` any that would fall below it and re-solving the rest."""
    if not np.any(held):  # the common case: one solve, no bound reached
        try:
            x = np.linalg.solve(F, rhs)
            if np.all(x >= lower):
                return x
        except np.linalg.LinAlgError:
            pass
    F, rhs, lower = np.asarray(F).tolist(), np.asarray(rhs).tolist(), np.asarray(lower).tolist()
    held, held_value = np.asarray(held).tolist(), np.asarray(held_value).tolist()
    n = len(rhs)
    fixed = list(held)
    x = list(held_value)  # all held when no entry is free: the return below takes held_value
    for _ in range(n):
        free = [i for i in range(n) if not fixed[i]]
        if not free:
            break
        x = [held_value[i] if held[i] else (lower[i] if fixed[i] else 0.0) for i in range(n)]
        pinned = [j for j in range(n) if fixed[j]]
        try:
            solution = _solve_small([[F[i][j] for j in free] for i in free],
                                    [rhs[i] - sum(F[i][j] * x[j] for j in pinned) for i in free])
        except np.linalg.LinAlgError:
            solution = [max(lower[i], 0.0) for i in free]
        for i, value in zip(free, solution):
            x[i] = value
        low = [i for i in free if x[i] < lower[i]]
        if not low:
            break
        for i in low:
            fixed[i] = True
    return np.array([held_value[i] if held[i] else max(x[i], lower[i]) for i in range(n)])


def _loss(z2: np.ndarray, loss: str | None) -> tuple[np.ndarray, np.ndarray]:
    """(rho, weight) of squared normalised pose residuals z2 for a robust loss scaled to
    ``LOSS_SCALE_CHI2``; rho is in the units of z2 and weight = d rho / d z2."""
    s = z2 / LOSS_SCALE_CHI2
    w = closed_forms.loss_weights(s, loss)
    if loss in (None, "linear"):
        rho = s
    elif loss == "huber":
        rho = np.where(s <= 1.0, s, 2.0 * np.sqrt(np.maximum(s, 1.0)) - 1.0)
    elif loss == "soft_l1":
        rho = 2.0 * (np.sqrt(1.0 + s) - 1.0)
    else:  # cauchy
        rho = np.log1p(s)
    return rho * LOSS_SCALE_CHI2, w


def _normal_equations(J, info, r, w):
    """H = sum_i w_i J_i' W_i J_i and g = sum_i w_i J_i' W_i r_i, as two matrix products."""
    WJ = (info @ J) * w[:, None, None]
    H = J.reshape(-1, 12).T @ WJ.reshape(-1, 12)
    g = WJ.reshape(-1, 12).T @ r.reshape(-1)
    return H, g


def _chi2(r, info):
    """Squared normalised residual r_i' W_i r_i per pose."""
    return np.einsum("ni,ni->n", r, (info @ r[:, :, None])[:, :, 0])


def _gauss_newton(problem, Z, Y, info, loss, max_iter, keep, tol=1e-10):
    """Levenberg-Marquardt on sum_i keep_i rho(r_i' W_i r_i), the loss by IRLS weights.

    Returns (Z, Y, cost, chi2 per pose, iterations, converged).
    """
    keep = keep.astype(float)

    def evaluate(Z, Y):
        r, Jinv, P = problem.residuals(Z, Y)
        z2 = _chi2(r, info)
        rho, w = _loss(z2, loss)
        return r, Jinv, P, z2, w * keep, float(rho @ keep)

    r, Jinv, P, z2, w, cost = evaluate(Z, Y)
    lam = 1e-6
    it = 0
    converged = False
    while it < max_iter:
        it += 1
        H, g = _normal_equations(problem.jacobian(P, Jinv), info, r, w)
        diag = np.diag(np.diag(H))
        # Gauss-Newton decrement: when even the undamped step would lower the cost by a
        # negligible fraction, the fit has converged; stop without another evaluation.
        gn_step = np.linalg.solve(H + 1e-12 * diag, -g)
        if -0.5 * (gn_step @ g) <= tol * max(cost, 1e-20):
            converged = True
            break
        while True:
            step = np.linalg.solve(H + lam * diag, -g)
            Zn = _exp_se3(step[0:3], step[3:6]) @ Z
            Yn = Y @ _exp_se3(step[6:9], step[9:12])
            rn, Jinv_n, Pn, z2n, w_n, cost_n = evaluate(Zn, Yn)
            if cost_n <= cost or lam > 1e8:
                break
            lam *= 10.0
        decrease = cost - cost_n
        if cost_n <= cost:
            Z, Y, r, Jinv, P, z2, w, cost = Zn, Yn, rn, Jinv_n, Pn, z2n, w_n, cost_n
            lam = max(lam / 10.0, 1e-9)
        if 0 <= decrease <= tol * max(cost, 1e-20) or np.abs(step).max() < 1e-15:
            converged = True
            break
    return Z, Y, cost, z2, it, converged


def _exp_se3(phi: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """The pose [exp(phi), rho] (rotation and translation decoupled)."""
    T = np.eye(4)
    theta = np.sqrt(phi @ phi)
    K = geo.skew(phi)
    if theta < 1e-8:
        T[:3, :3] += K + 0.5 * K @ K
    else:  # Rodrigues' formula; cheaper than building a scipy Rotation for one vector
        T[:3, :3] += np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta**2 * K @ K
    T[:3, 3] = rho
    return T


def _mad_sigma(values: np.ndarray) -> float:
    """Standard deviation of zero-mean normal values from their median absolute value."""
    return _MAD_TO_SIGMA * float(np.median(np.abs(values)))


def refine_hand_eye(base_T_flange, cam_T_target, mount: str = "eye_in_hand", X0=None, Y0=None,
                    robust: bool = True, max_iter: int = 50, sigma=None,
                    robot_rotation_sigma_rad: float | None = None,
                    loss: str = "cauchy", noise_model: str = "auto") -> HandEyeRefinement:
    """Maximum-likelihood hand-eye calibration from robot poses and board poses.

    Parameters
    ----------
    base_T_flange : (N, 4, 4) robot flange poses in the base frame, metres (OpenCV's
        gripper2base; NOT inverted for eye-to-hand, unlike ``cv2.calibrateHandEye``).
    cam_T_target : (N, 4, 4) board poses in the camera frame (solvePnP's rvec/tvec, OpenCV's
        target2cam).
    mount : "eye_in_hand" (X = flange_T_cam, Y = base_T_target) or "eye_to_hand"
        (X = base_T_cam, Y = flange_T_target).
    X0, Y0 : optional starting poses; by default Li's AX = YB closed form.
    robust : first fit with ``loss`` on each pose's normalised residual under isotropic noise
        levels from the medians; the poses whose squared normalised residual exceeds
        ``OUTLIER_CHI2`` there are suspects. Each suspect is tested again under the fitted
        noise model, allowing for the fit (``_outliers``), and dropped only if it fails that
        too; the rest are fitted by plain weighted least squares (as efficient as least
        squares when nothing is wrong). Dropped poses are ``outlier_indices``.
    max_iter : Levenberg-Marquardt steps per solve.
    sigma : (rotation_rad, translation_m): camera-side noise standard deviations per axis
        (robot translation noise may be folded into the translation), or None to estimate
        the noise from the residuals (REML variance components; see ``noise_model``).
    robot_rotation_sigma_rad : robot rotation noise per axis (rad); its effect on the
        predicted board grows with the flange-to-board lever arm. None estimates it with the
        other noise levels when ``sigma`` is None (and takes 0 when ``sigma`` is given).
    loss : robust loss of the first stage: "cauchy" (default), "soft_l1" or "huber".
    noise_model : shape of the camera-side noise when ``sigma`` is None. "isotropic": the
        same rotation and translation noise about every camera axis (a pose tracker, or poses
        perturbed as in OpenCV's test); "planar_target": poses from solvePnP on a flat board in
        the target's z = 0 plane, whose depth and tilt are much worse than the rest (see
        ``_planar_target_shape``; with 8 poses or more the board's middle is fitted too);
        "auto" (default) fits both and keeps the one with the higher REML likelihood
        (``HandEyeRefinement.noise_model`` says which). With fewer than 7 poses the robot's
        rotation noise is not estimated (too few residuals to tell it apart).

    Returns a ``HandEyeRefinement``. Raises ``ValueError`` for malformed or degenerate input
    (fewer than 3 poses, mismatched lengths, rotations about one axis only), for robot and
    camera translations in different units (``solutions.units``: e.g. the robot's in
    millimetres) and for a rotation noise level above pi (given in degrees).
    """
    A, C = _validate(base_T_flange, cam_T_target, mount)
    max_iter = diagnostics.check_number(max_iter, "max_iter", minimum=1, integer=True)
    robust = diagnostics.check_flag(robust, "robust")
    if robust:
        diagnostics.check_choice(loss, "loss", ("huber", "soft_l1", "cauchy"), "robust loss")
    diagnostics.check_choice(noise_model, "noise_model", NOISE_MODELS, "noise model")
    robot_rotation_sigma_rad = _rotation_sigma(robot_rotation_sigma_rad,
                                               "robot_rotation_sigma_rad", allow_none=True)
    estimate = sigma is None
    if not estimate:
        sigma = _sigma_pair(sigma, "sigma", positive=True)
    shape = None
    if estimate and noise_model != "isotropic":
        shape = _planar_target_shape(C)
        if shape is None and noise_model == "planar_target":
            raise ValueError(
                "noise_model='planar_target' needs cam_T_target from solvePnP on a flat board in "
                "the target's z = 0 plane, facing the cameras; these poses do not look like that "
                "(use noise_model='isotropic')")

    X, Y = _initial_guess(A, C, mount, X0, Y0)
    problem = _PoseProblem(A, C, mount)
    Z = geo.invert(X)
    n = len(A)
    keep = np.ones(n, bool)
    r, _, P = problem.residuals(Z, Y)
    e = problem.lever_arms(Z, P)

    # Isotropic noise levels (rotation, translation, robot rotation) to begin with: from the
    # medians of the residuals (which resist a bad view), or as given.
    if estimate:
        iso = np.array([max(_mad_sigma(r[:, :3]), _SIGMA_FLOOR_RAD) ** 2,
                        max(_mad_sigma(r[:, 3:]), _SIGMA_FLOOR_M) ** 2, 0.0])
        # Start the robot share at a tenth of the rotation noise; the estimation moves it.
        iso[2] = 0.1 * iso[0] if robot_rotation_sigma_rad is None else robot_rotation_sigma_rad**2
    else:
        iso = np.array([sigma[0] ** 2, sigma[1] ** 2, (robot_rotation_sigma_rad or 0.0) ** 2])

    total_it = 0
    converged = True
    # Stage 1: a first fit under isotropic noise levels from the medians, with the robust loss
    # if asked; then the levels again from the medians of the inliers. Any reasonable weighting
    # finds a gross error here; the poses it sets aside are only suspects, tested again below
    # under the fitted noise model. This fit need not be tight (a relative cost decrease of
    # 1e-4): REML sees its residuals only through P r, which a further move along J does not
    # change to first order, and stage 3 fits again to 1e-8. (Measured on 300 problems: the
    # same noise models and outliers as with 1e-6, X within 0.0004 deg / 0.003 mm.)
    info = _information(iso, _unit_parts(e, None))
    Z, Y, _, z2, total_it, converged = _gauss_newton(problem, Z, Y, info, loss if robust else None,
                                                     max_iter, keep, tol=1e-4)
    r, Jinv, P = problem.residuals(Z, Y)
    e = problem.lever_arms(Z, P)
    if robust and estimate:
        inl = z2 < OUTLIER_CHI2
        if inl.sum() < 3:
            inl[:] = True
        dof = np.sqrt(6 * inl.sum() / max(6 * inl.sum() - 12, 1))
        iso[:2] = [max(_mad_sigma(r[inl, :3]) * dof, _SIGMA_FLOOR_RAD) ** 2,
                   max(_mad_sigma(r[inl, 3:]) * dof, _SIGMA_FLOOR_M) ** 2]
    if robust:
        keep = _chi2(r, _information(iso, _unit_parts(e, None))) < OUTLIER_CHI2
        if keep.sum() < 3:
            keep[:] = True
    suspects = ~keep

    # Stage 2: the noise model. Estimate no more noise parameters than the poses support
    # (about 10 redundant residual components each): the robot's rotation noise from 7 poses
    # on, the board's middle from 8. Each candidate model gets its variances by REML on the
    # kept poses, and the one with the higher REML likelihood is kept. REML sees the residuals
    # only through P r, which a further move of the fit along J does not change, so these
    # estimates stand for the final fit unless the set of kept poses changes.
    redundancy = 6 * n - 12
    held = np.array([False, False, robot_rotation_sigma_rad is not None or redundancy < 30])
    if held[2] and robot_rotation_sigma_rad is None:
        iso[2] = 0.0
    chosen, variances, shift, axes = "isotropic", iso, np.zeros(2), None
    if estimate:
        J = problem.jacobian(P, Jinv)
        candidates = []
        if noise_model != "planar_target":
            candidates.append(("isotropic", None, iso))
        if shape is not None:
            # Start: the PnP shape alone explaining the camera side, a little of the rest.
            fisher = np.linalg.inv(shape[keep])
            scale = float(np.einsum("ni,nij,nj->", r[keep], fisher, r[keep])) / (6 * keep.sum())
            candidates.append(("planar_target", shape, np.array([scale, 0.1 * iso[1], iso[2]])))
        fitted = []
        for name, cam_shape, start in candidates:
            # Two steps tell the models apart (the same choice as after four on 299 of 300
            # problems, and the same medians); the chosen one is finished below.
            v, _, m2ll, done = _reml_noise(_unit_parts(e, cam_shape), start, r, J, keep, held,
                                           max_iter=2)
            fitted.append((m2ll, name, cam_shape, v, done))
        _, chosen, shape, variances, done = min(fitted, key=lambda f: f[0])
        estimated_on = keep
        if robust and suspects.any():
            # A suspect that either model explains is cleared and comes back before the last
            # estimate: on PnP poses with little noise the two can be close calls.
            for _, _, cam_shape, v, _ in fitted:
                cov = _covariance(v, _unit_parts(e, cam_shape))
                suspects &= _outliers(r, cov, J, keep, int(np.sum(~held)))
            keep = ~suspects
        if chosen == "planar_target" and redundancy >= 36:
            # With enough poses, where the board's middle lies is fitted too: the virtual
            # board's is only a guess.
            axes, done = C[:, :3, :2], False
        if not done or not np.array_equal(keep, estimated_on):
            variances, shift, _, _ = _reml_noise(_unit_parts(e, shape), variances, r, J, keep,
                                                 held, axes, max_iter=8, likelihood=False)
    else:
        shape = None

    def parts(e):
        return _shift_parts(_unit_parts(e, shape), shift, axes)

    n_noise_parameters = int(estimate) * (int(np.sum(~held)) + (0 if axes is None else 2))

    # Stage 3: weighted least squares under that model on the poses that are not outliers;
    # the suspects are tested again, and the noise re-estimated whenever the kept set changes.
    for _ in range(6):
        cov = _covariance(variances, parts(e))
        info = np.linalg.inv(cov)
        keep_changed = False
        if robust and suspects.any():
            r, Jinv, P = problem.residuals(Z, Y)
            new_keep = ~(suspects & _outliers(r, cov, problem.jacobian(P, Jinv), keep,
                                              n_noise_parameters))
            if new_keep.sum() < 3:
                raise ValueError(
                    f"only {int(new_keep.sum())} of {n} poses agree with each other; check that "
                    "base_T_flange and cam_T_target are paired in order and in the convention "
                    "this function expects (base_T_flange, not its inverse)")
            keep_changed = not np.array_equal(new_keep, keep)
            keep = new_keep
        Z, Y, _, z2, it, converged = _gauss_newton(problem, Z, Y, info, None, max_iter, keep,
                                                   tol=1e-8)
        total_it += it
        r, Jinv, P = problem.residuals(Z, Y)
        e = problem.lever_arms(Z, P)
        if not keep_changed and (estimate or variances[2] == 0.0):
            break
        if estimate:
            variances, shift, _, _ = _reml_noise(_unit_parts(e, shape), variances, r,
                                                 problem.jacobian(P, Jinv), keep, held, axes,
                                                 shift, likelihood=False)

    z2 = _chi2(r, _information(variances, parts(e)))
    outliers = tuple(int(i) for i in np.flatnonzero(~keep)) if robust else ()
    planar = chosen == "planar_target"
    return HandEyeRefinement(
        X=_clean(geo.invert(Z)), Y=_clean(Y), mount=mount,
        rotation_sigma_rad=0.0 if planar else float(np.sqrt(variances[0])),
        translation_sigma_m=float(np.sqrt(variances[1])),
        weights=keep.astype(float), outlier_indices=outliers, cost=float(z2[keep].sum()),
        n_iterations=total_it, converged=bool(converged),
        robot_rotation_sigma_rad=float(np.sqrt(variances[2])), per_pose_chi2=z2,
        noise_model=chosen, image_sigma_rad=float(np.sqrt(variances[0])) if planar else None,
    )


def cramer_rao_covariance(X, Y, base_T_flange, mount: str = "eye_in_hand", *,
                          rotation_sigma_rad: float, translation_sigma_m: float,
                          robot_rotation_sigma_rad: float = 0.0) -> np.ndarray:
    """The smallest covariance any unbiased estimate of X can have from these robot poses.

    The Cramer-Rao bound of the pose-based model of ``refine_hand_eye``: each measured
    ``cam_T_target_i`` is the prediction ``inv(X) @ H_i @ Y`` perturbed by independent noise,
    rotation ``R_meas = exp(w) @ R_pred`` with w ~ N(0, rotation_sigma_rad^2 I) in camera axes,
    translation ``t_meas = t_pred + v`` with v ~ N(0, translation_sigma_m^2 I) (m), plus robot
    rotation noise of ``robot_rotation_sigma_rad`` per axis carried by the flange-to-board lever
    arm. X and Y (see the module docstring for their meaning per ``mount``) are both unknown,
    so Y's uncertainty is paid for. Evaluate it at the true X and Y (synthetic data) or at an
    estimate (a first-order uncertainty of a real calibration).

    Returns the (6, 6) covariance of X's error delta = (rotation vector (rad), translation (m))
    with ``X_est = X @ [exp(delta_rot), delta_trans]``, i.e. in X's child frame (the camera).
    ``|delta_rot|`` is ``geometry.rotation_error_deg`` (in radians) and ``|delta_trans|`` is
    ``geometry.translation_error``. Raises ValueError when the poses do not determine X (the
    information matrix is singular: e.g. rotations about one axis only).
    """
    _check_mount(mount)
    A = geo.as_poses(base_T_flange, "base_T_flange", min_count=3)
    X, Y = geo.as_pose(X, "X"), geo.as_pose(Y, "Y")
    sigmas = np.array([diagnostics.check_number(v, name) for v, name in (
        (rotation_sigma_rad, "rotation_sigma_rad"), (translation_sigma_m, "translation_sigma_m"),
        (robot_rotation_sigma_rad, "robot_rotation_sigma_rad"))])
    units.check_radians(sigmas[0], "rotation_sigma_rad")
    units.check_radians(sigmas[2], "robot_rotation_sigma_rad")
    if not np.all(np.isfinite(sigmas)) or np.any(sigmas[:2] <= 0) or sigmas[2] < 0:
        raise ValueError("rotation_sigma_rad and translation_sigma_m must be finite and > 0 "
                         "(radians, metres); robot_rotation_sigma_rad finite and >= 0")
    problem = _PoseProblem(A, geo.invert(X) @ _chain(A, mount) @ Y, mount)
    Z = geo.invert(X)
    _, Jinv, P = problem.residuals(Z, Y)
    J = problem.jacobian(P, Jinv)
    info = _information(sigmas**2, _unit_parts(problem.lever_arms(Z, P), None))
    fisher = np.einsum("nji,njk,nkl->il", J, info, J)
    if np.linalg.cond(fisher) > 1e12:
        raise ValueError("these robot poses do not determine X (the Fisher information is "
                         "singular): rotate the flange about at least two different axes")
    # Z = inv(X) is perturbed on the left by (phi, rho), so X_est = X @ [exp(-phi), -rho] to
    # first order: the same covariance, in X's child frame.
    return np.linalg.inv(fisher)[:6, :6]


def _clean(T: np.ndarray) -> np.ndarray:
    """Re-orthonormalise the rotation block after many multiplications."""
    return geo.make_pose(geo.project_to_so3(T[:3, :3]), T[:3, 3])


# --------------------------------------------------------------------------- reprojection MLE


def _check_board(board_points) -> np.ndarray:
    expected = ("a finite (N, 3) array of board corners in the target frame (metres), N >= 4, "
                "e.g. Board.object_points()")
    P = diagnostics.as_array(board_points, "board_points", expected)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 4 or not np.all(np.isfinite(P)):
        what = f"shape {P.shape}" if P.ndim != 2 or P.shape[1] != 3 or len(P) < 4 else "NaN or inf"
        raise ValueError(f"board_points must be {expected}, got {what}")
    return P


def _check_intrinsics(K, dist) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(K, "fx") and hasattr(K, "K"):
        raise ValueError(
            f"K must be the (3, 3) camera matrix, got {diagnostics.describe(K)}: pass "
            "intrinsics.K and intrinsics.dist (K and dist are separate arguments)")
    K = diagnostics.as_array(K, "K", "a finite (3, 3) camera matrix in pixels")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 camera matrix with positive focal lengths, got {K}")
    dist = np.zeros(5) if dist is None else diagnostics.as_array(
        dist, "dist", "4, 5, 8, 12 or 14 OpenCV distortion coefficients, or None")
    if dist.ndim > 2 or (dist.ndim == 2 and min(dist.shape) != 1):
        raise ValueError(f"dist must be a vector of OpenCV distortion coefficients (k1, k2, p1, "
                         f"p2[, k3, ...]), got shape {dist.shape}")
    dist = dist.ravel()
    if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise ValueError(f"dist must hold 4, 5, 8, 12 or 14 finite OpenCV distortion "
                         f"coefficients (or be None), got {dist.size}")
    return K, dist


def check_corner_inputs(board_points, pixels, K, dist, n_views):
    """Validated ``(board_points (N, 3) m, pixels (n, N, 2) px, K (3, 3), dist)``; ``ValueError``
    naming the argument for a wrong shape, NaN board points, bad intrinsics or pixels given in
    normalised image coordinates."""
    P = _check_board(board_points)
    px = diagnostics.as_array(pixels, "pixels", "an (n_views, N, 2) array of corner pixels")
    if px.shape != (n_views, len(P), 2):
        raise ValueError(f"pixels must have shape (n_views, N, 2) = ({n_views}, {len(P)}, 2) to "
                         f"match base_T_flange and board_points, got {px.shape}; mark a corner "
                         "or view that was not seen with NaN")
    K, dist = _check_intrinsics(K, dist)
    # Normalised image coordinates (x/z, y/z) passed as pixels fit "converged" to a wrong pose.
    units.check_normalised_pixels(px, np.all(np.isfinite(px), axis=2), K)
    return P, px, K, dist


#: Intrinsics ``refine_reprojection(fit_intrinsics=True)`` refines, in this order: focal
#: lengths and principal point (pixels), then the first two radial distortion terms. The
#: tangential and higher radial terms stay as given: on 20-30 views tied to the robot they are
#: poorly determined and trade off against X.
INTRINSIC_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _with_intrinsics(K, dist, delta):
    """(K, dist) with ``delta`` (6,) added to (fx, fy, cx, cy, k1, k2)."""
    K, dist = K.copy(), dist.copy()
    K[0, 0] += delta[0]
    K[1, 1] += delta[1]
    K[0, 2] += delta[2]
    K[1, 2] += delta[3]
    dist[:2] += delta[4:6]
    return K, dist


def _reprojection_system(P, px, valid, K, dist, Z, Y, A, H, mount, views, w_view, noise,
                         fit_scale: bool = False, fit_intrinsics: bool = False):
    """Normal equations of the corner residuals with each view's robot error marginalised.

    Pixel residuals r (measured - projected) of view i are modelled as
    ``J_g dg + J_l xi_i + eps``: dg the 12 corrections of (Z, Y), xi_i = (u, v) the view's
    robot error in camera axes (rotation u about the flange origin, translation v) with prior
    N(0, diag(s_rr^2, s_rt^2)), eps ~ N(0, s_px^2) per pixel axis. Eliminating xi_i (Schur
    complement) gives the marginal likelihood's Gauss-Newton system over dg alone.

    With ``fit_scale`` a 13th parameter ds scales the board (``P`` is the board at its
    current scale s; s <- s (1 + ds)). With ``fit_intrinsics`` six more follow: additive
    corrections of ``INTRINSIC_PARAMETERS`` (OpenCV's own d pixel / d intrinsics).

    Returns (H (p, p), g (p,), marginal cost per view, raw squared residual per view,
    EM sufficient statistics (sum over views of E[|u|^2], E[|v|^2], E[|r - J_l xi|^2])),
    p = 12 + fit_scale + 6 fit_intrinsics.
    """
    s_px2, s_rr2, s_rt2 = noise
    n_geo = 13 if fit_scale else 12
    n = len(px)
    cost, raw = np.zeros(n), np.zeros(n)
    V = np.asarray(views)
    C = Z @ H[V] @ Y
    R, t = C[:, :3, :3], C[:, :3, 3]
    pc = np.einsum("vij,nj->vni", R, P) + t[:, None, :]        # corners in camera axes
    nv, npt = pc.shape[:2]
    # One projectPoints call for every view: with the identity pose, d pixel / d tvec is
    # d pixel / d (point in camera axes), the chain-rule factor each view needs.
    proj, jac = cv2.projectPoints(pc.reshape(-1, 3), np.zeros(3), np.zeros(3), K, dist)
    seen = valid[V][:, :, None]
    r = np.where(seen, px[V] - proj.reshape(nv, npt, 2), 0.0).reshape(nv, 2 * npt)
    dpdp = np.where(seen[..., None], jac[:, 3:6].reshape(nv, npt, 2, 3), 0.0)
    D = np.zeros((nv, npt, 3, n_geo))
    D[..., 0:3] = -_skew(pc)                                    # Z <- [exp(phi_z), rho_z] Z
    D[..., 3:6] = np.eye(3)
    D[..., 6:9] = -R[:, None] @ _skew(P)[None]                  # Y <- Y [exp(phi_y), rho_y]
    D[..., 9:12] = R[:, None]
    if fit_scale:
        D[..., 12] = pc - t[:, None, :]                         # s P <- s (1 + ds) P
    Jg = -(dpdp @ D).reshape(nv, 2 * npt, n_geo)
    if fit_intrinsics:
        # projectPoints' columns: rvec 0:3, tvec 3:6, (fx, fy) 6:8, (cx, cy) 8:10, dist 10:.
        dpdk = np.where(seen[..., None], jac[:, 6:12].reshape(nv, npt, 2, 6), 0.0)
        Jg = np.concatenate([Jg, -dpdk.reshape(nv, 2 * npt, 6)], axis=2)
    w = w_view[V]
    rr = np.einsum("vk,vk->v", r, r)
    raw[V] = rr
    Hgg = np.swapaxes(Jg, 1, 2) @ Jg / s_px2
    bg = (np.swapaxes(Jg, 1, 2) @ r[:, :, None])[:, :, 0] / s_px2
    if s_rr2 <= 0:
        cost[V] = rr / s_px2
        return (np.einsum("v,vpq->pq", w, Hgg), w @ bg, cost, raw,
                np.array([0.0, 0.0, float(rr.sum())]))
    prior = np.diag([1 / s_rr2] * 3 + [1 / s_rt2] * 3)
    # The flange origin in camera axes: the robot's rotation error turns about it.
    if mount == "eye_in_hand":
        flange = np.broadcast_to(Z[:3, 3], (nv, 3))
    else:
        flange = A[V, :3, 3] @ Z[:3, :3].T + Z[:3, 3]
    Dl = np.zeros((nv, npt, 3, 6))
    Dl[..., 0:3] = _skew(pc - flange[:, None, :])
    Dl[..., 3:6] = np.eye(3)
    Jl = -(dpdp @ Dl).reshape(nv, 2 * npt, 6)
    Hll_inv = np.linalg.inv(np.swapaxes(Jl, 1, 2) @ Jl / s_px2 + prior)
    Hlg = np.swapaxes(Jl, 1, 2) @ Jg / s_px2
    bl = (np.swapaxes(Jl, 1, 2) @ r[:, :, None])[:, :, 0] / s_px2
    HlgT_inv = np.swapaxes(Hlg, 1, 2) @ Hll_inv
    Hm = np.einsum("v,vpq->pq", w, Hgg - HlgT_inv @ Hlg)
    g = w @ (bg - np.einsum("vpq,vq->vp", HlgT_inv, bl))
    xi = np.einsum("vpq,vq->vp", Hll_inv, bl)
    cost[V] = rr / s_px2 - np.einsum("vp,vp->v", bl, xi)
    e = r - (Jl @ xi[:, :, None])[:, :, 0]
    stats = np.array([
        float(np.sum(xi[:, :3] ** 2) + np.trace(Hll_inv[:, :3, :3], axis1=1, axis2=2).sum()),
        float(np.sum(xi[:, 3:] ** 2) + np.trace(Hll_inv[:, 3:, 3:], axis1=1, axis2=2).sum()),
        float(np.sum(e * e) + np.sum((Jl @ Hll_inv) * Jl)),
    ])
    return Hm, g, cost, raw, stats


def refine_reprojection(board_points, pixels, K, dist, base_T_flange, mount: str = "eye_in_hand",
                        X0=None, Y0=None, robust: bool = True, max_iter: int = 50,
                        robot_sigma=None, fit_board_scale: bool = False,
                        fit_intrinsics: bool = False) -> HandEyeRefinement:
    """Hand-eye calibration by minimising the corner reprojection error (pixels).

    Corner j of view i is predicted at ``project(K, dist, inv(X) @ H_i @ Y @ board_points[j])``
    (OpenCV's pinhole + Brown distortion, ``cv2.projectPoints``) with
    ``H_i = inv(base_T_flange_i)`` for eye_in_hand (X = flange_T_cam, Y = base_T_target) and
    ``H_i = base_T_flange_i`` for eye_to_hand (X = base_T_cam, Y = flange_T_target). X and Y are
    fitted by Levenberg-Marquardt with the analytic Jacobian (OpenCV's d pixel / d point,
    chained by hand). The robot's own error in each view (rotation about the flange origin and
    translation) is a nuisance with a Gaussian prior, marginalised out, so a view that is
    shifted as a whole by robot error does not pull X; with exact robot poses this is the
    plain maximum-likelihood fit under pixel noise. The noise levels (pixels; robot rad and m)
    are estimated by expectation-maximisation unless ``robot_sigma`` = (rotation_rad,
    translation_m) is given ((0, 0) turns the nuisance off).

    Parameters: ``board_points`` (N, 3) corners in the target frame (m); ``pixels``
    (n_views, N, 2) detected corners in pixels, NaN where a corner or a whole view was not seen
    (skipped); ``K`` (3, 3) and ``dist`` (OpenCV order k1, k2, p1, p2[, k3...]);
    ``base_T_flange`` (n_views, 4, 4) as the controller reports it (not inverted for
    eye-to-hand); ``X0``, ``Y0`` a start, e.g. from ``refine_hand_eye`` on the solvePnP poses
    (both required). ``robust`` down-weights views whose RMS error is far above the median
    view's (Cauchy weights at 3 x the median) and reports views above 5 x the median by index.

    ``fit_board_scale`` also fits one factor s on ``board_points`` (a board printed a few per
    cent off its stated size: the PnP distances are then off by s but the robot's are not);
    the corners are then predicted at ``s * board_points`` (``board_scale`` of the result).

    ``fit_intrinsics`` also refines ``INTRINSIC_PARAMETERS`` (fx, fy, cx, cy in pixels; k1, k2),
    started from ``K`` and ``dist``, on the same corners: the views' camera poses are then tied
    to the robot's instead of free per view as in ``cv2.calibrateCamera``. No prior pulls them
    back to the start: hundreds of corners per view determine them, and a prior would need
    the start's covariance, which a caller's K does not carry. At least
    ``_MIN_VIEWS_INTRINSICS`` views are required. The refined intrinsics are returned as
    ``camera_matrix`` and ``dist_coeffs``; predict other views with them.

    Returns a ``HandEyeRefinement`` with ``reprojection_rms_px`` (inlier views, before the
    robot-error correction), ``pixel_sigma_px``, ``robot_rotation_sigma_rad``,
    ``board_scale``; its ``translation_sigma_m`` is the robot translation noise and
    ``rotation_sigma_rad`` 0.

    Refused with a ``ValueError`` naming the unit and the fix (``solutions.units``): normalised
    image coordinates passed as ``pixels`` with a pixel ``K``; a board and poses in different
    length units (the board's size in the image against its distance from X0, Y0 and the
    robot poses); a fitted board scale further than 30 times from 1; a rotation noise in
    ``robot_sigma`` above pi (degrees).
    """
    _check_mount(mount)
    A = geo.as_poses(base_T_flange, "base_T_flange")
    P, px, K, dist = check_corner_inputs(board_points, pixels, K, dist, len(A))
    if X0 is None or Y0 is None:
        raise ValueError("refine_reprojection needs a start X0 and Y0; get them from "
                         "refine_hand_eye(base_T_flange, cam_T_target, mount) on the solvePnP poses")
    X0, Y0 = geo.as_pose(X0, "X0"), geo.as_pose(Y0, "Y0")
    robust = diagnostics.check_flag(robust, "robust")
    max_iter = diagnostics.check_number(max_iter, "max_iter", minimum=1, integer=True)
    fit_board_scale = diagnostics.check_flag(fit_board_scale, "fit_board_scale")
    fit_intrinsics = diagnostics.check_flag(fit_intrinsics, "fit_intrinsics")
    if robot_sigma is not None:
        robot_sigma = _sigma_pair(robot_sigma, "robot_sigma", positive=False)
    valid = np.all(np.isfinite(px), axis=2)
    views = np.flatnonzero(valid.sum(axis=1) >= 4)
    if len(views) < 3:
        raise ValueError(f"only {len(views)} views have at least 4 corners seen; capture at least "
                         "3 views with the board (10-20 is typical)")
    closed_forms.check_rotation_variety(A[views, :3, :3], "base_T_flange (views with corners)")
    # A board in millimetres, or robot poses (or the start) in millimetres, against the rest in
    # metres: the board's size in the image says how far it is, the poses say it too.
    units.check_board_distance(P, px, valid, K, geo.invert(X0) @ _chain(A, mount) @ Y0)
    if fit_intrinsics and len(views) < _MIN_VIEWS_INTRINSICS:
        raise ValueError(f"fit_intrinsics needs at least {_MIN_VIEWS_INTRINSICS} views with "
                         f"corners, got {len(views)}: capture more views, or keep K and dist "
                         "fixed (fit_intrinsics=False)")
    px = np.where(valid[:, :, None], px, 0.0)
    counts = valid.sum(axis=1)
    H = _chain(A, mount)
    Z, Y = geo.invert(X0), Y0.copy()
    scale = 1.0
    w_view = np.zeros(len(A))
    w_view[views] = 1.0

    cam = (K, dist)
    n_geo = 13 if fit_board_scale else 12

    def system(Z, Y, w, noise, scale=1.0, cam=cam):
        return _reprojection_system(scale * P, px, valid, cam[0], cam[1], Z, Y, A, H, mount,
                                    views, w, noise, fit_board_scale, fit_intrinsics)

    def view_weights(raw):
        rms = np.sqrt(raw[views] / (2 * counts[views]))
        out = np.zeros(len(A))
        out[views] = 1.0 / (1.0 + (rms / (3.0 * max(float(np.median(rms)), 1e-12))) ** 2) if robust else 1.0
        return out

    # Start: pixel noise from the starting residuals, robot noise small against it.
    _, _, _, raw, _ = system(Z, Y, w_view, (1.0, 0.0, 0.0))
    s_px2 = max(float(raw[views].sum() / (2 * counts[views].sum())), 1e-24)
    if robot_sigma is None:
        noise = (s_px2, 1e-8, 1e-8)
    else:
        noise = (s_px2, robot_sigma[0] ** 2, robot_sigma[1] ** 2)
    estimate_robot = robot_sigma is None
    total_it = 0
    converged = False
    for _outer in range(8 if estimate_robot else 2):
        w_view = view_weights(raw)
        Hm, g, cost_v, raw, stats = system(Z, Y, w_view, noise, scale, cam)
        cost = float(w_view @ cost_v)
        lam = 1e-6
        converged = False
        for _ in range(max_iter):
            total_it += 1
            diag = np.diag(np.diag(Hm))
            gn_step = np.linalg.solve(Hm + 1e-12 * diag, -g)
            if -0.5 * (gn_step @ g) <= 1e-10 * max(cost, 1e-20):
                converged = True
                break
            while True:
                step = np.linalg.solve(Hm + lam * diag, -g)
                Zn = _exp_se3(step[0:3], step[3:6]) @ Z
                Yn = Y @ _exp_se3(step[6:9], step[9:12])
                scale_n = scale * (1.0 + step[12]) if fit_board_scale else scale
                cam_n = _with_intrinsics(*cam, step[n_geo:]) if fit_intrinsics else cam
                Hn, gn, cost_vn, rawn, statsn = system(Zn, Yn, w_view, noise, scale_n, cam_n)
                cost_n = float(w_view @ cost_vn)
                if cost_n <= cost or lam > 1e8:
                    break
                lam *= 10.0
            if cost_n > cost:
                converged = True
                break
            Z, Y, Hm, g, cost, raw, stats = Zn, Yn, Hn, gn, cost_n, rawn, statsn
            scale, cam = scale_n, cam_n
            lam = max(lam / 10.0, 1e-9)
        # EM update of the noise levels over the views in use.
        n_obs = 2 * counts[views].sum()
        n_views = len(views)
        n_fitted = 12 + (len(INTRINSIC_PARAMETERS) if fit_intrinsics else 0)
        new_px2 = max(stats[2] / max(n_obs - n_fitted, 1), 1e-24)
        if estimate_robot:
            new = (new_px2, max(stats[0] / (3 * n_views), 1e-16), max(stats[1] / (3 * n_views), 1e-16))
        else:
            new = (new_px2, noise[1], noise[2])
        moved = max(abs(np.sqrt(a / b) - 1) for a, b in zip(new, noise) if b > 0)
        noise = new
        if moved < 0.01:
            break

    if fit_board_scale:
        units.check_board_scale(scale)
    rms_view = np.zeros(len(A))
    rms_view[views] = np.sqrt(raw[views] / (2 * counts[views]))
    median_rms = float(np.median(rms_view[views]))
    outliers = tuple(int(i) for i in views if robust and rms_view[i] > 5.0 * max(median_rms, 1e-12))
    inl = np.array([i for i in views if i not in outliers])
    rms = float(np.sqrt(raw[inl].sum() / (2 * counts[inl].sum())))
    return HandEyeRefinement(
        X=_clean(geo.invert(Z)), Y=_clean(Y), mount=mount, rotation_sigma_rad=0.0,
        translation_sigma_m=float(np.sqrt(noise[2])), weights=w_view, outlier_indices=outliers,
        cost=float(cost), n_iterations=total_it, converged=converged,
        robot_rotation_sigma_rad=float(np.sqrt(noise[1])), reprojection_rms_px=rms,
        pixel_sigma_px=float(np.sqrt(noise[0])), per_pose_chi2=rms_view, board_scale=scale,
        camera_matrix=cam[0] if fit_intrinsics else None,
        dist_coeffs=cam[1] if fit_intrinsics else None,
    )


# --------------------------------------------------------------------------- noise model by CV


#: Robot-noise priors tried by ``calibrate_from_corners``, as fractions of the robot noise the
#: pose-based fit estimates: 0 is the pixel-only fit (best on the close KUKA views), 1 the fit
#: that trusts that estimate (best on textbook synthetic data, where the noise model is
#: exactly Gaussian robot and pixel noise), 0.1 in between (best on the far KUKA views).
ROBOT_WEIGHT_FRACTIONS = (0.0, 0.1, 1.0)
#: Pose-based candidates of ``calibrate_from_corners``: X and Y from the solvePnP poses alone,
#: the pixels used only to score them. ``"pose_mle"`` is ``refine_hand_eye`` (noise weights by
#: REML); ``"shah"`` and ``"li"`` are the AX = YB closed forms, which weight every view alike
#: and so hold up when the robot's error dominates (views far from the camera).
POSE_CANDIDATES = ("pose_mle", "shah", "li")
#: Views per inner fold are every k-th view, so views captured in runs stay spread over folds.
_CV_FOLDS = 3


@dataclass(frozen=True)
class CornerNoiseChoice:
    """One candidate model of ``calibrate_from_corners`` and its held-out score.

    ``method``: ``"reprojection"`` (``refine_reprojection`` on the corners) or one of
    ``POSE_CANDIDATES`` (a fit to the solvePnP poses). For ``"reprojection"``:
    ``robot_weight`` the fraction of the pose-based robot-noise estimate used as prior,
    ``robot_sigma`` that prior as (rotation rad, translation m) ((0, 0): pixel-only) and
    ``fit_board_scale`` whether the board's scale was a parameter; a pose-based candidate has
    ``robot_weight`` NaN, ``robot_sigma`` None and ``fit_board_scale`` False.
    ``fit_intrinsics``: whether the reprojection fit refined the camera's intrinsics.
    ``held_out_px``: geometric mean over the views of the RMS pixel error of each view's
    corners predicted by a fit that did not see it (inner K-fold cross-validation; inf when
    the candidate could not be fitted on some fold).
    """

    robot_weight: float
    robot_sigma: tuple[float, float] | None
    fit_board_scale: bool
    held_out_px: float
    method: str = "reprojection"
    fit_intrinsics: bool = False

    @property
    def label(self) -> str:
        """Short name, e.g. ``reprojection robot 0.1 x, board scale free`` or ``pose shah``."""
        if self.method != "reprojection":
            return f"pose {self.method}"
        scale = ", board scale free" if self.fit_board_scale else ""
        camera = ", intrinsics refined" if self.fit_intrinsics else ""
        return f"reprojection robot {self.robot_weight:g} x{scale}{camera}"


def _project_view(board_points, K, dist, cam_T_target):
    rvec, _ = cv2.Rodrigues(cam_T_target[:3, :3])
    proj, _ = cv2.projectPoints(board_points, rvec, cam_T_target[:3, 3], K, dist)
    return proj.reshape(-1, 2)


def predicted_corners(result: HandEyeRefinement, board_points, K, dist, base_T_flange):
    """Pixels (n, N, 2) where ``result`` puts the board corners in each view of these robot
    poses: ``project(K, dist, inv(X) @ H_i @ Y @ (board_scale * board_points))`` with H_i as in
    the module docstring (``inv(base_T_flange_i @ X) @ Y`` for eye-in-hand). ``K`` and ``dist``
    are replaced by the result's ``camera_matrix`` / ``dist_coeffs`` when it refined them."""
    if not isinstance(result, HandEyeRefinement):
        raise ValueError("result must be a HandEyeRefinement (from refine_hand_eye, "
                         f"refine_reprojection or calibrate_from_corners), got "
                         f"{diagnostics.describe(result)}")
    A = geo.as_poses(base_T_flange, "base_T_flange")
    P = _check_board(board_points)
    if result.camera_matrix is not None:
        K, dist = result.camera_matrix, result.dist_coeffs
    K, dist = _check_intrinsics(K, dist)
    C = geo.invert(result.X) @ _chain(A, result.mount) @ result.Y
    P = result.board_scale * P
    return np.array([_project_view(P, K, dist, c) for c in C])


def view_rms_px(predicted: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """RMS pixel distance per view (n,) between predicted and detected corners (NaN skipped)."""
    predicted = diagnostics.as_array(predicted, "predicted", "an (n, N, 2) array of pixels")
    pixels = diagnostics.as_array(pixels, "pixels", "an (n, N, 2) array of pixels")
    if predicted.ndim != 3 or predicted.shape[2] != 2 or pixels.shape != predicted.shape:
        raise ValueError(f"predicted and pixels must both have shape (n_views, N, 2), got "
                         f"{predicted.shape} and {pixels.shape}")
    d2 = np.sum((predicted - pixels) ** 2, axis=2)
    return np.sqrt(np.nanmean(d2, axis=1))


def held_out_view_rms(fit, board_points, pixels, K, dist, base_T_flange,
                      folds: int | None = None) -> np.ndarray:
    """The held-out error, per view (n,): the RMS pixel distance between a view's detected
    corners and those a fit that did not see it predicts through its robot pose
    (``predicted_corners``: the board at the fit's ``board_scale``, the fit's intrinsics when it
    refined them).

    View i is left out in fold ``i % folds``; ``folds=None`` leaves one view out at a time.
    ``fit(keep) -> HandEyeRefinement`` fits on the views where the boolean mask ``keep`` (n,)
    is True. ``board_points`` (N, 3) m, ``pixels`` (n, N, 2) with NaN where a corner was not
    seen, ``base_T_flange`` (n, 4, 4). This is the one held-out error of the project:
    ``calibrate_from_corners`` scores its candidates with it, and ``solutions.pipeline``
    reports it for the model a calibration chose.
    """
    A = geo.as_poses(base_T_flange, "base_T_flange")
    folds = len(A) if folds is None else folds
    fold_of = np.arange(len(A)) % folds
    rms = np.zeros(len(A))
    for k in range(folds):
        out = fold_of == k
        rms[out] = view_rms_px(predicted_corners(fit(~out), board_points, K, dist, A[out]),
                               pixels[out])
    return rms


def pnp_poses(board_points, pixels, K, dist) -> np.ndarray:
    """(n, 4, 4) ``cam_T_target`` per view by ``cv2.solvePnP`` on its found corners (NaN rows
    skipped), metres; ``ValueError`` for a view with fewer than 4 corners or no pose."""
    poses = []
    for i, view in enumerate(pixels):
        ok = np.all(np.isfinite(view), axis=1)
        if ok.sum() < 4:
            raise ValueError(f"view {i} has {ok.sum()} corners; every view needs at least 4 "
                             "(drop views where the board was not found)")
        found, rvec, tvec = cv2.solvePnP(board_points[ok], view[ok], K, dist)
        if not found:
            raise ValueError(f"solvePnP found no board pose in view {i}")
        poses.append(geo.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel()))
    return np.array(poses)


def _pose_candidate(method: str, A, C, mount: str) -> HandEyeRefinement:
    """X and Y from the poses alone by one of ``POSE_CANDIDATES``."""
    if method == "pose_mle":
        return refine_hand_eye(A, C, mount)
    solve = closed_forms.shah_closed_form if method == "shah" else closed_forms.li_closed_form
    if mount == "eye_in_hand":
        X, Y = solve(A, geo.invert(C))
    else:
        Y, X = solve(A, C)
    return HandEyeRefinement(X=_clean(X), Y=_clean(Y), mount=mount, rotation_sigma_rad=0.0,
                             translation_sigma_m=0.0, weights=np.ones(len(A)),
                             outlier_indices=(), cost=float("nan"), n_iterations=0,
                             converged=True)


def fit_candidate(choice: CornerNoiseChoice, P, px, K, dist, A, C, mount, start):
    """Fit one candidate model of ``calibrate_from_corners`` on these views (inputs validated):
    a reprojection fit started from ``start`` (a ``HandEyeRefinement``), or a pose-based fit on
    ``C``. Returns its ``HandEyeRefinement``."""
    if choice.method != "reprojection":
        return _pose_candidate(choice.method, A, C, mount)
    return refine_reprojection(P, px, K, dist, A, mount, X0=start.X, Y0=start.Y,
                               robot_sigma=choice.robot_sigma,
                               fit_board_scale=choice.fit_board_scale,
                               fit_intrinsics=choice.fit_intrinsics)


def _options(value, name: str, what: str) -> tuple:
    """A tuple of candidate settings from a tuple, list or 1-d array; ``ValueError`` naming
    ``name`` for anything else (a bare True or 0.1: wrap it, e.g. (True,))."""
    if isinstance(value, np.ndarray) and value.ndim == 1:
        return tuple(value.tolist())
    if not isinstance(value, (tuple, list)):
        raise ValueError(f"{name} must be a tuple of {what}, e.g. {name}=(...,), got "
                         f"{diagnostics.describe(value)}")
    return tuple(value)


def _simplest_within_noise(choices, log_rms) -> int:
    """Index of the candidate to fit: the best, unless a simpler one predicts as well.

    A candidate with extra parameters (the board's scale, the intrinsics) is kept only when it
    predicts the held-out views better than every simpler candidate by more than 0.5 % (the
    mean per-view log RMS lower by more than log(1.005)). Without this rule a free board scale
    won a tie on a clean simulated capture whose views all look at the board's centre from
    0.45 m: there scaling the board and sliding the camera along its axis (X's z) change no
    image, and it moved X by 26 mm for a held-out gain of 0.002 % (0.088241 against 0.088243
    px). A one-standard-error rule (the simpler model unless the gain exceeds the paired
    standard error over views) was tried too: it also fixes that case but gave kuka_2's free
    scale up in some folds, its held-out median 1.150 -> 1.204 px.
    """
    scores = np.array([c.held_out_px for c in choices])
    best = int(np.argmin(scores))
    extra = [int(c.fit_board_scale) + int(c.fit_intrinsics) for c in choices]
    for level in range(extra[best]):
        simpler = [k for k in range(len(choices)) if extra[k] == level and np.isfinite(scores[k])]
        if not simpler:
            continue
        k = min(simpler, key=lambda j: scores[j])
        if float(np.mean(log_rms[k] - log_rms[best])) <= _MIN_GAIN_LOG:
            return k
    return best


# An extra parameter must also buy a held-out gain above 0.5 % of the pixel error (the
# simulated tie in _simplest_within_noise: 0.002 %; kuka_2's free scale: more, fold by fold).
_MIN_GAIN_LOG = float(np.log(1.005))


def calibrate_from_corners(board_points, pixels, K, dist, base_T_flange,
                           mount: str = "eye_in_hand", cam_T_target=None, *,
                           robot_weights=ROBOT_WEIGHT_FRACTIONS, fit_board_scale=(False, True),
                           pose_candidates=POSE_CANDIDATES, folds: int = _CV_FOLDS,
                           fit_intrinsics=(False,)):
    """Hand-eye calibration from raw corners with the model chosen by held-out views.

    The default for a capture with corners. Real captures carry robot pose error comparable to
    the camera's, errors that repeat per view, and boards printed slightly off their stated
    size; which fit predicts best differs from capture to capture: the pixel-only fit, the fit
    with a robot-error prior (and how strong), the fit with the board's scale free, or, when
    the robot's error dominates the pixels' (views far from the camera), a fit to the solvePnP
    poses alone. So every candidate, ``robot_weights`` x ``fit_board_scale`` reprojection fits
    and the pose-based ``pose_candidates``, is scored by K-fold cross-validation over the
    views (``folds``; view i is in fold i % folds): fit it on the other views, predict the
    left-out views' corners through the robot poses, and take the geometric mean of their
    per-view RMS pixel error (the held-out Gaussian log-likelihood with one scale per view).
    The best candidate is then fitted on all views, unless a candidate with fewer free
    parameters scores within 0.5 % of it (``_simplest_within_noise``): then that one. Nothing
    is tuned by hand per capture.

    ``robot_weights`` are fractions of the robot noise that ``refine_hand_eye`` estimates
    on all views (rotation, and the translation noise it cannot tell from the camera's;
    0 = pixel-only); ``fit_intrinsics`` whether each reprojection fit keeps ``K`` and ``dist``
    (False) or refines them with the hand-eye fit (True; both: each candidate twice; a fold
    then predicts its left-out views with the intrinsics refined on its other views);
    ``pose_candidates`` a subset of ``POSE_CANDIDATES`` (``()`` for corner
    fits only). Inputs as for ``refine_reprojection``; ``cam_T_target`` (solvePnP poses) is
    found from the corners when not given.

    Returns ``(result, choices)``: the ``HandEyeRefinement`` of the chosen model (its
    ``board_scale`` is the fitted scale, 1 when not fitted or pose-based; its
    ``reprojection_rms_px`` the RMS over all views' corners) and the list of
    ``CornerNoiseChoice`` scores: the chosen model first, then the rest, best first.
    """
    _check_mount(mount)
    A = geo.as_poses(base_T_flange, "base_T_flange")
    P, px, K, dist = check_corner_inputs(board_points, pixels, K, dist, len(A))
    folds = diagnostics.check_number(folds, "folds", minimum=2, integer=True)
    if folds > len(A):
        raise ValueError(f"folds must be between 2 and the number of views ({len(A)}), got {folds}")
    weights = tuple(diagnostics.check_number(w, f"robot_weights[{i}]", minimum=0.0)
                    for i, w in enumerate(_options(robot_weights, "robot_weights", "fractions")))
    scales = tuple(diagnostics.check_flag(b, f"fit_board_scale[{i}]") for i, b in
                   enumerate(_options(fit_board_scale, "fit_board_scale", "booleans")))
    cameras = tuple(diagnostics.check_flag(b, f"fit_intrinsics[{i}]") for i, b in
                    enumerate(_options(fit_intrinsics, "fit_intrinsics", "booleans")))
    if weights and not cameras:
        raise ValueError("fit_intrinsics must be a non-empty tuple of booleans, e.g. (False,)")
    if weights and not scales:
        raise ValueError("robot_weights must be fractions >= 0 and fit_board_scale a "
                         "non-empty tuple of booleans")
    pose_methods = _options(pose_candidates, "pose_candidates", "method names")
    unknown = [m for m in pose_methods if not isinstance(m, str) or m not in POSE_CANDIDATES]
    if unknown:
        raise ValueError(f"unknown pose candidates {unknown}; choose from {POSE_CANDIDATES}")
    if not weights and not pose_methods:
        raise ValueError("no candidates: give robot_weights or pose_candidates")
    if cam_T_target is None:
        C = pnp_poses(P, px, K, dist)
        camera_name, camera_fix = "cam_T_target (solvePnP on board_points)", "divide board_points by {n}"
    else:
        C = geo.as_poses(cam_T_target, "cam_T_target")
        camera_name, camera_fix = "cam_T_target", None
    if len(C) != len(A):
        raise ValueError(f"cam_T_target has {len(C)} poses but base_T_flange has {len(A)}; "
                         "give one camera pose per view")
    # Checked here, naming what the caller passed (refine_hand_eye below checks it too).
    diagnostics.check_hand_eye_poses(A, C, mount, camera_name=camera_name,
                                     camera_fix=camera_fix)
    start = refine_hand_eye(A, C, mount)
    # The pose-based fit's REML noise split (camera translation and robot translation share one
    # term there) sets the robot prior's scale; the candidates rescale it.
    robot_sigma = np.array([start.robot_rotation_sigma_rad, start.translation_sigma_m])
    candidates = [CornerNoiseChoice(w, tuple(float(v) for v in w * robot_sigma), scale, np.nan,
                                    fit_intrinsics=camera)
                  for camera in cameras for w in weights for scale in scales]
    candidates += [CornerNoiseChoice(np.nan, None, False, np.nan, method=m) for m in pose_methods]
    choices, log_rms = [], []
    for cand in candidates:
        rms = np.zeros(len(A))
        try:
            rms = held_out_view_rms(
                lambda keep, cand=cand: fit_candidate(cand, P, px[keep], K, dist, A[keep], C[keep],
                                                      mount, start),
                P, px, K, dist, A, folds)
            score = float(np.exp(np.mean(np.log(np.maximum(rms, 1e-12)))))
        except ValueError:
            # A fold too degenerate for this candidate (e.g. the closed forms' checks): it
            # cannot be trusted on this capture.
            score = float("inf")
        choices.append(dataclasses.replace(cand, held_out_px=score))
        log_rms.append(np.log(np.maximum(rms, 1e-12)))
    if not any(np.isfinite(c.held_out_px) for c in choices):
        raise ValueError("no candidate model could be fitted on every cross-validation fold; "
                         "capture more views with varied orientations")
    chosen = _simplest_within_noise(choices, log_rms)
    choices = [choices[chosen]] + sorted(
        (c for k, c in enumerate(choices) if k != chosen), key=lambda c: c.held_out_px)
    result = fit_candidate(choices[0], P, px, K, dist, A, C, mount, start)
    if choices[0].method != "reprojection":
        # A pose-based fit has no corner residual of its own; report the one it leaves.
        rms = view_rms_px(predicted_corners(result, P, K, dist, A), px)
        result = dataclasses.replace(result, reprojection_rms_px=float(np.sqrt(np.nanmean(rms**2))))
    return result, choices
