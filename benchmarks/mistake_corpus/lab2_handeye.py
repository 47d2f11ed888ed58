"""Lab 2 (AX = XB hand-eye calibration): classic mistakes in motions, tsai_lenz, axes_ls,
rotation_residual and translation_residual (see ``mistake_corpus``).

Conventions of the lab: X = flange_T_cam, A = inv(F_i) @ F_j, B = C_i @ inv(C_j) for the pair
i < j, so that A @ X == X @ B.
"""

from __future__ import annotations

import numpy as np

from mistake_corpus import pose as _pose
from mistake_corpus import register
from robots import geometry as geo

mistake = register("lab2_handeye")


def _pairs(n, strategy):
    if strategy == "all":
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    if strategy == "consecutive":
        return [(i, i + 1) for i in range(n - 1)]
    raise ValueError(f"strategy must be 'all' or 'consecutive', got {strategy!r}")


def _tsai_rotation(A, B, rodrigues):
    """R_X by Tsai-Lenz from the modified Rodrigues vectors ``rodrigues(T)``."""
    lhs, rhs = [], []
    for Ak, Bk in zip(A, B):
        PA, PB = rodrigues(Ak), rodrigues(Bk)
        lhs.append(geo.skew(PA + PB))
        rhs.append(PB - PA)
    P_prime = np.linalg.lstsq(np.vstack(lhs), np.concatenate(rhs), rcond=None)[0]
    P = 2.0 * P_prime / np.sqrt(1.0 + P_prime @ P_prime)
    return ((1.0 - P @ P / 2.0) * np.eye(3)
            + 0.5 * (np.outer(P, P) + np.sqrt(4.0 - P @ P) * geo.skew(P)))


def _modified_rodrigues(T):
    rotvec, _ = geo.rotvec_from_pose(T)
    theta = np.linalg.norm(rotvec)
    return 2.0 * np.sin(theta / 2.0) * rotvec / theta


def _translation(A, B, R_X):
    M = np.vstack([Ak[:3, :3] - np.eye(3) for Ak in A])
    v = np.concatenate([R_X @ Bk[:3, 3] - Ak[:3, 3] for Ak, Bk in zip(A, B)])
    return np.linalg.lstsq(M, v, rcond=None)[0]


def _axes_rotation(A, B):
    omega_A = np.array([geo.rotvec_from_pose(Ak)[0] for Ak in A])
    omega_B = np.array([geo.rotvec_from_pose(Bk)[0] for Bk in B])
    M = np.linalg.lstsq(omega_B, omega_A, rcond=None)[0].T
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


# --------------------------------------------------------------------------- motions


@mistake("motions", "none", "for 'consecutive' I looped i over range(n) with j = (i + 1) % n, "
         "so I also paired the last pose with the first", names=r"consecutive|\(i, i ?\+ ?1\)")
def motions_wraparound(base_T_flange, cam_T_target, strategy="all"):
    F, C = np.asarray(base_T_flange, float), np.asarray(cam_T_target, float)
    n = len(F)
    pairs = (_pairs(n, "all") if strategy == "all"
             else [(i, (i + 1) % n) for i in range(n)])
    A = np.array([geo.invert(F[i]) @ F[j] for i, j in pairs])
    B = np.array([C[i] @ geo.invert(C[j]) for i, j in pairs])
    return A, B


@mistake("motions", "none", "I returned the poses of the second view of each pair, not the "
         "motions between the two views", names=r"absolute|relative|motion")
def motions_absolute_poses(base_T_flange, cam_T_target, strategy="all"):
    F, C = np.asarray(base_T_flange, float), np.asarray(cam_T_target, float)
    pairs = _pairs(len(F), strategy)
    return np.array([F[j] for _, j in pairs]), np.array([C[j] for _, j in pairs])


@mistake("motions", "inverse/transpose", "I inverted F_i with F_i.T, the transpose of the "
         "whole 4x4 pose, not its inverse")
def motions_transpose_for_inverse(base_T_flange, cam_T_target, strategy="all"):
    F, C = np.asarray(base_T_flange, float), np.asarray(cam_T_target, float)
    pairs = _pairs(len(F), strategy)
    A = np.array([F[i].T @ F[j] for i, j in pairs])
    B = np.array([C[i] @ geo.invert(C[j]) for i, j in pairs])
    return A, B


@mistake("motions", "reversed stack/order", "for 'all' I listed the pairs by j first "
         "(for j ... for i < j): the same pairs, in another order than asked")
def motions_pairs_out_of_order(base_T_flange, cam_T_target, strategy="all"):
    F, C = np.asarray(base_T_flange, float), np.asarray(cam_T_target, float)
    n = len(F)
    pairs = ([(i, j) for j in range(n) for i in range(j)] if strategy == "all"
             else _pairs(n, strategy))
    A = np.array([geo.invert(F[i]) @ F[j] for i, j in pairs])
    B = np.array([C[i] @ geo.invert(C[j]) for i, j in pairs])
    return A, B


