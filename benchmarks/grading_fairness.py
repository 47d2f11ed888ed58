"""Fairness of the hidden grade: correct code never loses credit, classic mistakes always do.

Monte Carlo over hidden draws, exactly as the grader draws them: for each student id, the
problems of one graded function are ``checks.make_trials(spec, problem_rng(...))``.
On the same problems it scores, side by side,

* the reference solutions (the notebook's SOLUTION regions and the ``solutions/`` package),
* correct alternatives a student may well write (consecutive-pair Tsai, Park-Martin, Horn's
  quaternion fit, float32 arithmetic where the lab allows it, a quaternion Rodrigues, ...),
* each classic mistake of the function's spec (``FunctionSpec.code_mistakes`` in
  autograder/specs: inverse pose, transposed rotation, mm for m, degrees for radians, swapped
  A / B, reversed multiplication order, no reflection fix, no degenerate-input check, ...),
  the same ones that check() and the feedback name.

A draw "loses credit" when the function scores below its full points. Targets: a correct
variant loses credit on fewer than 1 in 10,000 draws; a mistake on at least 99 % of draws.
The interval is Clopper-Pearson at 95 %: with 0 failures in n draws the upper bound is
about 3.7 / n, so 10,000 draws can show a rate below 3.7e-4, not below 1e-4 (that needs
about 37,000 draws with none lost). The margin column says how close correct code came:
the largest error / full-credit tolerance over every problem (below 1: full credit).

The Monte Carlo itself is :mod:`autograder.fairness` (draws, scoring, margins, intervals);
calls are in-process (``fairness.in_process``, the grader's own scoring): the sandbox
changes where code runs, not what it scores. ``--sandboxed`` shows it: the notebook's
reference also runs as the grader runs a submission, in the sandboxed worker through
:class:`autograder.pipeline.notebook_runner.NotebookRunner` (the one call loop of the grader and of
``cobotlab labs verify``), as a variant of its own on the same draws.

    .venv/bin/python benchmarks/grading_fairness.py --quick              # ~2 min, 300 draws
    .venv/bin/python benchmarks/grading_fairness.py --quick --labs lab0_frames --sandboxed
    .venv/bin/python benchmarks/grading_fairness.py --labs lab0_frames,lab4_stereo
    .venv/bin/python benchmarks/grading_fairness.py --functions tsai_lenz --draws 3000

Each run updates its functions' rows in docs/benchmarks/grading_fairness.json and rewrites
docs/benchmarks/grading_fairness.md from all rows (so runs per lab add up to the full table).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per worker: the machine is shared

import argparse  # noqa: E402
import contextlib
import fcntl  # noqa: E402
import inspect
import json
import math
import multiprocessing as mp
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import course_kit as kit  # noqa: E402

from autograder import checks, fairness  # noqa: E402
from autograder.fairness import clopper_pearson  # noqa: E402
from autograder.pipeline.problems import problem_rng as grader_rng  # noqa: E402
from autograder.pipeline.worker import Limits  # noqa: E402
from autograder.specs.lab1_flange import _kabsch  # noqa: E402
from autograder.specs.lab5_depth import _kasa  # noqa: E402
from robots import geometry as geo  # noqa: E402
from solutions import handeye as he  # noqa: E402
from solutions import registration as reg  # noqa: E402
from solutions import servoing as sv  # noqa: E402

RESULTS_JSON = ROOT / "docs" / "benchmarks" / "grading_fairness.json"
RESULTS_MD = ROOT / "docs" / "benchmarks" / "grading_fairness.md"
SECRET = "fairness-benchmark-secret"
SANDBOXED = "notebook solution, in the grader's worker"
CORRECT_TARGET = 1e-4
MISTAKE_TARGET = 0.99


@dataclass
class Variant:
    name: str
    correct: bool
    func: object


# --------------------------------------------------------------------------- references


def notebook_solutions(assignment: str) -> dict:
    """The notebook's SOLUTION cells as functions, in one namespace (as in the notebook, so
    ibvs_velocity finds interaction_matrix and the chain finds frame_from_three_points)."""
    names = [s.name for s in checks.SPECS[assignment]]
    namespace = {"np": np, "geo": geo, "__name__": f"notebook_{assignment}"}
    for source in kit.solution_sources(assignment, names).values():
        exec(compile(source, f"<{assignment} solution>", "exec"), namespace)  # noqa: S102
    return namespace


def _pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


# --------------------------------------------------------------------------- lab 0


def _rotvec_quaternion(rvec, t):
    """Rodrigues through the unit quaternion (cos(theta/2), sin(theta/2) k): no 0/0 at all."""
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    half = np.sinc(theta / (2 * np.pi)) / 2  # sin(theta/2)/theta, finite at 0
    w, (x, y, z) = np.cos(theta / 2), rvec * half
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return _pose(R, t)


def _rotvec_series(rvec, t):
    """sin(theta)/theta and (1 - cos theta)/theta^2 with a Taylor series near 0 (no K)."""
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    W = geo.skew(rvec)
    if theta < 1e-4:
        a, b = 1 - theta ** 2 / 6, 0.5 - theta ** 2 / 24
    else:
        a, b = np.sin(theta) / theta, (1 - np.cos(theta)) / theta ** 2
    return _pose(np.eye(3) + a * W + b * W @ W, t)


def lab0(ns) -> dict:
    return {
        "invert_pose": [
            Variant("notebook solution", True, ns["invert_pose"]),
            Variant("np.linalg.inv", True, lambda T: np.linalg.inv(T)),
        ],
        "compose_chain": [
            Variant("notebook solution", True, ns["compose_chain"]),
            Variant("np.linalg.multi_dot", True,
                    lambda P: np.linalg.multi_dot([np.eye(4), *P]) if len(P) < 2
                    else np.linalg.multi_dot(P)),
        ],
        "pose_from_rotvec": [
            Variant("notebook solution", True, ns["pose_from_rotvec"]),
            Variant("quaternion formula", True, _rotvec_quaternion),
            Variant("Taylor series near 0", True, _rotvec_series),
            Variant("scipy Rotation.from_rotvec", True,
                    lambda r, t: _pose(Rotation.from_rotvec(r).as_matrix(), t)),
        ],
    }


# --------------------------------------------------------------------------- lab 1


def _horn(src, dst):
    """Horn's closed form: R from the top eigenvector of the 4x4 quaternion matrix."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or len(src) < 3:
        raise ValueError("need (N, 3) point sets with N >= 3")
    a, b = src - src.mean(0), dst - dst.mean(0)
    if np.linalg.matrix_rank(a, tol=1e-6 * np.abs(a).max()) < 2:
        raise ValueError("collinear points")
    S = a.T @ b
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = S
    N = np.array([[sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
                  [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
                  [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
                  [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]])
    w, x, y, z = np.linalg.eigh(N)[1][:, -1]
    R = Rotation.from_quat([x, y, z, w]).as_matrix()
    return _pose(R, dst.mean(0) - R @ src.mean(0))


def _residuals_homogeneous(T, src, dst):
    h = np.c_[src, np.ones(len(src))] @ np.asarray(T).T
    return np.linalg.norm(h[:, :3] - dst, axis=1)


def _rmse_inverse_map(T, src, dst):
    """Residuals measured in the src frame by mapping dst back: inv(T) dst - src = -R^T r."""
    back = geo.transform_points(np.linalg.inv(T), dst) - src
    return np.sqrt(np.mean(back ** 2, axis=0))


def lab1(ns) -> dict:
    return {
        "fit_rigid": [
            Variant("notebook solution", True, ns["fit_rigid"]),
            Variant("solutions.registration.fit_rigid", True, reg.fit_rigid),
            Variant("Horn quaternion fit", True, _horn),
        ],
        "per_point_residuals": [
            Variant("notebook solution", True, ns["per_point_residuals"]),
            Variant("solutions.registration.residuals", True,
                    lambda T, s, d: np.linalg.norm(reg.residuals(T, s, d), axis=1)),
            Variant("homogeneous coordinates", True, _residuals_homogeneous),
        ],
        "per_axis_rmse": _rmse_variants(ns["per_axis_rmse"], "src"),
    }


def _rmse_variants(rmse, frame) -> list[Variant]:
    return [
        Variant("notebook solution", True, rmse),
        Variant("solutions.registration.per_axis_rmse", True,
                lambda T, s, d: reg.per_axis_rmse(T, s, d, expressed_in="src")),
        Variant(f"inverse map into the {frame} frame", True, _rmse_inverse_map),
    ]


# --------------------------------------------------------------------------- lab 2


def _consecutive_of_all(A, B):
    """From the motions of all pairs (i < j, lexicographic), those of consecutive poses."""
    M = len(A)
    n = int(round((1 + math.sqrt(1 + 8 * M)) / 2))
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    keep = [k for k, (i, j) in enumerate(pairs) if j == i + 1]
    return np.asarray(A)[keep], np.asarray(B)[keep]


def _park_martin(A, B):
    """Park-Martin: R_X = (M^T M)^(-1/2) M^T with M = sum beta alpha^T (log map axes)."""
    alpha = np.array([geo.rotvec_from_pose(a)[0] for a in A])
    beta_ = np.array([geo.rotvec_from_pose(b)[0] for b in B])
    M = beta_.T @ alpha
    w, V = np.linalg.eigh(M.T @ M)
    R = V @ np.diag(w ** -0.5) @ V.T @ M.T
    lhs = np.vstack([a[:3, :3] - np.eye(3) for a in A])
    rhs = np.concatenate([R @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B)])
    return _pose(R, np.linalg.lstsq(lhs, rhs, rcond=None)[0])


def _motions_np_inv(F, C, strategy="all"):
    n = len(F)
    pairs = ([(i, j) for i in range(n) for j in range(i + 1, n)] if strategy == "all"
             else [(i, i + 1) for i in range(n - 1)])
    return (np.array([np.linalg.inv(F[i]) @ F[j] for i, j in pairs]),
            np.array([C[i] @ np.linalg.inv(C[j]) for i, j in pairs]))


def _solver_variants(ref, alt_name, alt, extra=()) -> list[Variant]:
    return [
        Variant("notebook solution", True, ref),
        Variant(alt_name, True, alt),
        Variant("consecutive pairs only", True, lambda A, B: ref(*_consecutive_of_all(A, B))),
        *extra,
    ]


def lab2(ns) -> dict:
    return {
        "motions": [
            Variant("notebook solution", True, ns["motions"]),
            Variant("np.linalg.inv", True, _motions_np_inv),
        ],
        "tsai_lenz": _solver_variants(ns["tsai_lenz"], "solutions.handeye.solve_tsai",
                                      he.solve_tsai),
        "axes_ls": _solver_variants(ns["axes_ls"], "Park-Martin", _park_martin,
                                    [Variant("solutions.handeye.solve_axes_ls", True,
                                             he.solve_axes_ls)]),
        "rotation_residual": [
            Variant("notebook solution", True, ns["rotation_residual"]),
            Variant("solutions.handeye.rotation_residual", True, he.rotation_residual),
        ],
        "translation_residual": [
            Variant("notebook solution", True, ns["translation_residual"]),
            Variant("solutions.handeye.translation_residual", True, he.translation_residual),
        ],
    }


# --------------------------------------------------------------------------- lab 3


def _ibvs_lstsq(s, s_star, Z, gain):
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = interaction_matrix(s[:, 0], s[:, 1], Z)
    return -gain * np.linalg.lstsq(L, (s - s_star).reshape(-1), rcond=None)[0]


def _piece_nanmedian(depth, uv, K):
    """np.nanmedian of the 5x5 window (the reference drops NaN and non-positive depths)."""
    u, v = np.rint(np.asarray(uv, float)).astype(int)
    Z = float(np.nanmedian(depth[v - 2:v + 3, u - 2:u + 3]))
    return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])


