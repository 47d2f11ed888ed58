"""Fairness of the hidden grade: correct code never loses credit, classic mistakes always do.

Monte Carlo over hidden draws, exactly as the grader draws them: for each student id, the
problems of one graded function are ``checks.make_trials(spec, grading.problem_rng(...))``.
On the same problems it scores, side by side,

* the reference solutions (the notebook's SOLUTION regions and the ``solutions/`` package),
* correct alternatives a student may well write (consecutive-pair Tsai, Park-Martin, Horn's
  quaternion fit, float32 arithmetic where the lab allows it, a quaternion Rodrigues, ...),
* each classic mistake (inverse pose, transposed rotation, mm for m, degrees for radians,
  swapped A / B, reversed multiplication order, no reflection fix, no degenerate-input check).

A draw "loses credit" when the function scores below its full points. Targets: a correct
variant loses credit on fewer than 1 in 10,000 draws; a mistake on at least 99 % of draws.
The interval is Clopper-Pearson at 95 %: with 0 failures in n draws the upper bound is
about 3.7 / n, so 10,000 draws can show a rate below 3.7e-4, not below 1e-4 (that needs
about 37,000 draws with none lost). The margin column says how close correct code came:
the largest error / full-credit tolerance over every problem (below 1: full credit).

Scoring is in-process (``checks._call_in_process`` and ``checks.score_function``, the
grader's own scoring): the sandbox changes where code runs, not what it scores.

    .venv/bin/python benchmarks/grading_fairness.py --quick              # ~2 min, 300 draws
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
from scipy.stats import beta
from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import course_kit as kit  # noqa: E402

from autograder import checks, grading  # noqa: E402
from robots import geometry as geo  # noqa: E402
from solutions import handeye as he  # noqa: E402
from solutions import registration as reg  # noqa: E402
from solutions import servoing as sv  # noqa: E402

RESULTS_JSON = ROOT / "docs" / "benchmarks" / "grading_fairness.json"
RESULTS_MD = ROOT / "docs" / "benchmarks" / "grading_fairness.md"
SECRET = "fairness-benchmark-secret"
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


def _inv(T) -> np.ndarray:
    return _pose(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


def _transposed(T) -> np.ndarray:
    return _pose(T[:3, :3].T, T[:3, 3])


def _mm(T) -> np.ndarray:
    return _pose(T[:3, :3], T[:3, 3] * 1000.0)


def _wrap(f, post):
    return lambda *a: post(f(*a))


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


def _rotvec_no_zero_check(rvec, t):
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    K = geo.skew(rvec / theta)
    return _pose(np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K, t)


def lab0(ns) -> dict:
    ref_rotvec = ns["pose_from_rotvec"]
    return {
        "invert_pose": [
            Variant("notebook solution", True, ns["invert_pose"]),
            Variant("np.linalg.inv", True, lambda T: np.linalg.inv(T)),
            Variant("R not transposed", False, lambda T: _pose(T[:3, :3], -T[:3, :3] @ T[:3, 3])),
            Variant("t negated only (-t, not -R^T t)", False,
                    lambda T: _pose(T[:3, :3].T, -T[:3, 3])),
            Variant("returns the pose itself", False, lambda T: np.array(T)),
        ],
        "compose_chain": [
            Variant("notebook solution", True, ns["compose_chain"]),
            Variant("np.linalg.multi_dot", True,
                    lambda P: np.linalg.multi_dot([np.eye(4), *P]) if len(P) < 2
                    else np.linalg.multi_dot(P)),
            Variant("reversed multiplication order", False,
                    lambda P: ns["compose_chain"](list(P)[::-1])),
            Variant("inverse poses composed", False,
                    lambda P: ns["compose_chain"]([_inv(T) for T in P])),
        ],
        "pose_from_rotvec": [
            Variant("notebook solution", True, ref_rotvec),
            Variant("quaternion formula", True, _rotvec_quaternion),
            Variant("Taylor series near 0", True, _rotvec_series),
            Variant("scipy Rotation.from_rotvec", True,
                    lambda r, t: _pose(Rotation.from_rotvec(r).as_matrix(), t)),
            Variant("degrees taken for radians", False,
                    lambda r, t: ref_rotvec(np.radians(np.asarray(r, float)), t)),
            Variant("transposed rotation", False, _wrap(ref_rotvec, _transposed)),
            Variant("no zero-rotation check (0/0)", False, _rotvec_no_zero_check),
            Variant("translation in mm", False, _wrap(ref_rotvec, _mm)),
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


def _kabsch(src, dst, reflection_fix=True, degenerate_check=True):
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    a, b = src - src.mean(0), dst - dst.mean(0)
    if degenerate_check:
        if len(src) < 3:
            raise ValueError("fewer than 3 points")
        s = np.linalg.svd(a, compute_uv=False)
        if s[1] < 1e-3 * s[0]:
            raise ValueError("collinear points")
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) if reflection_fix else 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, dst.mean(0) - R @ src.mean(0))


def _residuals_homogeneous(T, src, dst):
    h = np.c_[src, np.ones(len(src))] @ np.asarray(T).T
    return np.linalg.norm(h[:, :3] - dst, axis=1)


def _rmse_inverse_map(T, src, dst):
    """Residuals measured in the src frame by mapping dst back: inv(T) dst - src = -R^T r."""
    back = geo.transform_points(np.linalg.inv(T), dst) - src
    return np.sqrt(np.mean(back ** 2, axis=0))


def _rmse_dst_axes(T, src, dst):
    r = geo.transform_points(T, src) - dst
    return np.sqrt(np.mean(r ** 2, axis=0))


def _rmse_r_not_transposed(T, src, dst):
    r = geo.transform_points(T, src) - dst
    return np.sqrt(np.mean((r @ T[:3, :3].T) ** 2, axis=0))


def lab1(ns) -> dict:
    fit, res, rmse = ns["fit_rigid"], ns["per_point_residuals"], ns["per_axis_rmse"]
    return {
        "fit_rigid": [
            Variant("notebook solution", True, fit),
            Variant("solutions.registration.fit_rigid", True, reg.fit_rigid),
            Variant("Horn quaternion fit", True, _horn),
            Variant("no reflection fix", False, lambda s, d: _kabsch(s, d, reflection_fix=False)),
            Variant("no degenerate-input check", False,
                    lambda s, d: _kabsch(s, d, degenerate_check=False)),
            Variant("inverse pose (src_T_dst)", False, _wrap(fit, _inv)),
            Variant("swapped src / dst", False, lambda s, d: fit(d, s)),
            Variant("transposed rotation", False, _wrap(fit, _transposed)),
            Variant("translation in mm", False, _wrap(fit, _mm)),
        ],
        "per_point_residuals": [
            Variant("notebook solution", True, res),
            Variant("solutions.registration.residuals", True,
                    lambda T, s, d: np.linalg.norm(reg.residuals(T, s, d), axis=1)),
            Variant("homogeneous coordinates", True, _residuals_homogeneous),
            Variant("squared distances", False, lambda T, s, d: res(T, s, d) ** 2),
            Variant("inverse pose used", False, lambda T, s, d: res(_inv(T), s, d)),
            Variant("transposed rotation", False, lambda T, s, d: res(_transposed(T), s, d)),
            Variant("in mm", False, lambda T, s, d: res(T, s, d) * 1000.0),
        ],
        "per_axis_rmse": _rmse_variants(rmse, "src"),
    }


def _rmse_variants(rmse, frame) -> list[Variant]:
    return [
        Variant("notebook solution", True, rmse),
        Variant("solutions.registration.per_axis_rmse", True,
                lambda T, s, d: reg.per_axis_rmse(T, s, d, expressed_in="src")),
        Variant(f"inverse map into the {frame} frame", True, _rmse_inverse_map),
        Variant("along the dst (base) axes", False, _rmse_dst_axes),
        Variant("R instead of R^T", False, _rmse_r_not_transposed),
        Variant("mean square (no sqrt)", False, lambda T, s, d: rmse(T, s, d) ** 2),
        Variant("one RMS for all axes", False,
                lambda T, s, d: np.full(3, np.sqrt(np.mean(rmse(T, s, d) ** 2)))),
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


def _motions_with(a_of, b_of, strategy_ignored=False):
    def motions(F, C, strategy="all"):
        n = len(F)
        if strategy_ignored:
            strategy = "all"
        pairs = ([(i, j) for i in range(n) for j in range(i + 1, n)] if strategy == "all"
                 else [(i, i + 1) for i in range(n - 1)])
        return (np.array([a_of(F[i], F[j]) for i, j in pairs]),
                np.array([b_of(C[i], C[j]) for i, j in pairs]))
    return motions


def _solver_variants(ref, alt_name, alt, extra=()) -> list[Variant]:
    return [
        Variant("notebook solution", True, ref),
        Variant(alt_name, True, alt),
        Variant("consecutive pairs only", True, lambda A, B: ref(*_consecutive_of_all(A, B))),
        *extra,
        Variant("inverse X (cam_T_flange)", False, _wrap(ref, _inv)),
        Variant("swapped A / B", False, lambda A, B: ref(B, A)),
        Variant("transposed R_X", False, _wrap(ref, _transposed)),
        Variant("t_X in mm", False, _wrap(ref, _mm)),
    ]


def lab2(ns) -> dict:
    mot, rr, tr = ns["motions"], ns["rotation_residual"], ns["translation_residual"]
    return {
        "motions": [
            Variant("notebook solution", True, mot),
            Variant("np.linalg.inv", True, _motions_np_inv),
            Variant("B = inv(C_i) C_j (inverse on the wrong side)", False,
                    _motions_with(lambda Fi, Fj: _inv(Fi) @ Fj, lambda Ci, Cj: _inv(Ci) @ Cj)),
            Variant("A = inv(F_j) F_i (reversed)", False,
                    _motions_with(lambda Fi, Fj: _inv(Fj) @ Fi, lambda Ci, Cj: Ci @ _inv(Cj))),
            Variant("strategy ignored (always all pairs)", False,
                    _motions_with(lambda Fi, Fj: _inv(Fi) @ Fj, lambda Ci, Cj: Ci @ _inv(Cj),
                                  strategy_ignored=True)),
            Variant("swapped A / B", False, lambda F, C, s="all": mot(F, C, s)[::-1]),
        ],
        "tsai_lenz": _solver_variants(ns["tsai_lenz"], "solutions.handeye.solve_tsai",
                                      he.solve_tsai),
        "axes_ls": _solver_variants(ns["axes_ls"], "Park-Martin", _park_martin,
                                    [Variant("solutions.handeye.solve_axes_ls", True,
                                             he.solve_axes_ls)]),
        "rotation_residual": [
            Variant("notebook solution", True, rr),
            Variant("solutions.handeye.rotation_residual", True, he.rotation_residual),
            Variant("sum, not mean", False, lambda A, B, X: rr(A, B, X) * len(A)),
            Variant("Frobenius norm, not squared", False,
                    lambda A, B, X: float(np.mean([np.linalg.norm(a[:3, :3] @ X[:3, :3]
                                                                  - X[:3, :3] @ b[:3, :3])
                                                   for a, b in zip(A, B)]))),
            Variant("R_X transposed", False, lambda A, B, X: rr(A, B, _transposed(X))),
        ],
        "translation_residual": [
            Variant("notebook solution", True, tr),
            Variant("solutions.handeye.translation_residual", True, he.translation_residual),
            Variant("sum, not mean", False, lambda A, B, X: tr(A, B, X) * len(A)),
            Variant("in mm^2", False, lambda A, B, X: tr(A, B, X) * 1e6),
            Variant("inverse X", False, lambda A, B, X: tr(A, B, _inv(X))),
        ],
    }


# --------------------------------------------------------------------------- lab 3


def _interaction_stacked(x, y, Z):
    """The right entries, rows stacked x1..xn, y1..yn instead of x1, y1, x2, ..."""
    L = np.asarray(interaction_matrix(x, y, Z))
    return np.vstack([L[0::2], L[1::2]])


def _interaction_rotation_sign(x, y, Z):
    L = np.asarray(interaction_matrix(x, y, Z)).copy()
    L[:, 3:] *= -1
    return L


def _interaction_no_depth(x, y, Z):
    L = np.asarray(interaction_matrix(x, y, np.ones_like(np.asarray(Z, float)))).copy()
    return L


def _ibvs_lstsq(s, s_star, Z, gain):
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = interaction_matrix(s[:, 0], s[:, 1], Z)
    return -gain * np.linalg.lstsq(L, (s - s_star).reshape(-1), rcond=None)[0]


def _ibvs_transpose(s, s_star, Z, gain):
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    return -gain * interaction_matrix(s[:, 0], s[:, 1], Z).T @ (s - s_star).reshape(-1)


def _ibvs_flipped(s, s_star, Z, gain):
    return -_ibvs_lstsq(s, s_star, Z, gain)


def _ibvs_no_gain(s, s_star, Z, gain):
    return _ibvs_lstsq(s, s_star, Z, 1.0)


def _piece_nanmedian(depth, uv, K):
    """np.nanmedian of the 5x5 window (the reference drops NaN and non-positive depths)."""
    u, v = np.rint(np.asarray(uv, float)).astype(int)
    Z = float(np.nanmedian(depth[v - 2:v + 3, u - 2:u + 3]))
    return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])


def _piece_pixel_only(depth, uv, K):
    u, v = np.rint(np.asarray(uv, float)).astype(int)
    Z = float(depth[v, u])
    return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])


def _piece_swapped(depth, uv, K, ref=None):
    return ref(depth, (uv[1], uv[0]), K)


def lab3(ns) -> dict:
    global interaction_matrix
    interaction_matrix = ns["interaction_matrix"]
    piece = ns["piece_position"]
    return {
        "interaction_matrix": [
            Variant("notebook solution", True, ns["interaction_matrix"]),
            Variant("solutions.servoing.interaction_matrix", True,
                    lambda x, y, Z: sv.interaction_matrix(np.column_stack([x, y]), Z)),
            Variant("rows stacked x..., y...", False, _interaction_stacked),
            Variant("rotation columns' sign flipped", False, _interaction_rotation_sign),
            Variant("depth ignored (Z = 1)", False, _interaction_no_depth),
        ],
        "ibvs_velocity": [
            Variant("notebook solution", True, ns["ibvs_velocity"]),
            Variant("lstsq instead of pinv", True, _ibvs_lstsq),
            Variant("gain sign flipped", False, _ibvs_flipped),
            Variant("L^T instead of pinv(L)", False, _ibvs_transpose),
            Variant("gain ignored", False, _ibvs_no_gain),
        ],
        "piece_position": [
            Variant("notebook solution", True, piece),
            Variant("np.nanmedian of the 5x5 window", True, _piece_nanmedian),
            Variant("the pixel's own depth (no hole handling)", False, _piece_pixel_only),
            Variant("u and v swapped", False,
                    lambda d, uv, K: _piece_swapped(d, uv, K, ref=piece)),
            Variant("depth in mm", False, lambda d, uv, K: piece(d, uv, K) * 1000.0),
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


def _frame_y_copied(o, px, pxy):
    o, px, pxy = (np.asarray(p, float) for p in (o, px, pxy))
    x = (px - o) / np.linalg.norm(px - o)
    y = (pxy - o) / np.linalg.norm(pxy - o)
    return _pose(np.column_stack([x, y, np.cross(x, y)]), o)


def _reproject_float32(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, np.float32) @ np.array([u, v, d, 1.0], np.float32)
    return np.array([X, Y, Z], np.float32) / W


def _reproject_cv2(u, v, d, Q):
    import cv2

    return cv2.perspectiveTransform(np.array([[[u, v, d]]], np.float32),
                                    np.asarray(Q, float)).reshape(3)


def _reproject_no_shift(u, v, d, Q):
    Q = np.array(Q, float)
    Q[3, 3] = 0.0
    X, Y, Z, W = Q @ np.array([u, v, d, 1.0])
    return np.array([X, Y, Z]) / W


def _chain_fit_rigid(cam, base):
    return _kabsch(cam, base)


def lab4(ns) -> dict:
    frame, rep, chain = ns["frame_from_three_points"], ns["reproject"], \
        ns["hand_to_eye_from_three_points"]

    def chain_with(combine):
        def hand_to_eye(cam_points, base_points):
            cam_T_world = frame_from_three_points(*np.asarray(cam_points, float))
            base_T_world = frame_from_three_points(*np.asarray(base_points, float))
            return combine(base_T_world, cam_T_world)
        return hand_to_eye

    global frame_from_three_points
    frame_from_three_points = frame
    return {
        "frame_from_three_points": [
            Variant("notebook solution", True, frame),
            Variant("solutions.registration.frame_from_three_points", True,
                    reg.frame_from_three_points),
            Variant("Gram-Schmidt y", True, _frame_gram_schmidt),
            Variant("left-handed (z = (p_xy - o) x x)", False,
                    lambda o, px, pxy: frame(o, px, pxy) @ np.diag([1.0, -1.0, -1.0, 1.0])),
            Variant("p_xy - o copied as the y axis", False, _frame_y_copied),
            Variant("inverse pose (frame_T_parent)", False, _wrap(frame, _inv)),
            Variant("transposed rotation", False, _wrap(frame, _transposed)),
        ],
        "reproject": [
            Variant("notebook solution", True, rep),
            Variant("float32 arithmetic", True, _reproject_float32),
            Variant("cv2.perspectiveTransform (float32)", True, _reproject_cv2),
            Variant("divided by Z, not W", False,
                    lambda u, v, d, Q: (lambda h: h[:3] / h[2])(np.asarray(Q) @ [u, v, d, 1.0])),
            Variant("(cx - cx')/Tx term dropped", False, _reproject_no_shift),
            Variant("disparity sign flipped", False, lambda u, v, d, Q: rep(u, v, -d, Q)),
            Variant("in mm", False, lambda u, v, d, Q: np.asarray(rep(u, v, d, Q)) * 1000.0),
        ],
        "hand_to_eye_from_three_points": [
            Variant("notebook solution", True, chain),
            Variant("fit_rigid on the three points", True, _chain_fit_rigid),
            Variant("inverse (cam_T_base)", False, _wrap(chain, _inv)),
            Variant("reversed order (world_T_cam @ base_T_world)", False,
                    chain_with(lambda bw, cw: _inv(cw) @ bw)),
            Variant("camera frame used as the world (no inverse)", False,
                    chain_with(lambda bw, cw: bw @ cw)),
        ],
        "per_axis_rmse": _rmse_variants(ns["per_axis_rmse"], "camera"),
    }


frame_from_three_points = None  # set by lab4(): the notebook's, replaced by the stand-in


# --------------------------------------------------------------------------- lab 5


def _backproject_float32(depth_raw, K, depth_scale):
    """All in float32, as the RealSense SDK hands out depth (raw * scale as float32)."""
    z = np.asarray(depth_raw).astype(np.float32) * np.float32(depth_scale)
    z[np.asarray(depth_raw) == 0] = np.nan
    v, u = np.indices(z.shape).astype(np.float32)
    K = np.asarray(K, np.float32)
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)


def _backproject_with(depth_raw, K, depth_scale, scale=None, swap=False, inverted=False,
                      holes_nan=True):
    z = np.asarray(depth_raw, dtype=float) * (depth_scale if scale is None else scale)
    if holes_nan:
        z[np.asarray(depth_raw) == 0] = np.nan
    v, u = np.indices(z.shape)
    if swap:
        u, v = v, u
    fx, fy = (1 / K[0, 0], 1 / K[1, 1]) if inverted else (K[0, 0], K[1, 1])
    return np.stack([(u - K[0, 2]) * z / fx, (v - K[1, 2]) * z / fy, z], axis=-1)


def _towards_camera(centre, normal):
    return centre, (-normal if normal @ centre > 0 else normal)


def _plane_svd_all(points, inlier_m, iterations=500, seed=0):
    pts = np.asarray(points, float).reshape(-1, 3)
    centre = pts.mean(axis=0)
    return _towards_camera(centre, np.linalg.svd(pts - centre, full_matrices=False)[2][2])


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


def _circle_kasa(rim, radius_m):
    """The algebraic (Kasa) fit in the rim's plane, not refined: the mistake."""
    c0, n, e1, e2, xy = _rim_plane(rim)
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    cx, cy, _ = np.linalg.lstsq(A, (xy ** 2).sum(axis=1), rcond=None)[0]
    return c0 + cx * e1 + cy * e2, n


