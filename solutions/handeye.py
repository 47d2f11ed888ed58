"""AX = XB hand-eye calibration: reference solvers (instructor-only).

Conventions
-----------
Poses are (4, 4) float64 arrays; ``a_T_b`` maps b-coordinates to a-coordinates; metres and
radians (see the project's DESIGN notes). The two mounts and their unknown X:

* ``eye_in_hand``: the camera rides on the flange and the board is fixed in the workcell.
  X = ``flange_T_cam``, and for every pose i
  ``base_T_flange[i] @ X @ cam_T_target[i] == base_T_target`` (a constant).
* ``eye_to_hand``: the camera is fixed and the board rides on the flange.
  X = ``base_T_cam``, and for every pose i
  ``inv(base_T_flange[i]) @ X @ cam_T_target[i] == flange_T_target`` (a constant).

Equating that constant at poses i and j eliminates it and leaves ``A @ X == X @ B`` with

* eye_in_hand: ``A = inv(base_T_flange[i]) @ base_T_flange[j]`` (robot side),
  ``B = cam_T_target[i] @ inv(cam_T_target[j])`` (camera side);
* eye_to_hand: ``A = base_T_flange[i] @ inv(base_T_flange[j])``,
  ``B = cam_T_target[i] @ inv(cam_T_target[j])``.

Only pairs i < j are used: the pair (j, i) gives the inverse motions ``inv(A), inv(B)``,
which carry exactly the same information (the test-suite shows their residuals are equal).

Relation to OpenCV
------------------
``cv2.calibrateHandEye(R_gripper2base, t_gripper2base, R_target2cam, t_target2cam)``:

=========================================  ===========================================
OpenCV name                                here
=========================================  ===========================================
gripper2base                               ``base_T_flange``
base2gripper                               ``inv(base_T_flange)`` = ``flange_T_base``
target2cam                                 ``cam_T_target``
cam2target                                 ``inv(cam_T_target)`` = ``target_T_cam``
output cam2gripper (eye-in-hand call)      ``flange_T_cam`` = ``calibrate_eye_in_hand(...)``
output cam2base (eye-to-hand call)         ``base_T_cam`` = ``calibrate_eye_to_hand(...)``
=========================================  ===========================================

* ``calibrate_eye_in_hand(base_T_flange, cam_T_target)`` takes exactly OpenCV's eye-in-hand
  inputs (gripper2base, target2cam); nothing is inverted.
* ``calibrate_eye_to_hand(base_T_flange, cam_T_target)`` takes ``base_T_flange``
  (= gripper2base) where OpenCV's eye-to-hand recipe wants base2gripper: OpenCV makes *you*
  invert the robot poses, this function does not. Hence, for the motion-based methods,
  ``calibrate_eye_to_hand(F, C) == calibrate_eye_in_hand(invert(F), C)``.
* Data in the other convention: robot poses reported as base2gripper (``flange_T_base``)
  -> pass ``robots.geometry.invert(them)``; camera poses reported as cam2target
  (``target_T_cam``, e.g. a tracker giving the camera in the board's frame) -> pass
  ``invert(them)``. Mixing these up is the most common student mistake: every solver would
  return a wrong X with large residuals, so ``calibrate_*`` refuse such poses (and poses whose
  lists are not paired view by view) with a ``ValueError`` naming the likely fix, and the
  motion-level ``solve_*`` warn when X fits the motions far worse than their noise allows (see
  ``solutions.diagnostics``).
* ``solve_ax_xb(A, B)`` and the ``solve_*`` functions work on motions; OpenCV has no
  motion-level entry point.

Residual metrics (the course's definitions), over n motions:
``rotation_residual = (1/n) sum ||R_A R_X - R_X R_B||_F^2`` (dimensionless) and
``translation_residual = (1/n) sum ||R_A t_X + t_A - R_X t_B - t_X||^2`` (metres^2).

Degenerate input raises ``ValueError`` naming the problem and the fix: fewer than 3 poses,
mismatched lengths, non-rotations or NaN, all rotation axes parallel, motions A[k], B[k] whose
rotation angles disagree by degrees (not the same motion), robot and camera translations in
different units (millimetres among metres: ``solutions.units``, which names the unit and the
fix), and motions that rotate by less than ``MIN_MOTION_DEG`` (dropped with a warning when
enough others remain). No
function here returns a default pose or NaN. Motions of nearly 180 degrees are ambiguous for
every method here (log map and quaternion sign); calibration motions of 15-45 degrees are
far from that.

Every solver gives the same X whatever the order of the poses: the closed forms' rotation
equations are unchanged when a motion is reversed, and the translation equations are written
in a form that is too (see ``_translation_ls``).

``calibrate_flange`` (a fixed camera seeing a marker on the flange; it lives in
``solutions.registration``) is re-exported here so every hand-eye entry point is in one place.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from robots import geometry as geo
from solutions import diagnostics, units
from solutions.diagnostics import MIN_AXIS_SPREAD_DEG, MIN_MOTION_DEG
from solutions.registration import calibrate_flange  # re-exported: see the docstring

__all__ = [
    "METHODS",
    "MIN_AXIS_SPREAD_DEG",
    "MIN_MOTION_DEG",
    "MOUNTS",
    "PAIR_STRATEGIES",
    "HandEyeResult",
    "calibrate_eye_in_hand",
    "calibrate_eye_in_hand_report",
    "calibrate_eye_to_hand",
    "calibrate_eye_to_hand_report",
    "calibrate_flange",
    "hand_eye_motions",
    "motion_pairs",
    "motion_residuals",
    "rotation_residual",
    "solve_ax_xb",
    "solve_ax_xb_report",
    "solve_axes_ls",
    "solve_daniilidis",
    "solve_nonlinear",
    "solve_park",
    "solve_tsai",
    "translation_residual",
]

METHODS = ("tsai", "park", "daniilidis", "axes_ls", "nonlinear")
MOUNTS = ("eye_in_hand", "eye_to_hand")
PAIR_STRATEGIES = ("all", "consecutive")

# MIN_MOTION_DEG and MIN_AXIS_SPREAD_DEG come from solutions.diagnostics, whose motion
# screening solutions.robot_world applies too, so both refuse the same motions.

# Robust loss: Huber on each motion's whole residual, with threshold HUBER_K times the median
# motion residual. A motion is reported as down-weighted (and left out of the final refit) when
# its weight falls below DOWNWEIGHT_FLAG, i.e. when its residual exceeds 4x the median one.
HUBER_K = 2.0
DOWNWEIGHT_FLAG = 0.5
_MAX_IRLS = 30
# Floors for the residual scales, so exact (noise-free) data never divides by zero.
_ROT_SCALE_FLOOR = 1e-12
_TRANS_SCALE_FLOOR_M = 1e-12
# Tsai's Gibbs vector tan(theta/2) blows up as X approaches a half-turn; beyond this angle we
# re-solve in a frame turned by a half-turn about x, y or z (see solve_tsai).
_TSAI_MAX_DEG = 120.0


# --------------------------------------------------------------------------- result


@dataclass
class HandEyeResult:
    """What a hand-eye solve found, for reports and for the autograder's self-check.

    X: the solution (4, 4): flange_T_cam (eye_in_hand) or base_T_cam (eye_to_hand).
    method: the method name; start_method: the closed form "nonlinear" started from.
    n_motions: motions the solver used. Per-motion arrays (``used``, ``weights``,
    ``rotation_residuals`` = ||R_A R_X - R_X R_B||_F^2, ``translation_residuals`` =
    ||R_A t_X + t_A - R_X t_B - t_X||^2 in m^2) have one entry per motion *given*, including
    motions dropped for rotating less than MIN_MOTION_DEG (``dropped_motion_indices``);
    ``rotation_residual`` and ``translation_residual`` are the course's means over the used ones.
    weights: the robust loss's final weight per motion (1 without robust loss, 0 if dropped;
    after the absolute-pose refinement of ``solutions.mle``, the same Huber rule evaluated at
    its X, as a diagnostic).
    downweighted_motion_indices: motions with weight < DOWNWEIGHT_FLAG (left out of the final
    refit). outlier_pose_indices: poses for which more than half of the used motions touching
    them were down-weighted (needs ``pairs``, the (M, 2) pose indices of each motion).
    """

    X: np.ndarray
    method: str
    n_motions: int
    used: np.ndarray
    rotation_residuals: np.ndarray
    translation_residuals: np.ndarray
    rotation_residual: float
    translation_residual: float
    weights: np.ndarray
    downweighted_motion_indices: tuple[int, ...] = ()
    outlier_pose_indices: tuple[int, ...] = ()
    dropped_motion_indices: tuple[int, ...] = ()
    pairs: np.ndarray | None = None
    mount: str | None = None
    start_method: str | None = None
    notes: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------- small helpers


def _skews(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of a stack of vectors: (M, 3) -> (M, 3, 3)."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian: ``exp(phi + d) ~= exp(J_l(phi) d) exp(phi)`` to first order."""
    theta = np.linalg.norm(phi)
    K = geo.skew(phi)
    if theta < 1e-4:  # series, to avoid 0/0
        a, b = 0.5 - theta**2 / 24.0, 1.0 / 6.0 - theta**2 / 120.0
    else:
        a = (1.0 - np.cos(theta)) / theta**2
        b = (theta - np.sin(theta)) / theta**3
    return np.eye(3) + a * K + b * (K @ K)