def lab3(ns) -> dict:
    global interaction_matrix
    interaction_matrix = ns["interaction_matrix"]
    return {
        "interaction_matrix": [
            Variant("notebook solution", True, ns["interaction_matrix"]),
            Variant("solutions.servoing.interaction_matrix", True,
                    lambda x, y, Z: sv.interaction_matrix(np.column_stack([x, y]), Z)),
        ],
        "ibvs_velocity": [
            Variant("notebook solution", True, ns["ibvs_velocity"]),
            Variant("lstsq instead of pinv", True, _ibvs_lstsq),
        ],
        "piece_position": [
            Variant("notebook solution", True, ns["piece_position"]),
            Variant("np.nanmedian of the 5x5 window", True, _piece_nanmedian),
        ],
    }


interaction_matrix = None  # set by lab3(): the notebook's, so the grader's stand-in finds it


# --------------------------------------------------------------------------- lab 4


def _frame_gram_schmidt(o, px, pxy):
    o, px, pxy = (np.asarray(p, float) for p in (o, px, pxy))
    x = (px - o) / np.linalg.norm(px - o)
    y = (pxy - o) - ((pxy - o) @ x) * x
    y /= np.linalg.norm(y)
    return _pose(np.column_stack([x, y, np.cross(x, y)]), o)


