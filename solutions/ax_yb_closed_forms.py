"""Checks and closed-form solutions of ``A_i @ X == Y @ B_i``, the layer under the solvers.

``solutions.robot_world`` (the solver menu ``solve_ax_yb``) and ``solutions.mle`` (the
maximum-likelihood refinement, whose Li start and input checks these are) both build on this
module, and it imports neither, so the two never import each other. The form and the meaning
of A, B, X and Y per mount are described in ``solutions.robot_world``; every name here is
re-exported there.
"""

from __future__ import annotations

import numpy as np

from robots import geometry as geo

__all__ = [
    "LOSSES",
    "MIN_MOTION_DEG",
    "check_rotation_variety",
    "li_closed_form",
    "loss_weights",
    "shah_closed_form",
    "validate_ax_yb",
]

MIN_MOTION_DEG = 1.0
"""Relative rotations smaller than this (degrees) carry too little information to use."""
_MIN_AXIS_SPREAD = 0.02
"""Smallest allowed second/first singular-value ratio of the stacked rotation axes
(about 1 degree of spread): below it every motion turns about (nearly) the same axis."""


# --------------------------------------------------------------------------- validation


def validate_ax_yb(A, B, name_a: str = "A", name_b: str = "B") -> tuple[np.ndarray, np.ndarray]:
    """Check the inputs of an ``A_i X = Y B_i`` problem and return them as (N, 4, 4) arrays.

    Raises ``ValueError`` naming the problem and the fix for: fewer than 3 poses, lists of
    different lengths, a malformed pose (shape, NaN, not a rotation; the index is named), and
    robot poses whose relative rotations are all tiny (< ``MIN_MOTION_DEG``) or all about one
    axis, from which X and Y cannot be separated.
    """
    A = geo.as_poses(A, name_a)
    B = geo.as_poses(B, name_b)
    if len(A) != len(B):
        raise ValueError(
            f"{name_a} has {len(A)} poses but {name_b} has {len(B)}; pass one {name_b} per "
            f"{name_a} (drop the robot poses whose image had no board)"
        )
    if len(A) < 3:
        raise ValueError(
            f"need at least 3 poses, got {len(A)}; capture more views (10-20 with varied "
            "orientations is typical)"
        )
    check_rotation_variety(A[:, :3, :3], name_a)
    return A, B


def check_rotation_variety(rotations: np.ndarray, name: str = "A") -> None:
    """Raise ``ValueError`` unless the relative rotations between poses turn about >= 2 axes.

    Every pair (i, j) is used, so the check does not depend on the capture order.
    """
    n = len(rotations)
    i, j = np.triu_indices(n, k=1)
    rel = np.swapaxes(rotations[i], 1, 2) @ rotations[j]  # R_i^T R_j
    # Axis times sin(angle) from the antisymmetric part, angle by atan2 with the trace: fast
    # for the n(n-1)/2 pairs, and accurate for small angles where the threshold lies.
    rotvecs = 0.5 * np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                              rel[:, 1, 0] - rel[:, 0, 1]], axis=1)
    sin = np.linalg.norm(rotvecs, axis=1)
    angles = np.arctan2(sin, 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1.0))
    # Near 180 deg the axis is lost in sin ~ 0; such pairs are left out of the axis test.
    big = (angles > np.radians(MIN_MOTION_DEG)) & (sin > 1e-3)
    if not big.any():
        raise ValueError(
            f"the {name} rotations differ by at most {np.degrees(angles.max()):.2f} deg; "
            f"motions below {MIN_MOTION_DEG:g} deg cannot be told from noise: tilt the tool "
            "by 15-45 deg between views"
        )
    if not big.any():
        raise ValueError(
            f"the {name} rotations differ only by about 180 deg turns about single axes; "
            "capture views with moderate (15-45 deg) rotations about varied axes")
    axes = rotvecs[big] / sin[big, None]
    s = np.linalg.svd(axes, compute_uv=False)
    if len(s) < 2 or s[1] < _MIN_AXIS_SPREAD * s[0]:
        raise ValueError(
            f"all relative rotations of {name} are about one axis (axis spread "
            f"{(s[1] / s[0]) if len(s) > 1 else 0.0:.1e}); the rotation about that axis and "
            "the translation along it are then unobservable: rotate about at least two "
            "different axes between views"
        )


# --------------------------------------------------------------------------- closed forms


def _unvec(v: np.ndarray) -> np.ndarray:
    """Inverse of the column-major vec of the identity vec(A M B) = (B^T ⊗ A) vec(M)."""
    return v.reshape(3, 3, order="F")