def _quat_wxyz(R: np.ndarray, canonical: bool = True) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of a stack of rotations; w >= 0 if ``canonical``, else
    whichever of q, -q SciPy happens to produce."""
    q = Rotation.from_matrix(R).as_quat()  # xyzw
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0) if canonical else q


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of stacks of (w, x, y, z) quaternions."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def _solved(m, X: np.ndarray, method: str) -> np.ndarray:
    """``_check_X``, then a warning if X fits the motions far worse than their noise allows
    (motions built from inverted poses: see ``solutions.diagnostics``)."""
    X = _check_X(X, method)
    diagnostics.check_motion_residuals(m.RA, m.RB, X)
    return X


def _check_X(X: np.ndarray, method: str) -> np.ndarray:
    """Last line of defence: never hand back NaN or a non-rotation."""
    try:
        return geo.as_pose(X, name=f"X from method {method!r}")
    except ValueError as err:
        raise ValueError(
            f"hand-eye method {method!r} produced an invalid pose ({err}); the motions are "
            "probably degenerate: capture poses rotating 15-45 degrees about varied axes"
        ) from None


# --------------------------------------------------------------------------- motions


def motion_pairs(poses, strategy: str = "all", name: str = "poses"):
    """Relative motions between absolute poses.

    For each pair (i, j) with i < j the motion is ``inv(poses[i]) @ poses[j]``: where pose j
    is, seen from pose i (if ``poses`` are ``w_T_f``, the motion is ``f_i T f_j``).

    strategy: ``"consecutive"`` gives the n-1 pairs (i, i+1); ``"all"`` gives all n(n-1)/2
    pairs i < j in lexicographic order (never both (i, j) and (j, i): they carry the same
    information).

    Returns ``(motions (M, 4, 4), pairs (M, 2) int)``.
    """
    P = geo.as_poses(poses, name=name, min_count=2)
    diagnostics.check_choice(strategy, "strategy", PAIR_STRATEGIES, "pair strategy")
    return _motion_pairs(P, strategy)


def _motion_pairs(P: np.ndarray, strategy: str):
    n = len(P)
    if strategy == "all":
        i, j = np.triu_indices(n, k=1)
    elif strategy == "consecutive":
        i, j = np.arange(n - 1), np.arange(1, n)
    else:
        raise ValueError(f"pair strategy must be one of {PAIR_STRATEGIES}, got {strategy!r}")
    return geo.invert(P[i]) @ P[j], np.stack([i, j], axis=1)


def _check_pose_lists(base_T_flange, cam_T_target):
    F = geo.as_poses(base_T_flange, name="base_T_flange")
    C = geo.as_poses(cam_T_target, name="cam_T_target")
    if len(F) != len(C):
        raise ValueError(
            f"mismatched lengths: base_T_flange has {len(F)} poses but cam_T_target has "
            f"{len(C)}; entry i of each must be recorded at the same robot pose"
        )
    if len(F) < 3:
        raise ValueError(
            f"hand-eye calibration needs at least 3 poses (2 motions about different axes), "
            f"got {len(F)}: one motion leaves the rotation about its axis unobservable; "
            "capture 10-20 poses rotating the flange 15-45 degrees about varied axes"
        )
    return F, C


def hand_eye_motions(base_T_flange, cam_T_target, mount: str = "eye_in_hand",
                     strategy: str = "all"):
    """Motions (A, B) with ``A[k] @ X == X @ B[k]`` for pose pairs ``pairs[k] = (i, j)``.

    eye_in_hand (X = flange_T_cam):
        ``A = inv(base_T_flange[i]) @ base_T_flange[j]``,
        ``B = cam_T_target[i] @ inv(cam_T_target[j])``
    eye_to_hand (X = base_T_cam):
        ``A = base_T_flange[i] @ inv(base_T_flange[j])``,
        ``B = cam_T_target[i] @ inv(cam_T_target[j])``

    Inputs are OpenCV's gripper2base and target2cam (see the module docstring); lengths must
    match and n >= 3. Returns ``(A (M, 4, 4), B (M, 4, 4), pairs (M, 2))``.
    """
    F, C = _check_pose_lists(base_T_flange, cam_T_target)
    diagnostics.check_choice(mount, "mount", MOUNTS)
    diagnostics.check_choice(strategy, "strategy", PAIR_STRATEGIES, "pair strategy")
    return _hand_eye_motions(F, C, mount, strategy)


def _hand_eye_motions(F: np.ndarray, C: np.ndarray, mount: str, strategy: str):
    if mount not in MOUNTS:
        raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
    # B = C_i inv(C_j) is motion_pairs of the inverted camera poses, and likewise
    # A = F_i inv(F_j) (eye_to_hand) is motion_pairs of the inverted robot poses.
    robot = F if mount == "eye_in_hand" else geo.invert(F)
    A, pairs = _motion_pairs(robot, strategy)
    B, _ = _motion_pairs(geo.invert(C), strategy)
    return A, B, pairs


@dataclass(frozen=True)
class _Motions:
    """Validated motions that the solvers use (after dropping too-small ones)."""

    RA: np.ndarray
    tA: np.ndarray
    RB: np.ndarray
    tB: np.ndarray
    rvA: np.ndarray
    rvB: np.ndarray
    index: np.ndarray  # positions of these motions in the caller's A, B


def _prepare(A, B, pairs=None, validate: bool = True, from_poses: bool = False) -> _Motions:
    """Validate A, B and screen out unobservable motions; see the module docstring.
    ``from_poses``: A and B were built from pose lists already checked as poses."""
    if validate:
        A = geo.as_poses(A, name="A")
        B = geo.as_poses(B, name="B")
    if len(A) != len(B):
        raise ValueError(
            f"mismatched lengths: A has {len(A)} motions but B has {len(B)}; A[k] and B[k] "
            "must be the same motion seen by the robot and by the camera"
        )
    if len(A) < 2:
        raise ValueError(
            f"AX = XB needs at least 2 motions (3 poses) with different rotation axes, got "
            f"{len(A)}: capture more poses"
        )
    rvA = geo.rotvecs_from_rotations(A[:, :3, :3])
    rvB = geo.rotvecs_from_rotations(B[:, :3, :3])
    # A robot motion and the camera motion it causes rotate by the same angle: if most do not,
    # A[k] and B[k] are not the same motion, and no X can be right. (Motions built here from
    # poses were checked as poses, with a message about the poses.)
    if not from_poses:
        diagnostics.check_motion_pairing(rvA, rvB, pairs)
        # Robot translations in millimetres and camera ones in metres (or the reverse) give a
        # right rotation and a translation hundreds of metres off; poses were checked whole.
        units.check_motion_units(A, B, rvA, rvB)
    keep = diagnostics.screen_motions(rvA, rvB, pairs)
    rvA, rvB = rvA[keep], rvB[keep]
    return _Motions(A[keep, :3, :3], A[keep, :3, 3], B[keep, :3, :3], B[keep, :3, 3],
                    rvA, rvB, keep)


# --------------------------------------------------------------------------- translation


def _translation_ls(m: _Motions, R_X: np.ndarray) -> np.ndarray:
    """t_X from the stacked equations (R_A - I) t_X = R_X t_B - t_A (least squares).

    R_X t_B is replaced by the mean of R_X t_B and R_A R_X R_B^T t_B, which are equal when
    R_A R_X = R_X R_B (so exact data gives exactly the course's equation). The mean makes the
    reversed motion (j, i) give the same equation, up to a rotation, as (i, j), so the answer
    does not depend on the order in which the poses were listed.
    """
    uB = np.einsum("mji,mj->mi", m.RB, m.tB)  # R_B^T t_B
    rhs = 0.5 * (m.tB @ R_X.T + np.einsum("mij,mj->mi", m.RA, uB @ R_X.T)) - m.tA
    lhs = m.RA - np.eye(3)
    t, *_ = np.linalg.lstsq(lhs.reshape(-1, 3), rhs.reshape(-1), rcond=None)
    return t


# --------------------------------------------------------------------------- closed forms


def _tsai(m: _Motions) -> np.ndarray:
    qa, qb = _quat_wxyz(m.RA), _quat_wxyz(m.RB)
    Pa, Pb = 2.0 * qa[:, 1:], 2.0 * qb[:, 1:]  # 2 sin(theta/2) * axis

    def gibbs(Pb_frame):
        # R_X maps Pb to Pa, so Pa - Pb = g x (Pa + Pb) with g = tan(theta_X / 2) * axis_X.
        S = _skews(Pa + Pb_frame).reshape(-1, 3)
        g, _, rank, _ = np.linalg.lstsq(S, (Pb_frame - Pa).reshape(-1), rcond=None)
        return g, rank == 3  # rank 2 when X is exactly a half-turn: g is then meaningless

    def rotation(g):
        return Rotation.from_quat(np.r_[g, 1.0]).as_matrix()  # (g, 1) ~ quaternion xyzw

    g, full_rank = gibbs(Pb)
    if full_rank and np.linalg.norm(g) <= np.tan(np.radians(_TSAI_MAX_DEG) / 2):
        R_X = rotation(g)
    else:
        # X turns by more than 120 deg (or exactly 180 deg: rank 2), where tan(theta/2) is
        # ill-conditioned (infinite at a half-turn, common for fixed cameras). Write
        # R_X = R' H with H a half-turn about x, y or z: then R_A R' = R' (H R_B H^T), whose
        # Pb is H Pb, and for one of the three R' turns by at most 120 deg. A frame where R'
        # is near a half-turn gives a singular system and a meaningless g, so keep the
        # candidate that best fits the motions.
        candidates = [rotation(g)]
        for axis in np.eye(3):
            H = Rotation.from_rotvec(np.pi * axis).as_matrix()
            candidates.append(rotation(gibbs(Pb @ H.T)[0]) @ H)
        misfit = [np.sum((m.RA @ R - R @ m.RB) ** 2) for R in candidates]
        R_X = candidates[int(np.argmin(misfit))]
    return geo.make_pose(geo.project_to_so3(R_X), _translation_ls(m, R_X))


def solve_tsai(A, B) -> np.ndarray:
    """Tsai-Lenz (1989): X from motions ``A[k] @ X == X @ B[k]``.

    Rotation: with modified Rodrigues vectors P = 2 sin(theta/2) * axis of each motion and
    g = tan(theta_X/2) * axis_X, each motion gives skew(P_A + P_B) g = P_B - P_A; g is the
    stacked least-squares solution. (If X turns by more than 120 deg the problem is also
    solved in frames turned by a half-turn about x, y and z, where it is well conditioned, and
    the best fit is kept; see the code.) Translation: stacked least squares
    (R_A - I) t_X = R_X t_B - t_A (order-symmetric form, see ``_translation_ls``).

    Motion inputs, (M, 4, 4) each; returns X (4, 4). Same formulas as OpenCV's
    CALIB_HAND_EYE_TSAI, but without its pair filter that can return identity.
    """
    m = _prepare(A, B)
    return _solved(m, _tsai(m), "tsai")


def _park(m: _Motions) -> np.ndarray:
    # alpha = log R_A, beta = log R_B satisfy alpha = R_X beta; M = sum beta alpha^T.
    M = m.rvB.T @ m.rvA
    # R_X = (M^T M)^(-1/2) M^T is the orthogonal polar factor of M^T, i.e. U V^T from its SVD;
    # forcing det +1 also covers the 2-motion case, where M^T M is singular.
    R_X = geo.project_to_so3(M.T)
    return geo.make_pose(R_X, _translation_ls(m, R_X))


def solve_park(A, B) -> np.ndarray:
    """Park-Martin (1994): X from motions ``A[k] @ X == X @ B[k]``.

    Rotation: alpha_k = log(R_A,k), beta_k = log(R_B,k) (rotation vectors) satisfy
    alpha = R_X beta; with M = sum_k beta_k alpha_k^T, R_X = (M^T M)^(-1/2) M^T.
    Translation: stacked least squares (R_A - I) t_X = R_X t_B - t_A (order-symmetric form,
    see ``_translation_ls``; OpenCV uses the plain one, so translations differ within noise).
    Returns X (4, 4). Same formulas as OpenCV's CALIB_HAND_EYE_PARK.
    """
    m = _prepare(A, B)
    return _solved(m, _park(m), "park")


def _dual_quats(R: np.ndarray, t: np.ndarray):
    """(real, dual) parts of unit dual quaternions of poses; dual = 1/2 (0, t) q."""
    q = _quat_wxyz(R, canonical=False)
    tq = np.concatenate([np.zeros((len(t), 1)), t], axis=1)
    return q, 0.5 * _qmul(tq, q)


def _daniilidis(m: _Motions) -> np.ndarray:
    a, a_d = _dual_quats(m.RA, m.tA)
    b, b_d = _dual_quats(m.RB, m.tB)
    # q and -q are the same rotation, but a q = q b holds only for the sign of b whose scalar
    # part equals a's (rotation angles of A and B are equal): flip b (and its dual) where the
    # scalar parts disagree in sign.
    flip = np.where(a[:, 0] * b[:, 0] < 0, -1.0, 1.0)[:, None]
    b, b_d = b * flip, b_d * flip
    # Vector part of a q - q b = 0 is (a - b) q_w + [a + b]x q_v = 0 (same for the dual part).
    av, bv, adv, bdv = a[:, 1:], b[:, 1:], a_d[:, 1:], b_d[:, 1:]
    M = len(av)
    T = np.zeros((M, 6, 8))
    T[:, :3, 0], T[:, :3, 1:4] = av - bv, _skews(av + bv)
    T[:, 3:, 0], T[:, 3:, 1:4] = adv - bdv, _skews(adv + bdv)
    T[:, 3:, 4], T[:, 3:, 5:8] = av - bv, _skews(av + bv)
    _, _, Vt = np.linalg.svd(T.reshape(6 * M, 8), full_matrices=False)
    v1, v2 = Vt[-2], Vt[-1]  # the (near) null space is spanned by these two
    u1, w1, u2, w2 = v1[:4], v1[4:], v2[:4], v2[4:]
    # The solution l1 v1 + l2 v2 must be a unit dual quaternion: q . q' = 0 is the quadratic
    # form l^T Q l = 0; solve it in Q's eigenbasis (no division by a possibly tiny coefficient).
    Q = np.array([[u1 @ w1, 0.5 * (u1 @ w2 + u2 @ w1)], [0.5 * (u1 @ w2 + u2 @ w1), u2 @ w2]])
    mu, V = np.linalg.eigh(Q)
    if mu[0] <= 0.0 <= mu[1]:
        y = np.sqrt(np.abs([mu[1], mu[0]]))
        candidates = [V @ (y * [1.0, s]) for s in (1.0, -1.0)]
    else:  # noise made Q definite: take the direction closest to satisfying it
        candidates = [V[:, np.argmin(np.abs(mu))]]
    # Of the two roots, the right one has the larger real part for the same l (|q| = 1 then
    # needs the smaller scaling).
    lam = max(candidates, key=lambda c: np.linalg.norm(c[0] * u1 + c[1] * u2))
    q = lam[0] * u1 + lam[1] * u2
    q_d = lam[0] * w1 + lam[1] * w2
    scale = np.linalg.norm(q)
    q, q_d = q / scale, q_d / scale
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    t = 2.0 * _qmul(q_d[None], conj[None])[0, 1:]
    R_X = Rotation.from_quat(np.r_[q[1:], q[0]]).as_matrix()
    return geo.make_pose(R_X, t)


def solve_daniilidis(A, B) -> np.ndarray:
    """Daniilidis (1999): X from motions via unit dual quaternions.

    Each motion's dual quaternions (a, a') and (b, b') -- with b's sign chosen so that the
    scalar parts of a and b agree -- give 6 linear equations in X's dual quaternion (q, q'):
    ``[a - b, [a + b]x, 0, 0; a' - b', [a' + b']x, a - b, [a + b]x] (q, q') = 0``. The two
    right singular vectors of the stacked 6M x 8 matrix with the smallest singular values span
    the solution; the unit-norm and q.q' = 0 constraints fix the combination.
    Returns X (4, 4). Same method as OpenCV's CALIB_HAND_EYE_DANIILIDIS.
    """
    m = _prepare(A, B)
    return _solved(m, _daniilidis(m), "daniilidis")


def _axes_ls(m: _Motions) -> np.ndarray:
    # omega_A = R_X omega_B for every motion: a linear least-squares problem in R_X's 9
    # entries (rows: omega_B^T R_X^T = omega_A^T). Rotation vectors are used, so larger and
    # better-determined motions weigh more.
    Rt_lin, *_ = np.linalg.lstsq(m.rvB, m.rvA, rcond=None)
    R0 = geo.project_to_so3(Rt_lin.T)

    # Orthogonalise by minimising the same equations over proper rotations exp(d) R0.
    def residual(d):
        return (m.rvB @ (Rotation.from_rotvec(d).as_matrix() @ R0).T - m.rvA).ravel()

    def jacobian(d):
        v = m.rvB @ (Rotation.from_rotvec(d).as_matrix() @ R0).T
        return (-_skews(v) @ _left_jacobian(d)).reshape(-1, 3)

    sol = least_squares(residual, np.zeros(3), jac=jacobian, method="lm", xtol=1e-14, ftol=1e-14)
    R_X = Rotation.from_rotvec(sol.x).as_matrix() @ R0
    return geo.make_pose(R_X, _translation_ls(m, R_X))


def solve_axes_ls(A, B) -> np.ndarray:
    """Rotation-axis least squares: X from motions ``A[k] @ X == X @ B[k]``.

    Rotation: the stacked equations omega_A = R_X omega_B (omega: rotation vectors) solved as
    a 9-unknown linear least squares, projected onto SO(3) by SVD, then refined by nonlinear
    least squares over proper rotations (a rotation-vector correction of that projection).
    Translation: stacked least squares (R_A - I) t_X = R_X t_B - t_A. Returns X (4, 4).

    The orthogonalised rotation minimises sum ||omega_A - R omega_B||^2 over rotations, the
    orthogonal Procrustes problem, whose solution is Park-Martin's polar factor: the two
    methods agree to solver tolerance. This one shows the general route (linear least
    squares, then a constrained refinement); Park's shows the closed form.
    """
    m = _prepare(A, B)
    return _solved(m, _axes_ls(m), "axes_ls")


_CLOSED_FORMS = {"tsai": _tsai, "park": _park, "daniilidis": _daniilidis, "axes_ls": _axes_ls}
# Candidates for the nonlinear method's start: the purely algebraic ones (axes_ls would only
# add another least-squares solve, and its rotation is Park's).
_START_METHODS = ("tsai", "park", "daniilidis")


# --------------------------------------------------------------------------- nonlinear


def _residual_blocks(m: _Motions, R: np.ndarray, t: np.ndarray):
    """Per-motion rotation residual R_A R_X - R_X R_B (M, 3, 3) and the order-symmetric
    translation residual (R_A - I) t_X + t_A - (R_X t_B + R_A R_X R_B^T t_B) / 2 (M, 3)."""
    uB = np.einsum("mji,mj->mi", m.RB, m.tB)
    E = m.RA @ R - R @ m.RB
    e = (np.einsum("mij,j->mi", m.RA, t) - t + m.tA
         - 0.5 * (m.tB @ R.T + np.einsum("mij,mj->mi", m.RA, uB @ R.T)))
    return E, e


def _motion_costs(m: _Motions, X: np.ndarray, s_rot: float, s_trans: float) -> np.ndarray:
    """Each motion's normalised residual norm (the quantity the robust loss acts on)."""
    E, e = _residual_blocks(m, X[:3, :3], X[:3, 3])
    return np.sqrt(np.sum(E**2, axis=(1, 2)) / s_rot**2 + np.sum(e**2, axis=1) / s_trans**2)


class _RefineProblem:
    """Residuals and analytic Jacobian of the weighted AX = XB cost, for least_squares.

    Parameters p = (d, dt) give X = (exp([d]x) R0, t0 + dt). Per motion k the residual is
    sqrt(w_k) * [vec(R_A R_X - R_X R_B) / s_rot (9), e_k / s_trans (3)], each block divided by
    its typical size so that neither dominates because of its units, and e_k the translation
    residual of ``_residual_blocks``. Everything is vectorised over motions.
    """

    def __init__(self, m: _Motions, X0: np.ndarray, weights: np.ndarray, s_rot: float,
                 s_trans: float):
        self.m, self.R0, self.t0 = m, X0[:3, :3], X0[:3, 3]
        self.s_rot, self.s_trans = s_rot, s_trans
        self.sw = np.sqrt(weights)[:, None]
        self.uB = np.einsum("mji,mj->mi", m.RB, m.tB)  # R_B^T t_B

    def pose(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return Rotation.from_rotvec(p[:3]).as_matrix() @ self.R0, self.t0 + p[3:]

    def residuals(self, p: np.ndarray) -> np.ndarray:
        E, e = _residual_blocks(self.m, *self.pose(p))
        M = len(E)
        return (self.sw * np.hstack([E.reshape(M, 9) / self.s_rot, e / self.s_trans])).ravel()

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        m, (R, _) = self.m, self.pose(p)
        M = len(m.RA)
        G = _left_jacobian(p[:3])  # d R_X = [G dd]x R_X
        J = np.zeros((M, 12, 6))
        for k in range(3):  # a loop over parameters, not over motions
            dR = geo.skew(G[:, k]) @ R
            J[:, :9, k] = (m.RA @ dR - dR @ m.RB).reshape(M, 9) / self.s_rot
            J[:, 9:, k] = -0.5 * (m.tB @ dR.T
                                  + np.einsum("mij,mj->mi", m.RA, self.uB @ dR.T)) / self.s_trans
        J[:, 9:, 3:] = (m.RA - np.eye(3)) / self.s_trans
        return (self.sw[:, :, None] * J).reshape(12 * M, 6)


def _refine(m: _Motions, X0: np.ndarray, weights: np.ndarray, s_rot: float,
            s_trans: float) -> np.ndarray:
    """Minimise sum_k w_k (||R_A R_X - R_X R_B||_F^2 / s_rot^2 + ||e_k||^2 / s_trans^2) over
    X on SO(3) x R^3 from X0 (Levenberg-Marquardt, analytic Jacobian)."""
    problem = _RefineProblem(m, X0, weights, s_rot, s_trans)
    sol = least_squares(problem.residuals, np.zeros(6), jac=problem.jacobian, method="lm",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12)
    R, t = problem.pose(sol.x)
    return geo.make_pose(geo.project_to_so3(R), t)


def _huber_weights(d: np.ndarray) -> np.ndarray:
    """Huber IRLS weights of per-motion residual norms, threshold HUBER_K x their median."""
    c = HUBER_K * max(float(np.median(d)), 1e-9)
    return np.minimum(1.0, c / np.maximum(d, 1e-300))


def _best_start(m: _Motions, robust: bool):
    """The closed form with the smallest (median if robust, else mean) normalised residual,
    and the residual scales used to normalise."""
    candidates = {name: _CLOSED_FORMS[name](m) for name in _START_METHODS}
    blocks = {name: _residual_blocks(m, X[:3, :3], X[:3, 3]) for name, X in candidates.items()}
    rot = {k: np.sqrt(np.sum(E**2, axis=(1, 2))) for k, (E, _) in blocks.items()}
    tra = {k: np.linalg.norm(e, axis=1) for k, (_, e) in blocks.items()}
    s_rot = max(min(np.median(v) for v in rot.values()), _ROT_SCALE_FLOOR)
    s_trans = max(min(np.median(v) for v in tra.values()), _TRANS_SCALE_FLOOR_M)
    average = np.median if robust else np.mean
    score = {k: average((rot[k] / s_rot) ** 2 + (tra[k] / s_trans) ** 2) for k in candidates}
    name = min(score, key=score.get)
    return name, candidates[name], s_rot, s_trans


def _nonlinear(m: _Motions, robust: bool):
    """(X, weights, start method, scales). Robust: Huber on each motion's whole residual,
    solved by iteratively reweighted least squares."""
    start, X, s_rot, s_trans = _best_start(m, robust)
    weights = _huber_weights(_motion_costs(m, X, s_rot, s_trans)) if robust else np.ones(len(m.RA))
    for _ in range(_MAX_IRLS):
        X = _refine(m, X, weights, s_rot, s_trans)
        if not robust:
            break
        new = _huber_weights(_motion_costs(m, X, s_rot, s_trans))
        converged = np.max(np.abs(new - weights)) < 1e-6
        weights = new
        if converged:
            break
    flagged = weights < DOWNWEIGHT_FLAG
    if robust and flagged.any() and diagnostics.axis_spread_deg(m.rvA[~flagged]) >= MIN_AXIS_SPREAD_DEG:
        # Huber bounds an outlier's pull but does not remove it, and one bad pose spoils all
        # n-1 motions that touch it: refit once without the motions Huber flagged.
        X = _refine(m, X, np.where(flagged, 0.0, 1.0), s_rot, s_trans)
    return X, weights, start, (s_rot, s_trans)


def solve_nonlinear(A, B, robust: bool = True) -> np.ndarray:
    """Joint refinement of R_X and t_X on SO(3) x R^3 from motions ``A[k] @ X == X @ B[k]``.

    Starts from the Tsai, Park or Daniilidis solution with the smallest residual and
    minimises, by Levenberg-Marquardt with an analytic Jacobian,
    ``sum_k w_k (||R_A R_X - R_X R_B||_F^2 / s_rot^2 + ||e_k||^2 / s_trans^2)``, where
    e_k is the translation residual R_A t_X + t_A - R_X t_B - t_X (with R_X t_B taken as the
    mean of R_X t_B and R_A R_X R_B^T t_B, so that reversing a motion changes nothing) and
    s_rot, s_trans are the median residuals at the start.

    robust=True: Huber weights w_k on each motion's whole residual (threshold HUBER_K x the
    median residual), by iteratively reweighted least squares; then one refit without the
    motions Huber gave less than half weight (their residual exceeds 4x the median). Weighting
    whole motions, not residual components, keeps a motion's weight independent of the frame
    its residual is written in, so reversing a motion or reordering poses changes nothing.
    See ``solve_ax_xb_report`` for the down-weighted motions. Returns X (4, 4).
    """
    robust = diagnostics.check_flag(robust, "robust")
    m = _prepare(A, B)
    X, *_ = _nonlinear(m, robust)
    return _solved(m, X, "nonlinear")


# --------------------------------------------------------------------------- metrics


def _course_residuals(RA, tA, RB, tB, X):
    R, t = X[:3, :3], X[:3, 3]
    rot = np.sum((RA @ R - R @ RB) ** 2, axis=(1, 2))
    trans = np.sum((np.einsum("mij,j->mi", RA, t) + tA - tB @ R.T - t) ** 2, axis=1)
    return rot, trans


def motion_residuals(A, B, X):
    """Per-motion residuals (course definitions): ``(||R_A R_X - R_X R_B||_F^2 (M,),
    ||R_A t_X + t_A - R_X t_B - t_X||^2 (M,) in metres^2)``."""
    A, B = geo.as_poses(A, name="A"), geo.as_poses(B, name="B")
    X = geo.as_pose(X, name="X")
    if len(A) != len(B) or len(A) == 0:
        raise ValueError(
            f"need the same non-zero number of motions in A and B, got {len(A)} and {len(B)}"
        )
    return _course_residuals(A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3], X)


def rotation_residual(A, B, X) -> float:
    """Mean rotational error (1/n) sum ||R_A R_X - R_X R_B||_F^2 over n motions (dimensionless)."""
    return float(np.mean(motion_residuals(A, B, X)[0]))


def translation_residual(A, B, X) -> float:
    """Mean translational error (1/n) sum ||R_A t_X + t_A - R_X t_B - t_X||^2 (metres^2)."""
    return float(np.mean(motion_residuals(A, B, X)[1]))


# --------------------------------------------------------------------------- dispatch


def _flagged_poses(down: np.ndarray, used_pairs: np.ndarray) -> tuple[int, ...]:
    """Poses for which more than half of the used motions touching them are down-weighted."""
    if used_pairs is None or len(used_pairs) == 0:
        return ()
    n = int(used_pairs.max()) + 1
    touching = np.bincount(used_pairs.ravel(), minlength=n)
    flagged = np.bincount(used_pairs[down].ravel(), minlength=n)
    return tuple(int(p) for p in np.flatnonzero(2 * flagged > touching))


def _check_options(method, robust):
    """The method and robust arguments of the solvers, checked (robust as a bool or None)."""
    diagnostics.check_choice(method, "method", METHODS, "hand-eye method")
    return diagnostics.check_flag(robust, "robust", allow_none=True)


def _check_pairs(pairs, n_motions: int):
    """``pairs`` given to ``solve_ax_xb_report``: None or (M, 2) non-negative pose indices."""
    if pairs is None:
        return None
    P = diagnostics.as_array(pairs, "pairs", f"an ({n_motions}, 2) array of pose indices (i, j) "
                                             "of each motion, or None")
    if P.shape != (n_motions, 2) or not np.all(np.isfinite(P)) or np.any(P < 0) or np.any(
            P != np.round(P)):
        raise ValueError(f"pairs must be an ({n_motions}, 2) array of non-negative integer pose "
                         f"indices (i, j), one row per motion in A and B, or None; got "
                         f"{diagnostics.describe(pairs if isinstance(pairs, np.ndarray) else P)}")
    return P.astype(int)


def _report(A, B, method, robust, pairs, validate, mount=None) -> HandEyeResult:
    robust = _check_options(method, robust)
    if robust is None:
        robust = method == "nonlinear"
    if robust and method != "nonlinear":
        raise ValueError(
            f"robust=True needs method='nonlinear' (the closed form {method!r} has no loss to "
            "make robust)"
        )
    if validate:
        A, B = geo.as_poses(A, name="A"), geo.as_poses(B, name="B")
        pairs = _check_pairs(pairs, len(A)) if len(A) == len(B) else pairs
    m = _prepare(A, B, pairs, validate=False, from_poses=not validate)
    start = None
    if method == "nonlinear":
        X, w_used, start, _ = _nonlinear(m, robust)
    else:
        X, w_used = _CLOSED_FORMS[method](m), np.ones(len(m.RA))
    # Motions given directly (validate) get the motion-level check; poses were checked whole.
    X = _solved(m, X, method) if validate else _check_X(X, method)
    return _assemble(A, B, m, X, method, w_used, pairs, mount, start)


def _assemble(A, B, m, X, method, w_used, pairs, mount, start) -> HandEyeResult:
    rot, trans = _course_residuals(A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3], X)
    used = np.zeros(len(A), dtype=bool)
    used[m.index] = True
    weights = np.zeros(len(A))
    weights[m.index] = w_used
    down = w_used < DOWNWEIGHT_FLAG
    pairs = None if pairs is None else np.asarray(pairs)
    return HandEyeResult(
        X=X, method=method, n_motions=int(used.sum()), used=used,
        rotation_residuals=rot, translation_residuals=trans,
        rotation_residual=float(rot[used].mean()), translation_residual=float(trans[used].mean()),
        weights=weights, downweighted_motion_indices=tuple(int(k) for k in m.index[down]),
        outlier_pose_indices=_flagged_poses(down, None if pairs is None else pairs[m.index]),
        dropped_motion_indices=tuple(int(k) for k in np.flatnonzero(~used)),
        pairs=pairs, mount=mount, start_method=start,
    )