def _reproject_float32(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, np.float32) @ np.array([u, v, d, 1.0], np.float32)
    return np.array([X, Y, Z], np.float32) / W


def _reproject_cv2(u, v, d, Q):
    import cv2

    return cv2.perspectiveTransform(np.array([[[u, v, d]]], np.float32),
                                    np.asarray(Q, float)).reshape(3)


def _chain_fit_rigid(cam, base):
    return _kabsch(cam, base)


def lab4(ns) -> dict:
    return {
        "frame_from_three_points": [
            Variant("notebook solution", True, ns["frame_from_three_points"]),
            Variant("solutions.registration.frame_from_three_points", True,
                    reg.frame_from_three_points),
            Variant("Gram-Schmidt y", True, _frame_gram_schmidt),
        ],
        "reproject": [
            Variant("notebook solution", True, ns["reproject"]),
            Variant("float32 arithmetic", True, _reproject_float32),
            Variant("cv2.perspectiveTransform (float32)", True, _reproject_cv2),
        ],
        "hand_to_eye_from_three_points": [
            Variant("notebook solution", True, ns["hand_to_eye_from_three_points"]),
            Variant("fit_rigid on the three points", True, _chain_fit_rigid),
        ],
        "per_axis_rmse": _rmse_variants(ns["per_axis_rmse"], "camera"),
    }


