"""Lab 3 (visual servoing to chess pieces), private side: problems, truths, the
reference control law and the code mistakes.

The scoring is public, in :mod:`autograder.scoring.lab3_servoing`; this module draws the
problems and computes their truths, and is never given to students:

* ``interaction_matrix``: the truth is central finite differences of the point projection
  under each of the six camera twist components;
* ``ibvs_velocity``: a start the textbook law can reach, and the law's first twist from it,
  which the public closed loop compares the student's first twist with;
* ``piece_position``: a noisy synthetic depth image with holes and the true surface point.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.scoring import lab3_servoing as scoring
from autograder.scoring.lab3_servoing import _drive_ibvs, _features, _move
from autograder.spec_types import CodeMistake, Trial


def _look_at_pose(rng, distance: float) -> np.ndarray:
    """A camera pose looking at the origin from ``distance`` m, tilted up to 25 degrees."""
    tilt = Rotation.from_rotvec(np.radians(25) * rng.uniform(-1, 1, 3) * [1, 1, 0])
    R = tilt.as_matrix() @ np.diag([1.0, -1.0, -1.0])  # z down onto the target
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R[:, 2] * distance
    return T


# --------------------------------------------------------------------------- interaction matrix


def _trial_interaction(rng, index: int) -> Trial:
    n = int(rng.integers(1, 7))
    # Points in front of the camera, within a 90-degree field of view, 0.15 to 1.5 m away.
    Z = rng.uniform(0.15, 1.5, n)
    x, y = rng.uniform(-0.8, 0.8, n), rng.uniform(-0.6, 0.6, n)
    if index == 0:
        x[0], y[0] = 0.0, 0.0  # on the optical axis: the rotation terms' edge case
    P = np.column_stack([x * Z, y * Z, Z])
    h = 1e-6
    L = np.zeros((2 * n, 6))
    for k in range(6):
        e = np.zeros(6)
        e[k] = 1.0
        # The camera moves with body twist e, the points stay: they move by exp(-h e^) in it.
        plus = (_move(np.eye(4), -h * e, 1.0) @ np.c_[P, np.ones(n)].T).T[:, :3]
        minus = (_move(np.eye(4), h * e, 1.0) @ np.c_[P, np.ones(n)].T).T[:, :3]
        d = (plus[:, :2] / plus[:, 2:] - minus[:, :2] / minus[:, 2:]) / (2 * h)
        L[:, k] = d.reshape(-1)
    # Central differences with h = 1e-6 are good to about 1e-9 of the entries' scale.
    scale = float(np.abs(L).max())
    tol = 1e-6 * scale
    return Trial(args=(x, y, Z), truth=L, tol={"translation": tol, "rotation": tol},
                 label=f"{n} point{'s' if n > 1 else ''}")


# --------------------------------------------------------------------------- IBVS in closed loop


def _true_interaction(x, y, Z) -> np.ndarray:
    """The (2n, 6) point-feature interaction matrix, rows x1, y1, x2, ... (normalised image
    coordinates, depths Z in metres)."""
    L = np.zeros((len(x), 2, 6))
    L[:, 0, 0], L[:, 0, 2], L[:, 0, 3], L[:, 0, 4], L[:, 0, 5] = -1 / Z, x / Z, x * y, -(1 + x * x), y
    L[:, 1, 1], L[:, 1, 2], L[:, 1, 3], L[:, 1, 4], L[:, 1, 5] = -1 / Z, y / Z, 1 + y * y, -x * y, -x
    return L.reshape(-1, 6)


def _reference_ibvs(s, s_star, Z, gain):
    return -gain * np.linalg.pinv(_true_interaction(s[:, 0], s[:, 1], Z)) @ (s - s_star).reshape(-1)


def _trial_ibvs(rng, index: int) -> Trial:
    n = 4 + index % 3  # 4, 5 or 6 points: a square (chess-square corners) and extra points
    while True:  # redrawn only when the start lies outside IBVS's reach (see below)
        side = rng.uniform(0.05, 0.1)
        square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * side / 2
        extra = rng.uniform([-side, -side, 0.0], [side, side, 0.04], (n - 4, 3))
        pts = np.vstack([square, extra])
        goal = _look_at_pose(rng, rng.uniform(0.25, 0.5))
        # Start: translated by 3-8 cm and turned by 5-20 degrees about the target centre.
        axis, direction = rng.normal(size=3), rng.normal(size=3)
        angle = np.radians(rng.uniform(5, 20))
        orbit = np.eye(4)
        orbit[:3, :3] = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
        start = orbit @ goal
        start[:3, 3] += rng.uniform(0.03, 0.08) * direction / np.linalg.norm(direction)
        gain = float(rng.uniform(1.0, 2.5))
        # The law's twist at the start, computed as the closed loop computes its first
        # features, so the public drive compares the student's first twist without the law.
        s, Z = _features(start, pts)
        s_star, _ = _features(goal, pts)
        # A correct law reaches the goal to micrometres; the tolerance leaves room for any
        # sound variant (a different pseudo-inverse) and none for a law that stalls or diverges.
        trial = Trial(args=(), truth={"pts": pts, "start": start, "goal": goal, "gain": gain,
                                      "first_twist": _reference_ibvs(s, s_star, Z, gain)},
                      tol={"position": 0.1, "rotation": 0.01, "velocity": 1e-6},
                      label=f"{n} points, offset {np.degrees(angle):.0f} deg, gain {gain:.2f}")
        if _within_reach(trial):
            return trial


def _within_reach(trial: Trial) -> bool:
    """Whether the textbook law reaches the goal (to 0.01 mm and 0.001 deg) from this start.
    IBVS is a local method: a few starts drift into a local minimum, e.g. with four coplanar
    points the mirror pose of a small square, whose image is nearly the goal's (the fairness
    benchmark found a correct law stalled 243 mm and 28 deg off at an image error of
    0.0013). Correct code cannot do better there, so such starts are not graded. (One closed
    loop, ~5 ms a trial. Checking at other gains too, against starts on the edge of the basin
    where rounding decides the way, tripled the cost of grading a lab 3 submission; the
    fairness benchmark's ibvs_velocity row measures what the single check leaves.)"""
    reached = _drive_ibvs(lambda s, s_star, Z, gain: _reference_ibvs(s, s_star, Z, gain), trial)
    return reached["position"] < 0.01 and reached["rotation"] < 0.001


# --------------------------------------------------------------------------- piece position


_PIECE_R = 0.009   # m: the radius of a piece's round top


def _piece_scene(rng, h: int, w: int):
    """A camera and a piece on a board: (K, the board's normal ``n`` and a point ``c`` of
    it, the top of the piece, the centre of its sphere), in the camera frame, metres."""
    f = rng.uniform(280, 330)
    K = np.array([[f, 0, w / 2 - 0.5 + rng.uniform(-4, 4)],
                  [0, f, h / 2 - 0.5 + rng.uniform(-4, 4)], [0, 0, 1.0]])
    # The board plane: a point 0.2-0.5 m ahead, normal up to 15 degrees off the optical axis.
    n = Rotation.from_rotvec(np.radians(15) * rng.uniform(-1, 1, 3) * [1, 1, 0]).apply([0, 0, -1])
    c = np.array([0.0, 0.0, rng.uniform(0.2, 0.5)])
    # A pawn-like round top: a sphere of radius 9 mm whose centre is 25 mm above the board,
    # its top seen 0.2 to 0.3 (normalised) off the optical axis, as a piece away from the
    # image centre is. There the ray is 2 to 4.4 % longer than Z: a depth taken as the
    # distance along the ray (the mistake the lab's text warns of) is off by 3.3 mm or more,
    # beyond the tolerance; nearer the centre it hid within it on 4 draws of 30.
    height = 0.025 + _PIECE_R
    rho, phi = rng.uniform(0.2, 0.3), rng.uniform(0.0, 2.0 * np.pi)
    ray_top = np.array([rho * np.cos(phi), rho * np.sin(phi), 1.0])
    top = ray_top * (height + c @ n) / (ray_top @ n)  # on that ray, `height` above the plane
    return K, n, c, top, top - _PIECE_R * n


def _piece_depth(K, n, c, centre, h: int, w: int):
    """(the board's depth, the scene's depth) of every pixel, noiseless z-depth in m."""
    f = K[0, 0]
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(uu - K[0, 2]) / f, (vv - K[1, 2]) / f, np.ones_like(uu, float)], axis=-1)
    z_plane = (c @ n) / (rays @ n)
    # Ray-sphere intersection (nearest root) in z-depth: |z ray - centre|^2 = r^2.
    a = np.sum(rays ** 2, axis=-1)
    b = rays @ centre
    disc = b * b - a * (centre @ centre - _PIECE_R * _PIECE_R)
    z_sphere = np.where(disc >= 0, (b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
    return z_plane, np.minimum(z_plane, z_sphere)


def _spoil_window(rng, depth, z_plane, uv, hole: bool) -> None:
    """A hole in ``depth`` at the pixel ``uv``, or flying pixels on its 5x5 window's rim."""
    u0, v0 = np.rint(uv).astype(int)
    if hole:
        # A shiny top: no depth in the 3x3 pixels around the requested one.
        depth[v0 - 1:v0 + 2, u0 - 1:u0 + 2] = np.nan
        return
    # Flying pixels: two pixels on the window's rim read 0.1-0.3 m behind the board (the
    # mixed returns a depth camera gives at a piece's edge). The text's median of the
    # window ignores them; a mean of it is pulled by a centimetre or more, beyond the
    # tolerance. Not beside a hole, where the median has only the rim's 16 pixels: two
    # outliers there moved the reference to 1.08 of its tolerance in 60,000 problems;
    # here its worst of 18,000 stays at 0.79, as without them.
    rim = [(dv, du) for dv in range(-2, 3) for du in range(-2, 3)
           if max(abs(dv), abs(du)) == 2]
    for k in rng.choice(len(rim), 2, replace=False):
        dv, du = rim[k]
        depth[v0 + dv, u0 + du] = z_plane[v0 + dv, u0 + du] + rng.uniform(0.1, 0.3)


def _trial_piece(rng, index: int) -> Trial:
    h, w = 240, 320
    K, n, c, top, centre = _piece_scene(rng, h, w)
    f, r = K[0, 0], _PIECE_R
    z_plane, depth = _piece_depth(K, n, c, centre, h, w)
    sigma = rng.uniform(0.0005, 0.0015)
    depth = depth + rng.normal(0.0, sigma, depth.shape)
    depth[rng.random(depth.shape) < 0.03] = np.nan  # scattered dropouts, as on a RealSense
    uv = np.array([K[0, 0] * top[0] / top[2] + K[0, 2], K[1, 1] * top[1] / top[2] + K[1, 2]])
    hole = index % 2 == 1
    _spoil_window(rng, depth, z_plane, uv, hole)
    # Truth: the sphere's surface point on the ray through uv.
    ray = np.array([(uv[0] - K[0, 2]) / f, (uv[1] - K[1, 2]) / f, 1.0])
    bb, aa = ray @ centre, ray @ ray
    z = (bb - np.sqrt(bb * bb - aa * (centre @ centre - r * r))) / aa
    # mm: 1 mm, plus sigma for the noise (a 5x5 median carries about sigma / 4 of it), plus
    # the sphere's curvature across the window: the median of pixels d (m) from the top sits
    # d^2 / 2r deeper, d up to the window's corner, 2 sqrt(2) px = 2.83 z / f m. That term
    # matters with a hole at the pixel, where only the window's outer ring has depth: at
    # 0.47 m it is 1.2 mm. Without it a correct 5x5 median lost credit on 7 of 10,000 draws
    # (benchmarks/grading_fairness.py; worst 1.06 x a tolerance of 1 mm + sigma, all of them
    # holes beyond 0.44 m); with it the worst of 30,000 problems is 0.76 x.
    corner_m = 2.0 * math.sqrt(2.0) * z / f
    tol = 1.0 + 1000.0 * sigma + 1000.0 * corner_m ** 2 / (2.0 * r)
    return Trial(args=(depth.astype(float), uv, K), truth=ray * z, tol={"position": tol},
                 label=f"{1000 * sigma:.1f} mm noise" + (", hole at the pixel" if hole else ""))


# --------------------------------------------------------------------------- code mistakes


def _interaction_stacked(x, y, Z):
    L = _true_interaction(np.asarray(x, float), np.asarray(y, float), np.asarray(Z, float))
    return np.vstack([L[0::2], L[1::2]])


def _interaction_rotation_sign(x, y, Z):
    L = _true_interaction(np.asarray(x, float), np.asarray(y, float), np.asarray(Z, float))
    L[:, 3:] *= -1
    return L


def _interaction_no_depth(x, y, Z):
    x = np.asarray(x, float)
    return _true_interaction(x, np.asarray(y, float), np.ones_like(np.asarray(Z, float)))


def _interaction_z_for_inverse(x, y, Z):
    # -Z and x Z, y Z where -1/Z and x/Z, y/Z belong: the translation columns multiply by
    # the depth instead of dividing by it
    return _true_interaction(np.asarray(x, float), np.asarray(y, float),
                             1.0 / np.asarray(Z, float))


def _ibvs_lstsq(s, s_star, Z, gain):
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = _true_interaction(s[:, 0], s[:, 1], np.asarray(Z, float))
    return -gain * np.linalg.lstsq(L, (s - s_star).reshape(-1), rcond=None)[0]


def _ibvs_gain_flipped(s, s_star, Z, gain):
    return -_ibvs_lstsq(s, s_star, Z, gain)


def _ibvs_transpose(s, s_star, Z, gain):
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = _true_interaction(s[:, 0], s[:, 1], np.asarray(Z, float))
    return -gain * L.T @ (s - s_star).reshape(-1)


def _ibvs_no_gain(s, s_star, Z, gain):
    return _ibvs_lstsq(s, s_star, Z, 1.0)


def _ibvs_error_stacked(s, s_star, Z, gain):
    # e = (x1..xn, y1..yn) against L's rows in pairs (x1, y1, x2, y2, ...)
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = _true_interaction(s[:, 0], s[:, 1], np.asarray(Z, float))
    return -gain * np.linalg.pinv(L) @ (s - s_star).T.reshape(-1)


def _ibvs_desired_l(s, s_star, Z, gain):
    # L built at the desired features s* (with the current depths), not the current ones
    s, s_star = np.asarray(s, float), np.asarray(s_star, float)
    L = _true_interaction(s_star[:, 0], s_star[:, 1], np.asarray(Z, float))
    return -gain * np.linalg.pinv(L) @ (s - s_star).reshape(-1)


def _ibvs_degrees(s, s_star, Z, gain):
    v = _reference_ibvs(np.asarray(s, float), np.asarray(s_star, float), np.asarray(Z, float),
                        gain)
    return np.concatenate([v[:3], np.degrees(v[3:])])


def _ibvs_w_first(s, s_star, Z, gain):
    v = _reference_ibvs(np.asarray(s, float), np.asarray(s_star, float), np.asarray(Z, float),
                        gain)
    return np.concatenate([v[3:], v[:3]])


def _window_position(depth, uv, K, statistic=np.median, rows_are_u: bool = False):
    """The lab's method: ``statistic`` (the median) of the valid depths of the 5x5 window at
    round(uv), back-projected through uv; ValueError when the window has none. The mistakes
    below change the statistic, or read the window at depth[u, v] (``rows_are_u``)."""
    u, v = np.rint(np.asarray(uv, dtype=float)).astype(int)
    row, column = (u, v) if rows_are_u else (v, u)
    window = depth[max(row - 2, 0):row + 3, max(column - 2, 0):column + 3]
    valid = window[np.isfinite(window) & (window > 0)]
    if valid.size == 0:
        raise ValueError(f"no depth measurement within 2 px of pixel ({u}, {v})")
    Z = float(statistic(valid))
    return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])