def _circle_lm(rim, radius_m):
    """Levenberg-Marquardt (scipy) on the geometric residuals, the radius fixed."""
    from scipy.optimize import least_squares

    c0, n, e1, e2, xy = _rim_plane(rim)
    start = np.asarray(_circle_kasa(rim, radius_m)[0] - c0) @ np.column_stack([e1, e2])
    cx, cy = least_squares(lambda c: np.linalg.norm(xy - c, axis=1) - radius_m, start,
                           method="lm").x
    return c0 + cx * e1 + cy * e2, n


def _registration_rt(cam_centres, base_T_flanges):
    """The cross-covariance built base-first: R^T (the mistake)."""
    a = np.asarray(cam_centres, float)
    b = np.asarray(base_T_flanges, float)[:, :3, 3]
    U, _, Vt = np.linalg.svd((b - b.mean(0)).T @ (a - a.mean(0)))
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return _pose(R, b.mean(0) - R @ a.mean(0))


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


def _rectangle_not_orthogonal(corners_px, width_m, height_m, K, ref=None):
    """The vanishing-point directions used as they are: R = [dx, dy, dx x dy]."""
    h = np.column_stack([corners_px, np.ones(4)]) @ np.linalg.inv(K).T
    dx = np.cross(np.cross(h[0], h[1]), np.cross(h[3], h[2]))
    dy = np.cross(np.cross(h[0], h[3]), np.cross(h[1], h[2]))
    dx = dx * (np.sign(dx[:2] @ (h[1, :2] - h[0, :2])) or 1.0)
    dy = dy * (np.sign(dy[:2] @ (h[3, :2] - h[0, :2])) or 1.0)
    dx, dy = dx / np.linalg.norm(dx), dy / np.linalg.norm(dy)
    T = np.array(ref(corners_px, width_m, height_m, K), dtype=float)
    T[:3, :3] = np.column_stack([dx, dy, np.cross(dx, dy)])
    return T