# --------------------------------------------------------------------------- lab 5


def _backproject_float32(depth_raw, K, depth_scale):
    """All in float32, as the RealSense SDK hands out depth (raw * scale as float32)."""
    z = np.asarray(depth_raw).astype(np.float32) * np.float32(depth_scale)
    z[np.asarray(depth_raw) == 0] = np.nan
    v, u = np.indices(z.shape).astype(np.float32)
    K = np.asarray(K, np.float32)
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)


def _towards_camera(centre, normal):
    return centre, (-normal if normal @ centre > 0 else normal)


def _plane_ransac(points, inlier_m, iterations=500, seed=0, msac=False, refit="svd"):
    """RANSAC (or MSAC: truncated squared distances instead of the inlier count) over
    random triples, then a refit on the best hypothesis's inliers (SVD or the covariance's
    smallest eigenvector)."""
    pts = np.asarray(points, float).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    best, best_cost = None, np.inf
    for _ in range(iterations):
        a, b, c = pts[rng.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        d = np.abs((pts - a) @ (n / np.linalg.norm(n)))
        cost = np.sum(np.minimum(d, inlier_m) ** 2) if msac else -np.sum(d < inlier_m)
        if cost < best_cost:
            best, best_cost = d < inlier_m, cost
    q = pts[best]
    centre = q.mean(axis=0)
    if refit == "svd":
        normal = np.linalg.svd(q - centre, full_matrices=False)[2][2]
    else:
        normal = np.linalg.eigh(np.cov(q.T))[1][:, 0]
    return _towards_camera(centre, normal)


def _rim_plane(rim):
    P = np.asarray(rim, float)
    c0, n = _towards_camera(P.mean(axis=0), np.linalg.svd(P - P.mean(axis=0),
                                                          full_matrices=False)[2][2])
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return c0, n, e1, e2, np.column_stack([(P - c0) @ e1, (P - c0) @ e2])


def _circle_lm(rim, radius_m):
    """Levenberg-Marquardt (scipy) on the geometric residuals, the radius fixed."""
    from scipy.optimize import least_squares

    c0, n, e1, e2, xy = _rim_plane(rim)
    start = np.asarray(_kasa(np.asarray(rim, float))[0] - c0) @ np.column_stack([e1, e2])
    cx, cy = least_squares(lambda c: np.linalg.norm(xy - c, axis=1) - radius_m, start,
                           method="lm").x
    return c0 + cx * e1 + cy * e2, n


def _rectangle_homography(corners_px, width_m, height_m, K):
    """The plane-to-image homography (DLT on the 4 corners), decomposed: [r1 r2 t] =
    K^-1 H / scale, scale the mean of |K^-1 h1| and |K^-1 h2|, R made a rotation (SVD)."""
    w, h = width_m / 2, height_m / 2
    P = np.array([[-w, -h], [w, -h], [w, h], [-w, h]])
    rows = []
    for (X, Y), (u, v) in zip(P, np.asarray(corners_px, float)):
        rows.append([X, Y, 1, 0, 0, 0, -u * X, -u * Y, -u])
        rows.append([0, 0, 0, X, Y, 1, -v * X, -v * Y, -v])
    H = np.linalg.svd(np.array(rows))[2][-1].reshape(3, 3)
    M = np.linalg.inv(K) @ H
    M /= (np.linalg.norm(M[:, 0]) + np.linalg.norm(M[:, 1])) / 2
    if M[2, 2] < 0:  # the mark in front of the camera
        M = -M
    U, _, Vt = np.linalg.svd(np.column_stack([M[:, 0], M[:, 1], np.cross(M[:, 0], M[:, 1])]))
    return _pose(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, M[:, 2])


def lab5(ns) -> dict:
    plane = ns["fit_plane_ransac"]
    return {
        "backproject": [
            Variant("notebook solution", True, ns["backproject"]),
            Variant("float32 arithmetic (as the RealSense SDK)", True, _backproject_float32),
        ],
        "fit_plane_ransac": [
            Variant("notebook solution", True, plane),
            Variant("covariance eigenvector refit", True,
                    lambda p, t, i=500, s=0: _plane_ransac(p, t, i, s, refit="eigh")),
            Variant("MSAC scoring", True, lambda p, t, i=500, s=0: _plane_ransac(p, t, i, s,
                                                                                  msac=True)),
            Variant("twice the iterations", True, lambda p, t, i=500, s=0: plane(p, t, 2 * i, s)),
        ],
        "fit_flange_circle": [
            Variant("notebook solution", True, ns["fit_flange_circle"]),
            Variant("Levenberg-Marquardt (scipy), radius fixed", True, _circle_lm),
        ],
        "base_T_cam_from_flanges": [
            Variant("notebook solution", True, ns["base_T_cam_from_flanges"]),
            Variant("Horn quaternion fit", True,
                    lambda a, F: _horn(a, np.asarray(F, float)[:, :3, 3])),
        ],
        "rectangle_pose": [
            Variant("notebook solution", True, ns["rectangle_pose"]),
            Variant("homography decomposition, orthogonalised", True, _rectangle_homography),
        ],
    }


LABS = {"lab0_frames": lab0, "lab1_flange": lab1, "lab2_handeye": lab2,
        "lab3_servoing": lab3, "lab4_stereo": lab4, "lab5_depth": lab5}


# --------------------------------------------------------------------------- the mistakes

# The table's short name of each spec mistake (by its function's qualified name): a spec's
# label is the sentence a student reads, too long for a table row. A mistake missing here is
# shown by its label, cut short (tests/test_grading_fairness.py keeps the list complete).
SHORT_NAMES = {
    # lab 0
    "_invert_keeps_r": "R not transposed",
    "_invert_negates_t": "t negated only (-t, not -R^T t)",
    "_invert_returns_input": "returns the pose itself",
    "_compose_reversed": "reversed multiplication order",
    "_compose_inverses": "inverse poses composed",
    "_rotvec_as_degrees": "degrees taken for radians",
    "_rotvec_transposed": "transposed rotation",
    "_rotvec_no_zero_check": "no zero-rotation check (0/0)",
    "_rotvec_translation_mm": "translation in mm",
    # lab 1 (and lab 4's per_axis_rmse)
    "_fit_no_reflection_fix": "no reflection fix",
    "_fit_no_degenerate_check": "no degenerate-input check",
    "_fit_inverse": "inverse pose (src_T_dst)",
    "_fit_swapped": "swapped src / dst",
    "_fit_transposed": "transposed rotation",
    "_fit_translation_mm": "translation in mm",
    "_fit_uncentred": "cross-covariance not centred",
    "_residuals_squared": "squared distances",
    "_residuals_inverse_pose": "inverse pose used",
    "_residuals_transposed": "transposed rotation",
    "_residuals_mm": "in mm",
    "_rmse_dst_axes": "along the dst (base) axes",
    "_rmse_r_not_transposed": "R instead of R^T",
    "_rmse_no_sqrt": "mean square (no sqrt)",
    "_rmse_one_for_all_axes": "one RMS for all axes",
    # lab 2
    "_motions_b_inverse_first": "B = inv(C_i) C_j (inverse on the wrong side)",
    "_motions_a_reversed": "A = inv(F_j) F_i (reversed)",
    "_motions_strategy_ignored": "strategy ignored (always all pairs)",
    "_motions_swapped": "swapped A / B",
    "_solver_mistakes.<locals>.inverse": "inverse X (cam_T_flange)",
    "_solver_mistakes.<locals>.swapped": "swapped A / B",
    "_solver_mistakes.<locals>.transposed": "transposed R_X",
    "_solver_mistakes.<locals>.translation_mm": "t_X in mm",
    "_rotation_residual_sum": "sum, not mean",
    "_rotation_residual_unsquared": "Frobenius norm, not squared",
    "_rotation_residual_transposed": "R_X transposed",
    "_translation_residual_sum": "sum, not mean",
    "_translation_residual_mm2": "in mm^2",
    "_translation_residual_inverse": "inverse X",
    # lab 3
    "_interaction_stacked": "rows stacked x..., y...",
    "_interaction_rotation_sign": "rotation columns' sign flipped",
    "_interaction_no_depth": "depth ignored (Z = 1)",
    "_interaction_z_for_inverse": "Z where 1/Z belongs",
    "_ibvs_gain_flipped": "gain sign flipped",
    "_ibvs_transpose": "L^T instead of pinv(L)",
    "_ibvs_no_gain": "gain ignored",
    "_ibvs_error_stacked": "error stacked x..., y...",
    "_ibvs_degrees": "angular velocity in deg/s",
    "_ibvs_w_first": "(w, v) returned for (v, w)",
    "_ibvs_desired_l": "L at s* (not the current s)",
    "_piece_pixel_only": "the pixel's own depth (no hole handling)",
    "_piece_uv_swapped": "u and v swapped",
    "_piece_mm": "depth in mm",
    "_piece_ray_length": "depth taken as the ray length",
    "_piece_rows_columns": "depth[u, v] for depth[v, u]",
    "_piece_window_mean": "mean of the window, not the median",
    # lab 4
    "_frame_left_handed": "left-handed (z = (p_xy - o) x x)",
    "_frame_y_copied": "p_xy - o copied as the y axis",
    "_frame_inverse": "inverse pose (frame_T_parent)",
    "_frame_transposed": "transposed rotation",
    "_reproject_by_z": "divided by Z, not W",
    "_reproject_no_shift": "(cx - cx')/Tx term dropped",
    "_reproject_disparity_flipped": "disparity sign flipped",
    "_reproject_mm": "in mm",
    "_hand_to_eye_inverse": "inverse (cam_T_base)",
    "_hand_to_eye_reversed": "reversed order (world_T_cam @ base_T_world)",
    "_hand_to_eye_not_inverted": "camera frame used as the world (no inverse)",
    # lab 5
    "_backproject_units": "depth in millimetres (depth_scale ignored)",
    "_backproject_fixed_scale": "depth_scale hard-coded to 0.001",
    "_backproject_uv_swapped": "u and v swapped",
    "_backproject_k_inverted": "intrinsics inverted ((u - cx) fx)",
    "_backproject_holes_at_zero": "holes left at z = 0",
    "_plane_all_points": "no outlier rejection (SVD on all points)",
    "_plane_normal_away": "normal away from the camera",
    "_circle_unrefined": "algebraic (Kasa) fit, unrefined",
    "_circle_normal_away": "normal away from the camera",
    "_registration_inverse": "cam_T_base returned (inverse)",
    "_registration_rt": "cross-covariance the other way round (R^T)",
    "_rectangle_swapped": "width and height swapped",
    "_rectangle_k_ignored": "K not inverted (pixels used as rays)",
    "_rectangle_not_orthogonal": "edge directions not made orthogonal",
    "_rectangle_unsigned": "vanishing directions unsigned",
    # lab 5, issue 38: the mistakes the text warns about
    "_backproject_ray_length": "depth taken as the ray's length",
    "_backproject_index_uv": "depth[u, v] for depth[v, u]",
    "_plane_uncentred": "refit SVD on uncentred points",
    "_circle_centroid": "centroid of the rim as the centre",
    "_circle_diameter": "diameter used as the radius",
    "_circle_uncentred": "rim plane by SVD of uncentred points",
    "_registration_uncentred": "uncentred cross-covariance",
}


def short_name(mistake) -> str:
    """The table's name of a spec's code mistake (its label cut short if it has none)."""
    name = SHORT_NAMES.get(getattr(mistake.func, "__qualname__", ""))
    if name is not None:
        return name
    return mistake.label if len(mistake.label) <= 44 else mistake.label[:41] + "..."


def variants(assignment: str) -> dict[str, list[Variant]]:
    """{function: its correct variants (the notebook's solution first), then the spec's code
    mistakes} for every graded function of ``assignment``."""
    solutions = notebook_solutions(assignment)
    if assignment in LABS:
        table = LABS[assignment](solutions)
    else:   # a course's own lab: no alternatives listed here, the notebook's solutions only
        table = {spec.name: [Variant("notebook solution", True, solutions[spec.name])]
                 for spec in checks.SPECS[assignment]}
    for spec in checks.SPECS[assignment]:
        table[spec.name] = table[spec.name] + [Variant(short_name(m), False, m.func)
                                               for m in spec.code_mistakes]
    return table


# --------------------------------------------------------------------------- the Monte Carlo


def problem_rng(assignment: str, student: str, function: str) -> np.random.Generator:
    """The grader's own generator for one student's problems of one function."""
    params = inspect.signature(grader_rng).parameters
    if "nonce" in params:  # a per-run nonce (older API): one fixed nonce for the whole run
        return grader_rng(SECRET, "fairness", assignment, student, function)
    return grader_rng(SECRET, assignment, student, function)


def run_function(job) -> dict:
    """All variants of one function over draws [start, stop) (:func:`fairness.score_draws`).

    ``job`` is (assignment, function, start, stop[, mistakes_stop[, sandboxed]]): mistakes
    are scored on draws below ``mistakes_stop`` only (1,000 draws without a miss already
    bound their rate above 99.6 %; it is correct code that needs the long run); with
    ``sandboxed``, the notebook's reference runs in the grader's worker too."""
    assignment, name, start, stop = job[:4]
    mistakes_stop = job[4] if len(job) > 4 else None
    sandboxed = bool(job[5]) if len(job) > 5 else False
    spec = next(s for s in checks.SPECS[assignment] if s.name == name)
    table = variants(assignment)[name]
    if len({v.name for v in table}) != len(table):
        raise ValueError(f"{name}: two variants share a name: {[v.name for v in table]}")
    started = time.perf_counter()
    callers = {v.name: fairness.in_process(v.func) for v in table}
    correct = {v.name for v in table if v.correct}
    with contextlib.ExitStack() as stack:
        if sandboxed:
            from autograder.registry import find_lab
            from cobotlab.verify import SandboxedReference

            reference = SandboxedReference(find_lab(assignment).notebook
                                           or kit.source_notebook(assignment), Limits())
            stack.callback(reference.close)
            callers[SANDBOXED] = reference
            correct.add(SANDBOXED)
        stats = fairness.score_draws(
            spec, assignment, range(start, stop), callers,
            lambda student: problem_rng(assignment, student, name),
            correct=correct, mistakes_stop=mistakes_stop)
    return {"assignment": assignment, "function": name, "start": start,
            "draws": stop - start, "stats": stats,
            "seconds": time.perf_counter() - started, "n_trials": spec.n_trials,
            "max_points": spec.points}


def _merge(parts: list[dict]) -> dict:
    parts = sorted(parts, key=lambda p: p["start"])
    out = dict(parts[0])
    out["draws"] = sum(p["draws"] for p in parts)
    out["stats"] = {name: s for name, s in parts[0]["stats"].items()}
    for p in parts[1:]:
        out["stats"] = {name: s.merged(p["stats"][name]) for name, s in out["stats"].items()}
    out["seconds"] = sum(p["seconds"] for p in parts)
    return out


def verdict(correct: bool, k: int, n: int) -> str:
    low, high = clopper_pearson(k, n)
    if correct:
        if high < CORRECT_TARGET:
            return "meets < 1e-4"
        return ("no loss seen (n too small to show < 1e-4)" if k == 0
                else "FAILS: correct code loses credit")
    if low >= MISTAKE_TARGET:
        return "meets >= 99 %"
    return "consistent with >= 99 %" if high >= MISTAKE_TARGET else "FAILS: < 99 % caught"


# --------------------------------------------------------------------------- report


def rows_of(result: dict) -> list[dict]:
    rows = []
    for name, s in result["stats"].items():
        n, k = s.seen, s.lost
        low, high = clopper_pearson(k, n)
        rows.append({"function": result["function"], "assignment": result["assignment"],
                     "variant": name, "correct": s.correct, "draws": n,
                     "lost": k, "rate": k / n, "low": low, "high": high,
                     "mean_points": s.points / n, "max_points": result["max_points"],
                     "margin": s.margin,
                     "example": s.first_loss.describe() if s.first_loss else None,
                     "verdict": verdict(s.correct, k, n)})
    return rows


def _fmt_rate(r: dict) -> str:
    return f"{r['lost']}/{r['draws']} [{r['low']:.2%}, {r['high']:.2%}]" if not r["correct"] else \
        f"{r['lost']}/{r['draws']} [0, {r['high']:.1e}]" if r["lost"] == 0 else \
        f"{r['rate']:.2e} [{r['low']:.1e}, {r['high']:.1e}]"


def _fmt_margin(r: dict) -> str:
    m = r["margin"]
    return "" if math.isnan(m) else "no answer" if not math.isfinite(m) else f"{m:.3g}"


def print_table(rows: list[dict]) -> None:
    print(f"{'function':<30} {'variant':<44} {'lost credit (95% CI)':<30} "
          f"{'mean pts':>9} {'margin':>9}  verdict")
    for r in rows:
        print(f"{r['function']:<30} {('+ ' if r['correct'] else '- ') + r['variant']:<44} "
              f"{_fmt_rate(r):<30} {r['mean_points']:>5.2f}/{r['max_points']:<3g} "
              f"{_fmt_margin(r):>9}  {r['verdict']}")


def write_markdown(store: dict) -> None:
    lines = [
        "# Grading fairness: correct code never loses credit, classic mistakes always do",
        "",
        "Written by `benchmarks/grading_fairness.py` (do not edit by hand). Each function's "
        "hidden problems are drawn as the grader draws them (`checks.make_trials` with "
        "`problem_rng` over distinct student ids) and every variant is scored on the "
        "same problems by the grader's own scoring, in process.",
        "",
        "* **lost credit**: draws (one student's hidden problem set) scoring below full "
        "points, with a 95 % Clopper-Pearson interval. `+` correct code (target: fewer than "
        "1 in 10,000), `-` a classic mistake (target: at least 99 %).",
        "* With 0 losses in n draws the upper bound is about 3.7 / n: 10,000 draws show a rate "
        "below 3.7e-4, not below 1e-4 (that needs ~37,000 clean draws). The **margin** says "
        "how close correct code came: its largest error / full-credit tolerance over all "
        "problems (above 1 loses credit).",
        "* A section run with fewer than 10,000 draws (its header says how many) is a bounded "
        "run, not the target's evidence: rerun it with the default `--draws 10000`.",
        "",
    ]
    by_lab: dict[str, list[dict]] = {}
    for entry in store.values():
        by_lab.setdefault(entry["assignment"], []).append(entry)
    for lab in sorted(by_lab):
        lines += [f"## {lab}", ""]
        for entry in sorted(by_lab[lab], key=lambda e: e["order"]):
            r0 = entry["rows"][0]
            lines += [f"### {r0['function']} ({entry['n_trials']} hidden problems per draw)", "",
                      f"{r0['draws']} draws in {entry['seconds']:.0f} s; run: "
                      f"`{entry['command']}` ({entry['when']})", "",
                      "| variant | lost credit [95 % CI] | mean points | margin | verdict |",
                      "|---|---|---|---|---|"]
            for r in entry["rows"]:
                sign = "+" if r["correct"] else "-"
                lines.append(f"| {sign} {r['variant']} | {_fmt_rate(r)} | "
                             f"{r['mean_points']:.2f} / {r['max_points']:g} | "
                             f"{_fmt_margin(r)} | {r['verdict']} |")
            lines.append("")
    RESULTS_MD.write_text("\n".join(lines))


CHUNK_DRAWS = 250  # draws per job


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=10_000, help="hidden draws per function")
    parser.add_argument("--mistake-draws", type=int, default=1000,
                        help="draws on which the mistakes are scored (the first ones)")
    parser.add_argument("--quick", action="store_true", help="300 draws (a smoke run)")
    parser.add_argument("--labs", default="", help="comma-separated assignments (default: the "
                        "built-in labs; a course's own lab with $COBOTLAB_COURSE or run in "
                        "its course folder)")
    parser.add_argument("--functions", default="", help="comma-separated function names")
    parser.add_argument("--workers", type=int, default=1, help="processes (2 on a quiet machine)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--sandboxed", action="store_true",
                        help="also run the notebook's reference in the grader's sandboxed "
                             "worker (autograder.pipeline.notebook_runner.NotebookRunner), a variant of its own")
    args = parser.parse_args(argv)
    draws = 300 if args.quick else args.draws
    labs = [x for x in args.labs.split(",") if x] or list(LABS)
    wanted = {x for x in args.functions.split(",") if x}
    jobs = []
    for lab in labs:
        for spec in checks.SPECS[lab]:
            if wanted and spec.name not in wanted:
                continue
            # Small chunks keep both workers busy to the end (the mistakes make the first
            # draws dearer) and let the progress bar move on runs of an hour or more.
            chunk = min(CHUNK_DRAWS, math.ceil(draws / max(1, args.workers)))
            jobs += [(lab, spec.name, s, min(s + chunk, draws), args.mistake_draws,
                      args.sandboxed) for s in range(0, draws, chunk)]
    started = time.perf_counter()
    parts = []
    pool = mp.get_context("fork").Pool(args.workers) if args.workers > 1 else None
    with pool or contextlib.nullcontext(), tqdm(total=sum(j[3] - j[2] for j in jobs),
                                                unit="draw", desc="fairness", file=sys.stderr,
                                                smoothing=0.05) as bar:
        for p in (pool.imap_unordered(run_function, jobs) if pool else map(run_function, jobs)):
            parts.append(p)
            bar.update(p["draws"])
    merged: dict[tuple, list] = {}
    for p in parts:
        merged.setdefault((p["assignment"], p["function"]), []).append(p)
    results = [_merge(v) for v in merged.values()]
    rows = [r for res in results for r in rows_of(res)]
    print_table(rows)
    wall = time.perf_counter() - started
    print(f"\n{draws} draws per function, {len(results)} functions, {wall:.0f} s wall "
          f"with {args.workers} worker(s)")
    own = sorted(set(labs) - set(LABS))
    if own and not args.no_write:
        print(f"not written to {RESULTS_MD.relative_to(ROOT)}: {', '.join(own)} is a course's "
              "own lab (its evidence is `cobotlab labs verify --draws 10000`, kept beside its "
              "spec)")
    elif not args.no_write:
        with open(Path(tempfile.gettempdir()) / "grading_fairness.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # runs per lab may finish at the same time
            _store(results, argv)
    failing = [r for r in rows if r["verdict"].startswith("FAILS")]
    return 1 if failing else 0


def _store(results: list[dict], argv) -> None:
    """Replace these functions' entries in the JSON store and rewrite the markdown."""
    store = json.loads(RESULTS_JSON.read_text()) if RESULTS_JSON.exists() else {}
    command = "python benchmarks/grading_fairness.py " + " ".join(
        a for a in (argv if argv is not None else sys.argv[1:]))
    order = {s.name: i for lab in LABS for i, s in enumerate(checks.SPECS[lab])}
    for res in results:
        store[f"{res['assignment']}/{res['function']}"] = {
            "assignment": res["assignment"], "n_trials": res["n_trials"],
            "seconds": res["seconds"], "command": command.strip(),
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "order": order[res["function"]], "rows": rows_of(res)}
    RESULTS_JSON.write_text(json.dumps(store, indent=1, default=float))
    write_markdown(store)
    print(f"wrote {RESULTS_MD.relative_to(ROOT)}")


if __name__ == "__main__":
    sys.exit(main())