def _window_median_position(depth, uv, K):
    return _window_position(depth, uv, K)


def _piece_pixel_only(depth, uv, K):
    u, v = np.rint(np.asarray(uv, float)).astype(int)
    Z = float(depth[v, u])
    return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])


def _piece_window_mean(depth, uv, K):
    return _window_position(depth, uv, K, statistic=np.mean)


def _piece_uv_swapped(depth, uv, K):
    return _window_median_position(depth, (uv[1], uv[0]), K)


def _piece_mm(depth, uv, K):
    return _window_median_position(depth, uv, K) * 1000.0


def _piece_ray_length(depth, uv, K):
    # the depth taken as the distance along the ray: p = d * ray / |ray|
    p = _window_median_position(depth, uv, K)
    return p * p[2] / np.linalg.norm(p)


def _piece_rows_columns(depth, uv, K):
    # the window read at depth[u, v] (u as the row); the back-projection keeps (u, v)
    return _window_position(depth, uv, K, rows_are_u=True)


INTERACTION_MISTAKES = (
    CodeMistake("its rows are stacked x1..xn, then y1..yn: the rows go in pairs, point by point "
                "(x1, y1, x2, y2, ...)", _interaction_stacked),
    CodeMistake("the rotation columns (wx, wy, wz) have the wrong sign: a point's x row is "
                "[-1/Z, 0, x/Z, x y, -(1 + x^2), y]", _interaction_rotation_sign),
    CodeMistake("the depth is ignored (Z = 1): the translation columns divide by each point's "
                "own depth Z", _interaction_no_depth),
    CodeMistake("Z is used where 1/Z belongs: the translation columns are -1/Z, x/Z and y/Z "
                "(a near point moves more), not -Z, x Z, y Z", _interaction_z_for_inverse),
)
IBVS_MISTAKES = (
    CodeMistake("the gain's sign is flipped: v = -gain pinv(L) (s - s*) drives the features "
                "towards s*; with +gain they run away", _ibvs_gain_flipped),
    CodeMistake("L^T is used for pinv(L): the law is v = -gain pinv(L) (s - s*)",
                _ibvs_transpose),
    CodeMistake("the gain is ignored: multiply the twist by -gain", _ibvs_no_gain),
    CodeMistake("the error vector is stacked x1..xn, y1..yn: L's rows go in pairs, point by "
                "point, so e = (s - s*).reshape(-1) = (x1, y1, x2, y2, ...)", _ibvs_error_stacked),
    CodeMistake("the angular velocity is in degrees per second: the twist is in m/s and rad/s "
                "(pinv(L) gives radians already)", _ibvs_degrees),
    CodeMistake("the twist is returned as (w, v): the order is (vx, vy, vz, wx, wy, wz), the "
                "linear velocity first, as L's columns", _ibvs_w_first),
    CodeMistake("L is built at the desired features s*: the law uses L at the current "
                "features s (and depths Z), recomputed every period", _ibvs_desired_l),
)
PIECE_MISTAKES = (
    CodeMistake("this is the depth of the one pixel: it has holes (NaN) and noise; take the "
                "median of the valid depths of the 5x5 window around it", _piece_pixel_only),
    CodeMistake("u and v are swapped: u is the column (x), v the row (y); the image is "
                "indexed depth[v, u]", _piece_uv_swapped),
    CodeMistake("the position is in millimetres: the depth image is in metres already, the "
                "course's unit", _piece_mm),
    CodeMistake("the depth was taken as the distance along the ray: it is the point's Z "
                "coordinate, so p = Z ((u - cx) / fx, (v - cy) / fy, 1), not Z times a unit ray",
                _piece_ray_length),
    CodeMistake("the depth image was read at depth[u, v]: numpy indexes the row first, so the "
                "pixel (u, v) is depth[v, u]", _piece_rows_columns),
    CodeMistake("the depth is the mean of the window: a few flying pixels (an edge's returns "
                "from far behind) pull a mean by centimetres; take the median of the valid "
                "depths", _piece_window_mean),
)