def _flip_normal(f):
    def flipped(*args):
        centre, normal = f(*args)
        return centre, -np.asarray(normal, float)
    return flipped


def lab5(ns) -> dict:
    bp, plane, circle = ns["backproject"], ns["fit_plane_ransac"], ns["fit_flange_circle"]
    reg5, rect = ns["base_T_cam_from_flanges"], ns["rectangle_pose"]
    return {
        "backproject": [
            Variant("notebook solution", True, bp),
            Variant("float32 arithmetic (as the RealSense SDK)", True, _backproject_float32),
            Variant("depth in millimetres (depth_scale ignored)", False,
                    lambda d, K, s: _backproject_with(d, K, s, scale=1.0)),
            Variant("depth_scale hard-coded to 0.001", False,
                    lambda d, K, s: _backproject_with(d, K, s, scale=0.001)),
            Variant("u and v swapped", False, lambda d, K, s: _backproject_with(d, K, s, swap=True)),
            Variant("intrinsics inverted ((u - cx) fx)", False,
                    lambda d, K, s: _backproject_with(d, K, s, inverted=True)),
            Variant("holes left at z = 0", False,
                    lambda d, K, s: _backproject_with(d, K, s, holes_nan=False)),
        ],
        "fit_plane_ransac": [
            Variant("notebook solution", True, plane),
            Variant("covariance eigenvector refit", True,
                    lambda p, t, i=500, s=0: _plane_ransac(p, t, i, s, refit="eigh")),
            Variant("MSAC scoring", True, lambda p, t, i=500, s=0: _plane_ransac(p, t, i, s,
                                                                                  msac=True)),
            Variant("twice the iterations", True, lambda p, t, i=500, s=0: plane(p, t, 2 * i, s)),
            Variant("no outlier rejection (SVD on all points)", False, _plane_svd_all),
            Variant("normal away from the camera", False, _flip_normal(plane)),
        ],
        "fit_flange_circle": [
            Variant("notebook solution", True, circle),
            Variant("Levenberg-Marquardt (scipy), radius fixed", True, _circle_lm),
            Variant("algebraic (Kasa) fit, unrefined", False, _circle_kasa),
            Variant("normal away from the camera", False, _flip_normal(circle)),
        ],
        "base_T_cam_from_flanges": [
            Variant("notebook solution", True, reg5),
            Variant("Horn quaternion fit", True,
                    lambda a, F: _horn(a, np.asarray(F, float)[:, :3, 3])),
            Variant("cam_T_base returned (inverse)", False, _wrap(reg5, _inv)),
            Variant("cross-covariance the other way round (R^T)", False, _registration_rt),
        ],
        "rectangle_pose": [
            Variant("notebook solution", True, rect),
            Variant("homography decomposition, orthogonalised", True, _rectangle_homography),
            Variant("width and height swapped", False,
                    lambda uv, w, h, K: rect(uv, h, w, K)),
            Variant("K not inverted (pixels used as rays)", False,
                    lambda uv, w, h, K: rect(uv, w, h, np.eye(3))),
            Variant("edge directions not made orthogonal", False,
                    lambda uv, w, h, K: _rectangle_not_orthogonal(uv, w, h, K, ref=rect)),
        ],
    }