# --------------------------------------------------------------------------- tsai_lenz


@mistake("tsai_lenz", "none", "I forgot the factor 2 in P = 2 P' / sqrt(1 + |P'|^2)",
         names=r"2 ?P'|factor (of )?2|twice")
def tsai_p_conversion_without_2(A, B):
    lhs, rhs = [], []
    for Ak, Bk in zip(A, B):
        PA, PB = _modified_rodrigues(Ak), _modified_rodrigues(Bk)
        lhs.append(geo.skew(PA + PB))
        rhs.append(PB - PA)
    P_prime = np.linalg.lstsq(np.vstack(lhs), np.concatenate(rhs), rcond=None)[0]
    P = P_prime / np.sqrt(1.0 + P_prime @ P_prime)
    R_X = ((1.0 - P @ P / 2.0) * np.eye(3)
           + 0.5 * (np.outer(P, P) + np.sqrt(4.0 - P @ P) * geo.skew(P)))
    return _pose(R_X, _translation(A, B, R_X))


@mistake("tsai_lenz", "sign", "I wrote the right-hand side as P_A - P_B instead of "
         "P_B - P_A", also=("inverse/transpose",))  # -P gives exactly R_X^T
def tsai_rhs_sign(A, B):
    lhs, rhs = [], []
    for Ak, Bk in zip(A, B):
        PA, PB = _modified_rodrigues(Ak), _modified_rodrigues(Bk)
        lhs.append(geo.skew(PA + PB))
        rhs.append(PA - PB)
    P_prime = np.linalg.lstsq(np.vstack(lhs), np.concatenate(rhs), rcond=None)[0]
    P = 2.0 * P_prime / np.sqrt(1.0 + P_prime @ P_prime)
    R_X = ((1.0 - P @ P / 2.0) * np.eye(3)
           + 0.5 * (np.outer(P, P) + np.sqrt(4.0 - P @ P) * geo.skew(P)))
    return _pose(R_X, _translation(A, B, R_X))


@mistake("tsai_lenz", "sign", "in the translation system I stacked R_A + I instead of "
         "R_A - I")
def tsai_translation_plus_identity(A, B):
    R_X = _tsai_rotation(A, B, _modified_rodrigues)
    M = np.vstack([Ak[:3, :3] + np.eye(3) for Ak in A])
    v = np.concatenate([R_X @ Bk[:3, 3] - Ak[:3, 3] for Ak, Bk in zip(A, B)])
    return _pose(R_X, np.linalg.lstsq(M, v, rcond=None)[0])


@mistake("tsai_lenz", "none", "I used P' from the least squares directly as P, without "
         "P = 2 P' / sqrt(1 + |P'|^2)", names=r"P'|P_prime|sqrt\(1")
def tsai_p_prime_unconverted(A, B):
    lhs, rhs = [], []
    for Ak, Bk in zip(A, B):
        PA, PB = _modified_rodrigues(Ak), _modified_rodrigues(Bk)
        lhs.append(geo.skew(PA + PB))
        rhs.append(PB - PA)
    P = np.linalg.lstsq(np.vstack(lhs), np.concatenate(rhs), rcond=None)[0]
    R_X = ((1.0 - P @ P / 2.0) * np.eye(3)
           + 0.5 * (np.outer(P, P) + np.sqrt(4.0 - P @ P) * geo.skew(P)))
    return _pose(R_X, _translation(A, B, R_X))


# --------------------------------------------------------------------------- axes_ls


@mistake("axes_ls", "inverse/transpose", "I forgot the .T after lstsq: it solves "
         "omega_B M^T = omega_A row by row, so it returns M^T")
def axes_lstsq_not_transposed(A, B):
    omega_A = np.array([geo.rotvec_from_pose(Ak)[0] for Ak in A])
    omega_B = np.array([geo.rotvec_from_pose(Bk)[0] for Bk in B])
    M = np.linalg.lstsq(omega_B, omega_A, rcond=None)[0]
    U, _, Vt = np.linalg.svd(M)
    R_X = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return _pose(R_X, _translation(A, B, R_X))


@mistake("axes_ls", "none", "I never projected M onto the rotations (the SVD step): I "
         "returned the least-squares M itself", names=r"project|orthonormal|SVD|not a rotation")
def axes_no_projection(A, B):
    omega_A = np.array([geo.rotvec_from_pose(Ak)[0] for Ak in A])
    omega_B = np.array([geo.rotvec_from_pose(Bk)[0] for Bk in B])
    M = np.linalg.lstsq(omega_B, omega_A, rcond=None)[0].T
    return _pose(M, _translation(A, B, M))