def _translations_given_rotations(A, B, R_X, R_Y) -> tuple[np.ndarray, np.ndarray]:
    """Least squares for t_X, t_Y in ``R_A t_X - t_Y = R_Y t_B - t_A`` (stacked over poses)."""
    n = len(A)
    M = np.zeros((3 * n, 6))
    M[:, :3] = A[:, :3, :3].reshape(3 * n, 3)
    M[:, 3:] = np.tile(-np.eye(3), (n, 1))
    rhs = (B[:, :3, 3] @ R_Y.T - A[:, :3, 3]).reshape(3 * n)
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    return sol[:3], sol[3:]


def shah_closed_form(A, B) -> tuple[np.ndarray, np.ndarray]:
    """Shah's (X, Y) for (N, 4, 4) arrays already checked by ``validate_ax_yb``."""
    # (R_B ⊗ R_A) vec(R_X) - vec(R_Y) = 0, from vec(R_A R_X R_B^T) = vec(R_Y).
    n = len(A)
    K = np.zeros((9 * n, 18))
    K[:, :9] = np.concatenate([np.kron(Bi[:3, :3], Ai[:3, :3]) for Ai, Bi in zip(A, B)])
    K[:, 9:] = np.tile(-np.eye(9), (n, 1))
    _, _, Vt = np.linalg.svd(K)
    v = Vt[-1]
    Mx, My = _unvec(v[:9]), _unvec(v[9:])
    # The null vector has arbitrary scale and sign; det(R) = +1 fixes both (Shah, eq. 10).
    R_X = geo.project_to_so3(Mx / np.cbrt(np.linalg.det(Mx)))
    R_Y = geo.project_to_so3(My / np.cbrt(np.linalg.det(My)))
    t_X, t_Y = _translations_given_rotations(A, B, R_X, R_Y)
    return geo.make_pose(R_X, t_X), geo.make_pose(R_Y, t_Y)


def li_closed_form(A, B) -> tuple[np.ndarray, np.ndarray]:
    """Li's (X, Y) for (N, 4, 4) arrays already checked by ``validate_ax_yb``."""
    # Unknowns [vec(R_X), vec(R_Y), t_X, t_Y] (24). Per pose: 9 rotation rows
    # (I ⊗ R_A) vec(R_X) - (R_B^T ⊗ I) vec(R_Y) = 0 and 3 translation rows
    # R_A t_X - (t_B^T ⊗ I) vec(R_Y) - t_Y = -t_A. The t_A on the right fixes the scale.
    n = len(A)
    R_A, t_A, R_B, t_B = A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3]
    I3 = np.eye(3)
    M = np.zeros((n, 12, 24))
    # (I ⊗ R_A) is block-diagonal with R_A in each 3x3 block; block (k, l) of (R_B^T ⊗ I) is
    # R_B[l, k] * I; (t_B^T ⊗ I) is [t_B[0] I, t_B[1] I, t_B[2] I].
    for k in range(3):
        M[:, 3 * k:3 * k + 3, 3 * k:3 * k + 3] = R_A
        for m in range(3):
            M[:, 3 * k:3 * k + 3, 9 + 3 * m:12 + 3 * m] = -R_B[:, m, k, None, None] * I3
        M[:, 9:12, 9 + 3 * k:12 + 3 * k] = -t_B[:, k, None, None] * I3
    M[:, 9:12, 18:21] = R_A
    M[:, 9:12, 21:24] = -I3
    rhs = np.zeros((n, 12))
    rhs[:, 9:12] = -t_A
    M, rhs = M.reshape(12 * n, 24), rhs.reshape(12 * n)
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    R_X = geo.project_to_so3(_unvec(sol[:9]))
    R_Y = geo.project_to_so3(_unvec(sol[9:18]))
    # The linear t's were solved with the unprojected rotations; re-solve with the proper ones.
    t_X, t_Y = _translations_given_rotations(A, B, R_X, R_Y)
    return geo.make_pose(R_X, t_X), geo.make_pose(R_Y, t_Y)


# --------------------------------------------------------------------------- robust loss


LOSSES = (None, "linear", "huber", "soft_l1", "cauchy")


def loss_weights(z2: np.ndarray, loss: str | None) -> np.ndarray:
    """IRLS weights rho'(z^2) for a squared normalised residual z^2 (scipy's loss names)."""
    # (Called in IRLS loops on arrays the solvers built: only the caller's choice is checked.)
    if not any(loss is c or (isinstance(loss, str) and loss == c) for c in LOSSES):
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    if loss in (None, "linear"):
        return np.ones_like(z2)
    if loss == "huber":
        return np.where(z2 <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z2, 1.0)))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z2)
    if loss == "cauchy":
        return 1.0 / (1.0 + z2)
    raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