INTERACTION_MATRIX = replace(scoring.INTERACTION_MATRIX, make_trial=_trial_interaction,
                             code_mistakes=INTERACTION_MISTAKES, reference=_true_interaction)
IBVS_VELOCITY = replace(scoring.IBVS_VELOCITY, make_trial=_trial_ibvs,
                        code_mistakes=IBVS_MISTAKES)
PIECE_POSITION = replace(scoring.PIECE_POSITION, make_trial=_trial_piece,
                         code_mistakes=PIECE_MISTAKES, reference=_window_median_position)

SPECS = (INTERACTION_MATRIX, IBVS_VELOCITY, PIECE_POSITION)

# What computes a graded quantity (a truth, the reference law, a mistaken answer): never in a
# student's copy.
ANSWERS = (_true_interaction, _reference_ibvs, _within_reach, _trial_interaction, _trial_ibvs,
           _trial_piece, _interaction_stacked, _interaction_rotation_sign, _interaction_no_depth,
           _ibvs_lstsq, _ibvs_gain_flipped, _ibvs_transpose, _ibvs_no_gain,
           _window_median_position, _piece_pixel_only, _piece_uv_swapped, _piece_mm,
           _interaction_z_for_inverse, _ibvs_error_stacked, _ibvs_degrees, _ibvs_w_first,
           _ibvs_desired_l,
           _piece_ray_length, _piece_rows_columns)