@mistake("axes_ls", "inverse/transpose", "in the translation equations I rotated t_B by "
         "R_X^T instead of R_X")
def axes_translation_transposed(A, B):
    R_X = _axes_rotation(A, B)
    return _pose(R_X, _translation(A, B, R_X.T))


@mistake("axes_ls", "sign", "I wrote the right-hand side as t_A - R_X t_B, the wrong sign, "
         "so t_X came out negated")
def axes_translation_sign(A, B):
    R_X = _axes_rotation(A, B)
    M = np.vstack([Ak[:3, :3] - np.eye(3) for Ak in A])
    v = np.concatenate([Ak[:3, 3] - R_X @ Bk[:3, 3] for Ak, Bk in zip(A, B)])
    return _pose(R_X, np.linalg.lstsq(M, v, rcond=None)[0])


# --------------------------------------------------------------------------- residuals


@mistake("rotation_residual", "reversed stack/order", "I wrote R_X R_A - R_B R_X, the "
         "products in the wrong order", also=("inverse/transpose",))
def rotation_residual_product_order(A, B, X):
    R_X = X[:3, :3]
    return float(np.mean([np.sum((R_X @ Ak[:3, :3] - Bk[:3, :3] @ R_X) ** 2)
                          for Ak, Bk in zip(A, B)]))


@mistake("rotation_residual", "none", "I took the median over the motions, not the mean",
         names=r"median")
def rotation_residual_median(A, B, X):
    R_X = X[:3, :3]
    return float(np.median([np.sum((Ak[:3, :3] @ R_X - R_X @ Bk[:3, :3]) ** 2)
                            for Ak, Bk in zip(A, B)]))


@mistake("rotation_residual", "first/last for mean", "my loop overwrote the residual each "
         "time, so I returned the last motion's, not the mean")
def rotation_residual_last_motion(A, B, X):
    R_X = X[:3, :3]
    for Ak, Bk in zip(A, B):
        residual = np.sum((Ak[:3, :3] @ R_X - R_X @ Bk[:3, :3]) ** 2)
    return float(residual)


@mistake("rotation_residual", "none", "I multiplied the rotations with * (element by "
         "element) instead of @", names=r"element|@|matmul")
def rotation_residual_elementwise(A, B, X):
    R_X = X[:3, :3]
    return float(np.mean([np.sum((Ak[:3, :3] * R_X - R_X * Bk[:3, :3]) ** 2)
                          for Ak, Bk in zip(A, B)]))


@mistake("translation_residual", "none", "I forgot the - t_X term of R_A t_X + t_A - R_X "
         "t_B - t_X", names=r"t_X")
def translation_residual_no_tx(A, B, X):
    R_X, t_X = X[:3, :3], X[:3, 3]
    return float(np.mean([np.sum((Ak[:3, :3] @ t_X + Ak[:3, 3] - R_X @ Bk[:3, 3]) ** 2)
                          for Ak, Bk in zip(A, B)]))


@mistake("translation_residual", "none", "I took np.mean over every x, y, z component of "
         "every motion, which also divides by 3", names=r"component|divided by 3|over x, y(,| and) z")
def translation_residual_mean_of_components(A, B, X):
    R_X, t_X = X[:3, :3], X[:3, 3]
    r = np.array([Ak[:3, :3] @ t_X + Ak[:3, 3] - R_X @ Bk[:3, 3] - t_X for Ak, Bk in zip(A, B)])
    return float(np.mean(r ** 2))


@mistake("translation_residual", "sign", "I subtracted t_A instead of adding it")
def translation_residual_ta_sign(A, B, X):
    R_X, t_X = X[:3, :3], X[:3, 3]
    return float(np.mean([np.sum((Ak[:3, :3] @ t_X - Ak[:3, 3] - R_X @ Bk[:3, 3] - t_X) ** 2)
                          for Ak, Bk in zip(A, B)]))


@mistake("translation_residual", "inverse/transpose", "I wrote t_B @ R_X for R_X t_B, which "
         "is R_X^T t_B")
def translation_residual_row_vector(A, B, X):
    R_X, t_X = X[:3, :3], X[:3, 3]
    return float(np.mean([np.sum((Ak[:3, :3] @ t_X + Ak[:3, 3] - Bk[:3, 3] @ R_X - t_X) ** 2)
                          for Ak, Bk in zip(A, B)]))


@mistake("translation_residual", "root or not", "I averaged the lengths ||r_k||, not their "
         "squares ||r_k||^2")
def translation_residual_norm_not_squared(A, B, X):
    R_X, t_X = X[:3, :3], X[:3, 3]
    return float(np.mean([np.linalg.norm(Ak[:3, :3] @ t_X + Ak[:3, 3] - R_X @ Bk[:3, 3] - t_X)
                          for Ak, Bk in zip(A, B)]))