LABS = {"lab0_frames": lab0, "lab1_flange": lab1, "lab2_handeye": lab2,
        "lab3_servoing": lab3, "lab4_stereo": lab4, "lab5_depth": lab5}


def variants(assignment: str) -> dict[str, list[Variant]]:
    return LABS[assignment](notebook_solutions(assignment))


# --------------------------------------------------------------------------- the Monte Carlo


def problem_rng(assignment: str, student: str, function: str) -> np.random.Generator:
    """The grader's own generator for one student's problems of one function."""
    params = inspect.signature(grading.problem_rng).parameters
    if "nonce" in params:  # a per-run nonce (older API): one fixed nonce for the whole run
        return grading.problem_rng(SECRET, "fairness", assignment, student, function)
    return grading.problem_rng(SECRET, assignment, student, function)


def _margin(spec, trial, outcome) -> float:
    """Largest error / full-credit tolerance over the checks (inf: no usable answer)."""
    if trial.raises is not None:
        ok = outcome.error is not None and outcome.error.split(":", 1)[0] == trial.raises
        return 0.0 if ok else math.inf
    if outcome.error is not None:
        return math.inf
    try:
        measured = spec.measure(outcome.value, trial)
    except checks.OutputError:
        return math.inf
    return max(float(measured[c.name]) / trial.tol[c.name] for c in spec.checks)


