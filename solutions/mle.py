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
inverse of their covariance. The covariance holds the camera's rotation and translation noise
and, optionally, the robot's rotation noise, which moves the predicted board by the lever arm
from the flange to the board (a 0.001 rad wrist error is 1 mm at 1 m). Noise levels are
estimated from the residuals when not given (solve, estimate robustly, re-solve). A robust
loss on each pose's normalised residual down-weights a mis-detected board, and the poses it
rejects are reported by index.

``refine_reprojection`` minimises the corner reprojection error (pixels) instead: the exact
maximum-likelihood estimate under pixel noise when the robot poses are accurate.

Relation to OpenCV: ``cv2.calibrateHandEye`` takes (gripper2base, target2cam) =
(``base_T_flange``, ``cam_T_target``) for eye-in-hand and returns cam2gripper = ``flange_T_cam``
(= X here); for eye-to-hand it takes base2gripper = ``inv(base_T_flange)`` and returns
cam2base = ``base_T_cam`` (= X here). This module takes ``base_T_flange`` as is for both mounts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from robots import geometry as geo
from solutions import robot_world

__all__ = [
    "MOUNTS",
    "OUTLIER_CHI2",
    "HandEyeRefinement",
    "pose_residuals",
    "refine_hand_eye",
    "refine_reprojection",
]

MOUNTS = ("eye_in_hand", "eye_to_hand")

#: A pose is reported as an outlier when its squared normalised residual (chi-square with 6
#: degrees of freedom for a good pose) exceeds this: the 99.99 % quantile, so a good pose is
#: misnamed about once in 10 000.
OUTLIER_CHI2 = 27.86
#: Scale of the robust loss on the squared normalised pose residual: the 95 % quantile of
#: chi-square(6), so good poses keep most of their weight.
LOSS_SCALE_CHI2 = 12.59
_MAD_TO_SIGMA = 1.4826
_SIGMA_FLOOR_RAD = 1e-12
_SIGMA_FLOOR_M = 1e-12


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

    @property
    def outlier_pose_indices(self) -> tuple[int, ...]:
        """Alias of ``outlier_indices`` (the name the benchmark and catalogue read)."""
        return self.outlier_indices


# --------------------------------------------------------------------------- shared pieces


def _check_mount(mount: str) -> None:
    if mount not in MOUNTS:
        raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")