def solve_ax_xb_report(A, B, method: str = "park", robust: bool | None = None,
                       pairs=None) -> HandEyeResult:
    """Solve ``A[k] @ X == X @ B[k]`` and report residuals and down-weighted motions.

    A, B: (M, 4, 4) motions (robot side, camera side; see ``hand_eye_motions``). method: one
    of ``METHODS``. robust: Huber loss on each motion (only for ``"nonlinear"``; None means
    True for "nonlinear", False otherwise). pairs: optional (M, 2) pose indices of each
    motion, used to name motions in messages and to report ``outlier_pose_indices``.
    """
    return _report(A, B, method, robust, pairs, validate=True)


def solve_ax_xb(A, B, method: str = "park", robust: bool | None = None) -> np.ndarray:
    """X (4, 4) with ``A[k] @ X == X @ B[k]`` by ``method`` (see ``solve_ax_xb_report``)."""
    return solve_ax_xb_report(A, B, method, robust).X


# --------------------------------------------------------------------------- calibration


def _absolute_refinement():
    """``solutions.mle.refine_hand_eye`` if that module exists, else None."""
    try:
        from solutions.mle import refine_hand_eye
    except ModuleNotFoundError as err:
        if err.name != "solutions.mle":
            raise
        return None
    return refine_hand_eye