def run_function(job) -> dict:
    """All variants of one function over draws [start, stop): losses and margins.

    ``job`` is (assignment, function, start, stop[, mistakes_stop]): mistakes are scored on
    draws below ``mistakes_stop`` only (1,000 draws without a miss already bound their rate
    above 99.6 %; it is correct code that needs the long run)."""
    assignment, name, start, stop = job[:4]
    mistakes_stop = job[4] if len(job) > 4 else stop
    spec = next(s for s in checks.SPECS[assignment] if s.name == name)
    table = variants(assignment)[name]
    lost = [0] * len(table)
    seen = [0] * len(table)
    points = [0.0] * len(table)
    margin = [0.0 if v.correct else math.nan for v in table]
    examples: list[str | None] = [None] * len(table)
    started = time.perf_counter()
    np.seterr(all="ignore")  # the mistakes divide by zero on purpose
    for k in range(start, stop):
        trials = checks.make_trials(spec, problem_rng(assignment, f"student{k:06d}", name))
        for i, v in enumerate(table):
            if not v.correct and k >= mistakes_stop:
                continue
            seen[i] += 1
            outcomes = [checks._call_in_process(v.func, t, spec) for t in trials]
            result = checks.score_function(spec, trials, outcomes)
            points[i] += result.points
            if result.points < spec.points:
                lost[i] += 1
                if examples[i] is None:
                    examples[i] = f"student{k:06d}: {result.points:g}/{spec.points:g}"
            if v.correct:  # how close correct code comes to losing credit
                margin[i] = max(margin[i], *(_margin(spec, t, o)
                                             for t, o in zip(trials, outcomes)))
    return {"assignment": assignment, "function": name, "start": start,
            "draws": stop - start, "seen": seen,
            "variants": [v.name for v in table], "correct": [v.correct for v in table],
            "lost": lost, "points": points, "margin": margin, "examples": examples,
            "seconds": time.perf_counter() - started, "n_trials": spec.n_trials,
            "max_points": spec.points}


