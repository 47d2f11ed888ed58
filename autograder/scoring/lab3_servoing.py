"""Lab 3 (visual servoing to chess pieces): how its graded functions are scored.

* ``interaction_matrix(x, y, Z)`` is compared entry by entry with the derivative of the
  point projection under each of the six camera twist components, which the private
  generator computes by finite differences of the moved points.
* ``ibvs_velocity(s, s_star, Z, gain)`` is graded in closed loop (:func:`_drive_ibvs`): a free
  camera (pure kinematics, no images) starts from a hidden offset, the student's law is
  called once per control period with the features it sees, the returned twist is
  integrated, and where the camera ends up is scored, with the first twist against the one
  the problem holds.
* ``piece_position(depth, uv, K)`` is scored against the true surface point seen at pixel
  ``uv`` of a noisy synthetic depth image with holes.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.spec_types import Check, FunctionSpec, OutputError, Trial
from robots import geometry as geo

# --------------------------------------------------------------------------- helpers


def _move(T: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """Pose after a constant body twist for dt seconds (the exact SE(3) exponential, in
    closed form: scipy's general expm costs milliseconds a call)."""
    # Plain-float arithmetic where it is cheap: a closed-loop trial calls this ~70 times and
    # numpy's per-call overhead on 3-vectors was most of the grader's time.
    xi = np.asarray(twist, float) * dt
    v, w = xi[:3], xi[3:]
    wx, wy, wz = w.tolist()
    theta = math.sqrt(wx * wx + wy * wy + wz * wz)
    W = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    if theta < 1e-8:
        V = np.eye(3) + 0.5 * W
    else:
        V = (np.eye(3) + (1 - math.cos(theta)) / theta ** 2 * W
             + (theta - math.sin(theta)) / theta ** 3 * W @ W)
    step = np.eye(4)
    step[:3, :3] = geo.rotation_from_rotvec(w)
    step[:3, 3] = V @ v
    return T @ step


def _as_array(value, shape: tuple, what: str) -> np.ndarray:
    if isinstance(value, (list, tuple)):
        try:
            value = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise OutputError(f"returned a list that is not a {shape} array of numbers") from None
    if not isinstance(value, np.ndarray):
        raise OutputError(f"returned {type(value).__name__}, expected {what}")
    if value.shape != shape:
        raise OutputError(f"returned shape {value.shape}, expected {shape} ({what})")
    value = value.astype(float)
    if not np.all(np.isfinite(value)):
        raise OutputError("returned NaN or inf")
    return value


# --------------------------------------------------------------------------- interaction matrix


def _measure_interaction(value, trial: Trial) -> dict[str, float]:
    L = _as_array(value, trial.truth.shape, "the (2n, 6) interaction matrix, rows x1, y1, x2, ...")
    err = np.abs(L - trial.truth)
    return {"translation": float(err[:, :3].max()), "rotation": float(err[:, 3:].max())}


INTERACTION_MATRIX = FunctionSpec(
    name="interaction_matrix", points=4.0, n_trials=18, practice_trials=6, make_trial=None,
    measure=_measure_interaction,
    checks=(
        Check("translation", "", 0.5, ((1.0, 1.0), (100.0, 0.5)),
              "columns vx, vy, vz (the -1/Z and x/Z, y/Z terms) against finite differences"),
        Check("rotation", "", 0.5, ((1.0, 1.0), (100.0, 0.5)),
              "columns wx, wy, wz (the xy, 1 + x^2, 1 + y^2 terms and their signs)"),
    ),
    signature="interaction_matrix(x: (n,), y: (n,), Z: (n,)) -> L (2n, 6)",
    parameters="x, y, Z",
)


# --------------------------------------------------------------------------- IBVS in closed loop

SERVO_DT = 0.1             # s, one control period
SERVO_ITERATIONS = 80
SERVO_MAX_LINEAR = 0.5     # m/s: a saturation, as on any robot
SERVO_MAX_ANGULAR = 1.5    # rad/s
SERVO_FOV = 1.0            # |x|, |y| beyond this (a 90-degree view) and the target is lost


def _features(T_cam, pts_world):
    P = (pts_world - T_cam[:3, 3]) @ T_cam[:3, :3]  # rows of R^T (p - t): the camera frame
    return P[:, :2] / P[:, 2:], P[:, 2]


def _twist_hat(twist) -> np.ndarray:
    """The (4, 4) se(3) matrix of a body twist (vx, vy, vz, wx, wy, wz), any dtype."""
    v, (wx, wy, wz) = twist[:3], twist[3:]
    return np.array([[0, -wz, wy, v[0]], [wz, 0, -wx, v[1]], [-wy, wx, 0, v[2]], [0, 0, 0, 0]],
                    dtype=np.asarray(twist).dtype)


def _expm_series(X: np.ndarray) -> np.ndarray:
    """exp(X) by its Taylor series, analytic in X (so complex steps pass through it); only for
    a tiny X, where a few terms reach rounding."""
    result, term = np.eye(len(X), dtype=X.dtype), np.eye(len(X), dtype=X.dtype)
    scale = float(np.abs(X).max())
    for k in range(1, 30):
        term = term @ X / k
        result = result + term
        if float(np.abs(term).max()) <= 1e-20 * scale:  # far below X's own rounding
            break
    return result


def _projection_jacobian(x, y, Z) -> np.ndarray:
    """How the projections of the scene points seen at (x, y) and depth Z move per unit of
    each camera twist component: the derivative of the problem's own construction (move the
    camera, project the points), by complex step, so it is exact to rounding (no formula)."""
    x, y, Z = (np.asarray(a, dtype=float).reshape(-1) for a in (x, y, Z))
    n = len(Z)
    P = np.column_stack([x * Z, y * Z, Z, np.ones(n)])
    h = 1e-30
    L = np.zeros((2 * n, 6))
    for k in range(6):
        e = np.zeros(6, dtype=complex)
        e[k] = 1j * h
        # The camera moves with body twist e, the points stay: they move by exp(-e^) in it.
        moved = P @ _expm_series(_twist_hat(-e)).T
        L[:, k] = (np.imag(moved[:, :2] / moved[:, 2:3]) / h).reshape(-1)
    return L


def _ibvs_substitutes(args) -> dict:
    # ibvs_velocity is scored on its own: its call of interaction_matrix(x, y, Z) gets the
    # true matrix, so an error in L costs its points once, in interaction_matrix. The loop's
    # states are only known while it runs, so the table is derived here, from the geometry.
    s, _, Z, _ = args
    s, Z = np.asarray(s, dtype=float), np.asarray(Z, dtype=float)
    return {"interaction_matrix": [((s[:, 0], s[:, 1], Z), _projection_jacobian(s[:, 0], s[:, 1], Z))]}


def _drive_ibvs(call, trial: Trial) -> dict:
    """Fly the camera from ``truth["start"]`` with the student's law; the first twist is
    compared with ``truth["first_twist"]``, the law's value at the start (from the problem)."""
    pts, goal, gain = trial.truth["pts"], trial.truth["goal"], trial.truth["gain"]
    s_star, _ = _features(goal, pts)
    T = trial.truth["start"].copy()
    velocity_error = math.inf
    for k in range(SERVO_ITERATIONS):
        s, Z = _features(T, pts)
        if np.any(Z <= 0.02) or np.any(np.abs(s) > SERVO_FOV):
            break  # the target left the view: the servo is over, wherever the camera is
        if np.sqrt(np.mean(np.sum((s - s_star) ** 2, axis=1))) < 1e-9:
            break
        v = _as_array(call(s.copy(), s_star.copy(), Z.copy(), gain), (6,),
                      "the camera twist (vx, vy, vz, wx, wy, wz)")
        if k == 0:
            ref = trial.truth["first_twist"]
            velocity_error = float(np.linalg.norm(v - ref) / np.linalg.norm(ref))
        nv, nw = np.linalg.norm(v[:3]), np.linalg.norm(v[3:])
        v = v * min(1.0, SERVO_MAX_LINEAR / max(nv, 1e-300), SERVO_MAX_ANGULAR / max(nw, 1e-300))
        T = _move(T, v, SERVO_DT)
    delta = np.linalg.inv(goal) @ T
    return {"position": float(np.linalg.norm(delta[:3, 3]) * 1000.0),
            "rotation": float(np.degrees(Rotation.from_matrix(delta[:3, :3]).magnitude())),
            "velocity": velocity_error}


def _measure_ibvs(value, trial: Trial) -> dict[str, float]:
    return value  # the closed loop above measured it


IBVS_VELOCITY = FunctionSpec(
    name="ibvs_velocity", points=4.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_ibvs, drive=_drive_ibvs,
    checks=(
        # Neutral words: a law that diverges may have a flipped gain, a stacked error vector,
        # an angular velocity in deg/s or (w, v) for (v, w); the named mistake, if one
        # matches, is in the feedback's errors (autograder.mistakes).
        Check("position", "mm", 0.35, ((1.0, 1.0), (10.0, 0.5)),
              f"camera position error to the goal after {SERVO_ITERATIONS} periods of "
              f"{SERVO_DT} s: does the law converge from the start?"),
        Check("rotation", "deg", 0.35, ((1.0, 1.0), (10.0, 0.5)),
              "camera rotation error to the goal at the end of the closed loop"),
        Check("velocity", "", 0.3, ((1.0, 1.0),),
              "relative error of the first twist against v = -gain pinv(L) (s - s*), with "
              "(s - s*) in L's row order (x1, y1, x2, y2, ...) and the twist (vx, vy, vz, "
              "wx, wy, wz) in m/s and rad/s"),
    ),
    signature="ibvs_velocity(s: (n, 2), s_star: (n, 2), Z: (n,), gain: float) -> v (6,)",
    parameters="s, s_star, Z, gain",
    time_limit_s=20.0,
    substitutes=_ibvs_substitutes,
)


# --------------------------------------------------------------------------- piece position


def _measure_piece(value, trial: Trial) -> dict[str, float]:
    p = _as_array(value, (3,), "the point (X, Y, Z) in the camera frame, metres")
    return {"position": float(np.linalg.norm(p - trial.truth) * 1000.0)}


PIECE_POSITION = FunctionSpec(
    name="piece_position", points=2.0, n_trials=6, practice_trials=2, make_trial=None,
    measure=_measure_piece,
    checks=(
        Check("position", "mm", 1.0, ((1.0, 1.0), (3.0, 0.5)),
              "distance to the true surface point at the pixel: Z from the median of the "
              "valid depths around depth[v, u] (holes are NaN), then X = (u - cx) Z / fx, "
              "Y = (v - cy) Z / fy (Z is the depth, not the distance along the ray)"),
    ),
    signature="piece_position(depth: (H, W) metres, uv: (2,) px, K: (3, 3)) -> p_cam (3,)",
    parameters="depth, uv, K",
)

SPECS = (INTERACTION_MATRIX, IBVS_VELOCITY, PIECE_POSITION)