def _calibrate(base_T_flange, cam_T_target, mount, method, pairs, robust) -> HandEyeResult:
    robust = _check_options(method, robust)
    diagnostics.check_choice(pairs, "pairs", PAIR_STRATEGIES, "pair strategy")
    F, C = _check_pose_lists(base_T_flange, cam_T_target)
    diagnostics.check_choice(mount, "mount", MOUNTS)
    A, B, pose_pairs = _hand_eye_motions(F, C, mount, pairs)
    refine = _absolute_refinement() if method == "nonlinear" else None
    if refine is None:
        # Inverted poses, the wrong mount or lists not paired view by view give every method
        # a wrong X with large residuals, not an error: refuse them, naming the likely cause.
        # (solutions.mle.refine_hand_eye makes the same check itself.)
        diagnostics.check_hand_eye_poses(F, C, mount)
        report = _report(A, B, method, robust, pose_pairs, validate=False, mount=mount)
        if method == "nonlinear":
            # Without solutions/mle.py the motion-based refinement stands in for the
            # absolute-pose maximum-likelihood one.
            report.notes.append("solutions.mle missing: motion-based nonlinear refinement only")
        return report
    robust = True if robust is None else bool(robust)
    m = _prepare(A, B, pose_pairs, validate=False, from_poses=True)
    # The absolute-pose refinement starts from Li's AX = YB closed form on the poses themselves
    # (one linear solve: cheaper than trying every motion-based closed form, and as good a start).
    refined = refine(F, C, mount=mount, robust=robust)
    X = _check_X(refined.X, "nonlinear (solutions.mle.refine_hand_eye)")
    # Motion weights are a diagnostic here: the motion-based Huber rule applied at the final X,
    # each residual block scaled by its median there.
    w = np.ones(len(m.RA))
    if robust:
        E, e = _residual_blocks(m, X[:3, :3], X[:3, 3])
        s_rot = max(float(np.median(np.sqrt(np.sum(E**2, axis=(1, 2))))), _ROT_SCALE_FLOOR)
        s_trans = max(float(np.median(np.linalg.norm(e, axis=1))), _TRANS_SCALE_FLOOR_M)
        w = _huber_weights(_motion_costs(m, X, s_rot, s_trans))
    out = _assemble(A, B, m, X, "nonlinear", w, pose_pairs, mount, "li")
    out.notes.append("refined by solutions.mle.refine_hand_eye (absolute poses)")
    # The estimator that produced X decides which poses it rejected.
    pose_outliers = tuple(
        int(i) for i in getattr(refined, "outlier_indices", out.outlier_pose_indices))
    if pose_outliers != out.outlier_pose_indices:
        out.notes.append(f"motion residuals at X point at poses {out.outlier_pose_indices}")
    out.outlier_pose_indices = pose_outliers
    return out