def _merge(parts: list[dict]) -> dict:
    parts = sorted(parts, key=lambda p: p["start"])  # the first example is the lowest draw
    out = dict(parts[0])
    out["draws"] = sum(p["draws"] for p in parts)
    out["seen"] = [sum(p["seen"][i] for p in parts) for i in range(len(out["seen"]))]
    out["lost"] = [sum(p["lost"][i] for p in parts) for i in range(len(out["lost"]))]
    out["points"] = [sum(p["points"][i] for p in parts) for i in range(len(out["points"]))]
    out["margin"] = [max(p["margin"][i] for p in parts) if c else math.nan
                     for i, c in enumerate(out["correct"])]
    out["examples"] = [next((p["examples"][i] for p in parts if p["examples"][i]), None)
                       for i in range(len(out["lost"]))]
    out["seconds"] = sum(p["seconds"] for p in parts)
    return out


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval for k successes in n trials."""
    a = (1 - level) / 2
    low = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    high = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return low, high


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
    for i, name in enumerate(result["variants"]):
        n, k = result["seen"][i], result["lost"][i]
        low, high = clopper_pearson(k, n)
        rows.append({"function": result["function"], "assignment": result["assignment"],
                     "variant": name, "correct": result["correct"][i], "draws": n,
                     "lost": k, "rate": k / n, "low": low, "high": high,
                     "mean_points": result["points"][i] / n, "max_points": result["max_points"],
                     "margin": result["margin"][i], "example": result["examples"][i],
                     "verdict": verdict(result["correct"][i], k, n)})
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
        "`grading.problem_rng` over distinct student ids) and every variant is scored on the "
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
    parser.add_argument("--labs", default="", help="comma-separated assignments (default all)")
    parser.add_argument("--functions", default="", help="comma-separated function names")
    parser.add_argument("--workers", type=int, default=1, help="processes (2 on a quiet machine)")
    parser.add_argument("--no-write", action="store_true", help="print only")
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
            jobs += [(lab, spec.name, s, min(s + chunk, draws), args.mistake_draws)
                     for s in range(0, draws, chunk)]
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
    if not args.no_write:
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