def _validate(base_T_flange, cam_T_target, mount: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated (N, 4, 4) robot and camera poses; degeneracy checked as for AX = YB."""
    _check_mount(mount)
    return robot_world.validate_ax_yb(base_T_flange, cam_T_target, "base_T_flange", "cam_T_target")


def _chain(A: np.ndarray, mount: str) -> np.ndarray:
    """H_i with cam_T_target_i = inv(X) @ H_i @ Y."""
    return geo.invert(A) if mount == "eye_in_hand" else A


def _initial_guess(A, C, mount, X0, Y0) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) to start from: given ones, the other one averaged from them, or Li's AX = YB."""
    H = _chain(A, mount)
    if X0 is None and Y0 is None:
        if mount == "eye_in_hand":
            return robot_world.li_closed_form(A, geo.invert(C))
        flange_T_target, base_T_cam = robot_world.li_closed_form(A, C)
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



def _covariance_parts(var_cam_rot, var_trans, var_robot_rot, e):
    """The three (N, 6, 6) covariance parts of the pose residual, in camera axes.

    Camera rotation noise (variance per axis, rad^2) on the rotation; translation noise
    (m^2, camera and robot translation noise together) on the translation; robot rotation noise
    delta (rad^2), which moves the predicted board as (rotation, translation) =
    (delta, -[e]x delta), e being the flange-to-board lever arm in camera axes.
    """
    n = len(e)
    Se = _skew(e)
    cam = np.zeros((n, 6, 6))
    cam[:, :3, :3] = var_cam_rot * np.eye(3)
    trans = np.zeros((n, 6, 6))
    trans[:, 3:, 3:] = var_trans * np.eye(3)
    robot = np.zeros((n, 6, 6))
    robot[:, :3, :3] = np.eye(3)
    robot[:, :3, 3:] = Se
    robot[:, 3:, :3] = np.swapaxes(Se, 1, 2)
    robot[:, 3:, 3:] = Se @ np.swapaxes(Se, 1, 2)
    return [cam, trans, var_robot_rot * robot]


def _update_variances(variances, parts, info, r, J, keep):
    """One step of Foerstner's variance-component estimation (it converges to REML).

    Each variance is scaled by (r' W S_k W r) / tr((W - W J H^-1 J' W) S_k) over the kept
    poses, S_k being its covariance part and W the information matrix: the scatter of the
    residuals seen over the scatter expected after the fit has used up its 12 parameters.
    """
    Jk, Wk, rk = J[keep], info[keep], r[keep]
    WJ = Wk @ Jk
    Hinv = np.linalg.inv(Jk.reshape(-1, 12).T @ WJ.reshape(-1, 12))
    Wr = (Wk @ rk[:, :, None])[:, :, 0]
    redundancy = Wk - WJ @ Hinv @ np.swapaxes(WJ, 1, 2)
    out = []
    for var, S in zip(variances, parts):
        if var <= 0.0:
            out.append(0.0)
            continue
        Sk = S[keep]
        num = float(np.einsum("ni,ni->", Wr, (Sk @ Wr[:, :, None])[:, :, 0]))
        den = float(np.sum(redundancy * Sk))
        out.append(var * num / den if den > 1e-9 * float(np.sum(Wk * Sk)) else var)
    return out


def _loss(z2: np.ndarray, loss: str | None) -> tuple[np.ndarray, np.ndarray]:
    """(rho, weight) of squared normalised pose residuals z2 for a robust loss scaled to
    ``LOSS_SCALE_CHI2``; rho is in the units of z2 and weight = d rho / d z2."""
    s = z2 / LOSS_SCALE_CHI2
    w = robot_world.loss_weights(s, loss)
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
                    loss: str = "cauchy") -> HandEyeRefinement:
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
    robust : first fit with ``loss`` on each pose's normalised residual, then drop the poses
        whose squared normalised residual exceeds ``OUTLIER_CHI2`` and fit the rest by plain
        weighted least squares (as efficient as least squares when nothing is wrong).
    max_iter : Levenberg-Marquardt steps per solve.
    sigma : (rotation_rad, translation_m): camera-side noise standard deviations per axis
        (robot translation noise may be folded into the translation), or None to estimate
        them from the residuals (variance-component estimation, re-solving until they settle).
    robot_rotation_sigma_rad : robot rotation noise per axis (rad); its effect on the
        predicted board grows with the flange-to-board lever arm. None estimates it with the
        other noise levels when ``sigma`` is None (and takes 0 when ``sigma`` is given).
    loss : robust loss of the first stage: "cauchy" (default), "soft_l1" or "huber".

    Returns a ``HandEyeRefinement``. Raises ``ValueError`` for malformed or degenerate input
    (fewer than 3 poses, mismatched lengths, rotations about one axis only).
    """
    A, C = _validate(base_T_flange, cam_T_target, mount)
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    if robust and loss not in ("huber", "soft_l1", "cauchy"):
        raise ValueError(f"loss must be 'huber', 'soft_l1' or 'cauchy', got {loss!r}")
    if robot_rotation_sigma_rad is not None and not (np.isfinite(robot_rotation_sigma_rad)
                                                     and robot_rotation_sigma_rad >= 0):
        raise ValueError("robot_rotation_sigma_rad must be a finite value >= 0 (radians) or None")
    estimate = sigma is None
    if not estimate:
        sigma = np.asarray(sigma, dtype=float)
        if sigma.shape != (2,) or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
            raise ValueError(
                "sigma must be (rotation_rad, translation_m), both finite and > 0, e.g. "
                "(np.radians(0.1), 0.0005); or None to estimate them from the data")

    X, Y = _initial_guess(A, C, mount, X0, Y0)
    problem = _PoseProblem(A, C, mount)
    Z = geo.invert(X)
    n = len(A)
    keep = np.ones(n, bool)
    r, _, P = problem.residuals(Z, Y)
    e = problem.lever_arms(Z, P)

    if estimate:
        # The start is only roughly right, so these overstate the noise, which keeps the first
        # robust pass gentle. The median resists a bad view.
        var_cr = max(_mad_sigma(r[:, :3]), _SIGMA_FLOOR_RAD) ** 2
        var_t = max(_mad_sigma(r[:, 3:]), _SIGMA_FLOOR_M) ** 2
        # Start the robot share at a tenth of the rotation noise; the estimation moves it.
        var_rr = 0.1 * var_cr if robot_rotation_sigma_rad is None else robot_rotation_sigma_rad**2
    else:
        var_cr, var_t = sigma[0] ** 2, sigma[1] ** 2
        var_rr = (robot_rotation_sigma_rad or 0.0) ** 2
    estimate_rr = estimate and robot_rotation_sigma_rad is None

    def information(e):
        return np.linalg.inv(sum(_covariance_parts(var_cr, var_t, var_rr, e)))

    total_it = 0
    converged = True
    if robust:
        # Stage 1: robust loss, noise re-estimated by medians until it settles.
        for _ in range(2):
            Z, Y, _, z2, it, converged = _gauss_newton(problem, Z, Y, information(e), loss,
                                                       max_iter, keep, tol=1e-6)
            total_it += it
            r, _, P = problem.residuals(Z, Y)
            e = problem.lever_arms(Z, P)
            if not estimate:
                break
            inl = z2 < OUTLIER_CHI2
            if inl.sum() < 3:
                inl[:] = True
            dof = np.sqrt(6 * inl.sum() / max(6 * inl.sum() - 12, 1))
            new_cr = max(_mad_sigma(r[inl, :3]) * dof, _SIGMA_FLOOR_RAD) ** 2
            new_t = max(_mad_sigma(r[inl, 3:]) * dof, _SIGMA_FLOOR_M) ** 2
            settled = abs(new_cr / var_cr - 1) < 0.05 and abs(new_t / var_t - 1) < 0.05
            var_cr, var_t = new_cr, new_t
            if settled:
                break

    # Stage 2: weighted least squares on the poses that are not outliers, with the noise
    # levels re-estimated by variance components (REML) until they and the inlier set settle.
    # The variance iteration runs at fixed residuals between solves: residuals barely move when
    # the weights change a little, and a solve costs far more than a variance update.
    for _ in range(6):
        info = information(e)
        if robust:
            r, _, _ = problem.residuals(Z, Y)
            new_keep = _chi2(r, info) < OUTLIER_CHI2
            if new_keep.sum() < 3:
                raise ValueError(
                    f"only {int(new_keep.sum())} of {n} poses agree with each other; check that "
                    "base_T_flange and cam_T_target are paired in order and in the convention "
                    "this function expects (base_T_flange, not its inverse)")
            keep_changed = not np.array_equal(new_keep, keep)
            keep = new_keep
        else:
            keep_changed = False
        Z, Y, _, z2, it, converged = _gauss_newton(problem, Z, Y, info, None, max_iter, keep)
        total_it += it
        r, Jinv, P = problem.residuals(Z, Y)
        e = problem.lever_arms(Z, P)
        if not estimate:
            if var_rr == 0.0 and not keep_changed:
                break
            continue
        J = problem.jacobian(P, Jinv)
        old = (var_cr, var_t, var_rr)
        for _ in range(10):
            rr_now = var_rr if estimate_rr else 0.0
            parts = _covariance_parts(var_cr, var_t, rr_now, e)
            info = np.linalg.inv(sum(parts))
            new = _update_variances([var_cr, var_t, rr_now], parts, info, r, J, keep)
            new_cr = max(new[0], _SIGMA_FLOOR_RAD**2)
            new_t = max(new[1], _SIGMA_FLOOR_M**2)
            new_rr = new[2] if estimate_rr else var_rr
            # A robot share below 1 % of the rotation noise changes nothing; end it there
            # rather than let the multiplicative update creep towards zero.
            if estimate_rr and new_rr < 1e-4 * new_cr:
                new_rr, estimate_rr = 0.0, False
            step = max(abs(np.sqrt(new_cr / var_cr) - 1), abs(np.sqrt(new_t / var_t) - 1),
                       abs(np.sqrt(new_rr) - np.sqrt(var_rr)) / np.sqrt(new_cr + new_rr))
            var_cr, var_t, var_rr = new_cr, new_t, new_rr
            if step < 1e-3:
                break
        moved = max(abs(np.sqrt(var_cr / old[0]) - 1), abs(np.sqrt(var_t / old[1]) - 1),
                    abs(np.sqrt(var_rr) - np.sqrt(old[2])) / np.sqrt(var_cr + var_rr))
        if moved < 0.01 and not keep_changed:
            break

    info = information(e)
    r, _, _ = problem.residuals(Z, Y)
    z2 = _chi2(r, info)
    outliers = tuple(int(i) for i in np.flatnonzero(~keep)) if robust else ()
    return HandEyeRefinement(
        X=_clean(geo.invert(Z)), Y=_clean(Y), mount=mount,
        rotation_sigma_rad=float(np.sqrt(var_cr)), translation_sigma_m=float(np.sqrt(var_t)),
        weights=keep.astype(float), outlier_indices=outliers, cost=float(z2[keep].sum()),
        n_iterations=total_it, converged=bool(converged),
        robot_rotation_sigma_rad=float(np.sqrt(var_rr)), per_pose_chi2=z2,
    )


def _clean(T: np.ndarray) -> np.ndarray:
    """Re-orthonormalise the rotation block after many multiplications."""
    return geo.make_pose(geo.project_to_so3(T[:3, :3]), T[:3, 3])


# --------------------------------------------------------------------------- reprojection MLE


def _check_camera(board_points, pixels, K, dist, n_views):
    P = np.asarray(board_points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 4 or not np.all(np.isfinite(P)):
        raise ValueError(f"board_points must be a finite (N, 3) array with N >= 4 (metres, target "
                         f"frame), got shape {P.shape}")
    px = np.asarray(pixels, dtype=float)
    if px.shape != (n_views, len(P), 2):
        raise ValueError(f"pixels must have shape (n_views, N, 2) = ({n_views}, {len(P)}, 2) to "
                         f"match base_T_flange and board_points, got {px.shape}; mark a corner "
                         "or view that was not seen with NaN")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 camera matrix with positive focal lengths, got {K}")
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise ValueError(f"dist must hold 4, 5, 8, 12 or 14 finite OpenCV distortion "
                         f"coefficients, got {dist.size}")
    return P, px, K, dist


def _reprojection_system(P, px, valid, K, dist, Z, Y, A, H, mount, views, w_view, noise):
    """Normal equations of the corner residuals with each view's robot error marginalised.

    Pixel residuals r (measured - projected) of view i are modelled as
    ``J_g dg + J_l xi_i + eps``: dg the 12 corrections of (Z, Y), xi_i = (u, v) the view's
    robot error in camera axes (rotation u about the flange origin, translation v) with prior
    N(0, diag(s_rr^2, s_rt^2)), eps ~ N(0, s_px^2) per pixel axis. Eliminating xi_i (Schur
    complement) gives the marginal likelihood's Gauss-Newton system over dg alone.

    Returns (H (12, 12), g (12,), marginal cost per view, raw squared residual per view,
    EM sufficient statistics (sum over views of E[|u|^2], E[|v|^2], E[|r - J_l xi|^2])).
    """
    s_px2, s_rr2, s_rt2 = noise
    prior = np.diag([1 / s_rr2] * 3 + [1 / s_rt2] * 3) if s_rr2 > 0 else None
    n = len(px)
    cost = np.zeros(n)
    raw = np.zeros(n)
    stats = np.zeros(3)
    Hm = np.zeros((12, 12))
    g = np.zeros(12)
    SP = _skew(P)
    for i in views:
        C = Z @ H[i] @ Y
        R, t = C[:3, :3], C[:3, 3]
        rvec, _ = cv2.Rodrigues(R)
        proj, jac = cv2.projectPoints(P, rvec, t, K, dist)
        m = valid[i]
        r = (px[i] - proj.reshape(-1, 2))[m].reshape(-1)
        # d pixel / d tvec is d pixel / d (point in camera frame): the point is R P + t.
        dpdp = jac[:, 3:6].reshape(-1, 2, 3)[m]
        pc = (P @ R.T + t)[m]
        D = np.zeros((len(pc), 3, 12))
        D[:, :, 0:3] = -_skew(pc)             # Z <- [exp(phi_z), rho_z] Z
        D[:, :, 3:6] = np.eye(3)
        D[:, :, 6:9] = -R @ SP[m]             # Y <- Y [exp(phi_y), rho_y]
        D[:, :, 9:12] = R
        Jg = -(dpdp @ D).reshape(-1, 12)
        Hgg, bg, rr = Jg.T @ Jg / s_px2, Jg.T @ r / s_px2, float(r @ r)
        raw[i] = rr
        if prior is None:
            Hm += w_view[i] * Hgg
            g += w_view[i] * bg
            cost[i] = rr / s_px2
            stats[2] += rr
            continue
        # The flange origin in camera axes: the robot's rotation error turns about it.
        flange = Z[:3, 3] if mount == "eye_in_hand" else Z[:3, :3] @ A[i, :3, 3] + Z[:3, 3]
        Dl = np.zeros((len(pc), 3, 6))
        Dl[:, :, 0:3] = _skew(pc - flange)
        Dl[:, :, 3:6] = np.eye(3)
        Jl = -(dpdp @ Dl).reshape(-1, 6)
        Hll = Jl.T @ Jl / s_px2 + prior
        Hll_inv = np.linalg.inv(Hll)
        Hlg, bl = Jl.T @ Jg / s_px2, Jl.T @ r / s_px2
        Hm += w_view[i] * (Hgg - Hlg.T @ Hll_inv @ Hlg)
        g += w_view[i] * (bg - Hlg.T @ Hll_inv @ bl)
        xi = Hll_inv @ bl
        cost[i] = rr / s_px2 - bl @ xi
        e = r - Jl @ xi
        stats += [xi[:3] @ xi[:3] + np.trace(Hll_inv[:3, :3]), xi[3:] @ xi[3:] + np.trace(Hll_inv[3:, 3:]),
                  e @ e + np.sum((Jl @ Hll_inv) * Jl)]
    return Hm, g, cost, raw, stats


def refine_reprojection(board_points, pixels, K, dist, base_T_flange, mount: str = "eye_in_hand",
                        X0=None, Y0=None, robust: bool = True, max_iter: int = 50,
                        robot_sigma=None) -> HandEyeRefinement:
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

    Returns a ``HandEyeRefinement`` with ``reprojection_rms_px`` (inlier views, before the
    robot-error correction), ``pixel_sigma_px``, ``robot_rotation_sigma_rad``; its
    ``translation_sigma_m`` is the robot translation noise and ``rotation_sigma_rad`` 0.
    """
    _check_mount(mount)
    A = geo.as_poses(base_T_flange, "base_T_flange")
    P, px, K, dist = _check_camera(board_points, pixels, K, dist, len(A))
    if X0 is None or Y0 is None:
        raise ValueError("refine_reprojection needs a start X0 and Y0; get them from "
                         "refine_hand_eye(base_T_flange, cam_T_target, mount) on the solvePnP poses")
    X0, Y0 = geo.as_pose(X0, "X0"), geo.as_pose(Y0, "Y0")
    if robot_sigma is not None:
        robot_sigma = np.asarray(robot_sigma, dtype=float)
        if robot_sigma.shape != (2,) or not np.all(np.isfinite(robot_sigma)) or np.any(robot_sigma < 0):
            raise ValueError("robot_sigma must be (rotation_rad, translation_m), finite and >= 0")
    valid = np.all(np.isfinite(px), axis=2)
    views = np.flatnonzero(valid.sum(axis=1) >= 4)
    if len(views) < 3:
        raise ValueError(f"only {len(views)} views have at least 4 corners seen; capture at least "
                         "3 views with the board (10-20 is typical)")
    robot_world.check_rotation_variety(A[views, :3, :3], "base_T_flange (views with corners)")
    px = np.where(valid[:, :, None], px, 0.0)
    counts = valid.sum(axis=1)
    H = _chain(A, mount)
    Z, Y = geo.invert(X0), Y0.copy()
    w_view = np.zeros(len(A))
    w_view[views] = 1.0

    def system(Z, Y, w, noise):
        return _reprojection_system(P, px, valid, K, dist, Z, Y, A, H, mount, views, w, noise)

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
        Hm, g, cost_v, raw, stats = system(Z, Y, w_view, noise)
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
                Hn, gn, cost_vn, rawn, statsn = system(Zn, Yn, w_view, noise)
                cost_n = float(w_view @ cost_vn)
                if cost_n <= cost or lam > 1e8:
                    break
                lam *= 10.0
            if cost_n > cost:
                converged = True
                break
            Z, Y, Hm, g, cost, raw, stats = Zn, Yn, Hn, gn, cost_n, rawn, statsn
            lam = max(lam / 10.0, 1e-9)
        # EM update of the noise levels over the views in use.
        n_obs = 2 * counts[views].sum()
        n_views = len(views)
        new_px2 = max(stats[2] / max(n_obs - 12, 1), 1e-24)
        if estimate_robot:
            new = (new_px2, max(stats[0] / (3 * n_views), 1e-16), max(stats[1] / (3 * n_views), 1e-16))
        else:
            new = (new_px2, noise[1], noise[2])
        moved = max(abs(np.sqrt(a / b) - 1) for a, b in zip(new, noise) if b > 0)
        noise = new
        if moved < 0.01:
            break

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
        pixel_sigma_px=float(np.sqrt(noise[0])), per_pose_chi2=rms_view,
    )