def calibrate_eye_in_hand_report(base_T_flange, cam_T_target, method: str = "nonlinear",
                                 pairs: str = "all", robust: bool | None = None) -> HandEyeResult:
    """``calibrate_eye_in_hand`` returning a ``HandEyeResult`` (residuals per motion, motion
    pairs, and ``outlier_pose_indices``: poses most of whose motions the robust loss
    down-weighted)."""
    return _calibrate(base_T_flange, cam_T_target, "eye_in_hand", method, pairs, robust)


def calibrate_eye_to_hand_report(base_T_flange, cam_T_target, method: str = "nonlinear",
                                 pairs: str = "all", robust: bool | None = None) -> HandEyeResult:
    """``calibrate_eye_to_hand`` returning a ``HandEyeResult`` (see the eye-in-hand variant)."""
    return _calibrate(base_T_flange, cam_T_target, "eye_to_hand", method, pairs, robust)


def calibrate_eye_in_hand(base_T_flange, cam_T_target, method: str = "nonlinear",
                          pairs: str = "all", robust: bool | None = None) -> np.ndarray:
    """Camera on the flange, board fixed: ``flange_T_cam`` (4, 4), metres.

    base_T_flange: (n, 4, 4) robot poses as the controller reports them (OpenCV's
    gripper2base); cam_T_target: (n, 4, 4) board poses seen by the camera (OpenCV's
    target2cam, e.g. from solvePnP). Nothing is inverted relative to
    ``cv2.calibrateHandEye``, whose output cam2gripper is this function's result.
    method: one of ``METHODS``; pairs: ``"all"`` or ``"consecutive"`` motions.
    ``"nonlinear"`` (default) refines the best closed form, robustly unless robust=False,
    with the absolute-pose refinement of ``solutions.mle`` when available.
    """
    return calibrate_eye_in_hand_report(base_T_flange, cam_T_target, method, pairs, robust).X


def calibrate_eye_to_hand(base_T_flange, cam_T_target, method: str = "nonlinear",
                          pairs: str = "all", robust: bool | None = None) -> np.ndarray:
    """Camera fixed, board on the flange: ``base_T_cam`` (4, 4), metres.

    base_T_flange: (n, 4, 4) robot poses as the controller reports them (gripper2base) --
    NOT inverted: OpenCV's eye-to-hand recipe passes base2gripper = inv(base_T_flange), this
    function takes base_T_flange itself. cam_T_target: (n, 4, 4) (target2cam). The result is
    OpenCV's cam2base. Other arguments as ``calibrate_eye_in_hand``.
    """
    return calibrate_eye_to_hand_report(base_T_flange, cam_T_target, method, pairs, robust).X
