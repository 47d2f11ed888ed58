"""Lab 5 (depth camera and flange; rectangle pose), private side: problems, truths, tolerances
and the code mistakes.

The scoring is public, in :mod:`autograder.scoring.lab5_depth`; this module draws the
problems, computes their truths, and is never given to students. Every problem is what a
RealSense D4xx and a robot give, made small enough to grade in milliseconds:

* ``backproject``: Z16 depth images (integer units, int64) of a tilted table with a box on it, random
  intrinsics (fx != fy, principal point off centre, H != W) and random depth scales (0.001,
  0.0005, 0.00025, 0.0001 m per unit), holes as zeros;
* ``fit_plane_ransac``: the flange face seen at 0.3-0.5 m, depth noise sigma_z = k z^2 along
  the viewing rays, with outliers: the wrist housing 6.5 mm behind on one side, flying pixels
  between the two, and scattered points;
* ``fit_flange_circle``: points on partial arcs of the rim (edge dropouts), with the rim's
  pixel footprint (z / f) as in-plane noise and the depth noise along the rays;
* ``base_T_cam_from_flanges``: flange centres seen by a fixed camera over 6-20 robot poses,
  with the centre noise of the circle fit;
* ``rectangle_pose``: the corners of a 100 mm mark (and of other sizes, most not square)
  seen from random poses, with sub-pixel corner noise.

The tolerances follow from each problem's noise by first-order error propagation, times a
factor measured with the reference over 10,000 draws (the constants below say how).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.scoring import lab5_depth as scoring
from autograder.spec_types import CodeMistake, Trial
from robots import geometry as geo

# --------------------------------------------------------------------------- shared


def _random_K(rng, h: int, w: int, f_range=(200.0, 900.0)) -> np.ndarray:
    """Intrinsics with fx != fy (a few per cent) and the principal point off centre, so
    swapping u and v, or fx and fy, or inverting K shows."""
    fx = rng.uniform(*f_range)
    fy = fx * rng.uniform(0.95, 1.05)
    cx = (w - 1) / 2 + rng.uniform(-0.1, 0.1) * w
    cy = (h - 1) / 2 + rng.uniform(-0.1, 0.1) * h
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


# D4xx depth noise sigma_z = k z^2; k = subpixel / (f B): 0.00358 1/m for a D435 at 848 x 480
# (sim_backends/depth_noise.py), lower on a D415 and higher with a worse texture.
NOISE_K = (0.0025, 0.0045)


def _tilted_normal(rng, max_deg: float, min_deg: float = 0.0) -> np.ndarray:
    """A unit normal towards the camera (-z side), ``min_deg`` to ``max_deg`` off the optical
    axis, turned any way about it."""
    axis = rng.normal(size=3)
    axis[2] = 0.0
    axis /= np.linalg.norm(axis)
    return Rotation.from_rotvec(axis * math.radians(rng.uniform(min_deg, max_deg))).apply(
        [0, 0, -1.0])


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _depth_noise(rng, P: np.ndarray, k: float) -> np.ndarray:
    """Points moved along their viewing rays by depth noise sigma_z = k z^2 (as a stereo
    camera errs: in depth, not across)."""
    z = P[:, 2]
    dz = rng.normal(0.0, 1.0, len(P)) * k * z ** 2
    return P * ((z + dz) / z)[:, None]


# --------------------------------------------------------------------------- back-projection

DEPTH_SCALES = (0.001, 0.0005, 0.00025, 0.0001)


def _true_backproject(depth_raw, K, depth_scale) -> np.ndarray:
    z = depth_raw.astype(float) * depth_scale
    z[depth_raw == 0] = np.nan
    v, u = np.indices(z.shape)
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)


def _trial_backproject(rng, index: int) -> Trial:
    # Small images (the arithmetic is the same at 848 x 480), never square, so rows and
    # columns cannot be swapped unnoticed.
    h = int(rng.integers(24, 56))
    w = int(rng.integers(h + 8, 88))
    # A depth camera's field of view (D435: 87 deg wide, D415: 65 deg): 60-90 deg across
    # the image's width. With a narrow one (f of 200-900 px on 88 px) the rays are nearly
    # parallel, and depth taken as the ray's length would land within 0.2 % of the truth,
    # where a wrong answer near the truth would be named after it.
    f_lo, f_hi = (w / (2 * math.tan(math.radians(deg) / 2)) for deg in (90.0, 60.0))
    K = _random_K(rng, h, w, (f_lo, f_hi))
    scale = DEPTH_SCALES[index % len(DEPTH_SCALES)]
    # A table plane 0.3-2.5 m away, tilted up to 40 deg, with a box standing on it.
    n = _tilted_normal(rng, 40.0)
    c = np.array([0.0, 0.0, rng.uniform(0.3, 2.5)])
    v, u = np.indices((h, w))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)
    z = (c @ n) / (rays @ n)
    box = (abs(u - rng.uniform(0.3, 0.7) * w) < 0.15 * w) & (abs(v - rng.uniform(0.3, 0.7) * h)
                                                            < 0.15 * h)
    z[box] -= rng.uniform(0.03, 0.15)
    z = z + rng.normal(0.0, 1.0, z.shape) * rng.uniform(*NOISE_K) * z ** 2
    # Z16 values (0..65535), held as int64: the grader's wire format (autograder.inside.wire) sends
    # integer arrays as int64, so check(), the kernel and the sandbox all pass the same type.
    raw = np.clip(np.rint(z / scale), 1, 65535).astype(np.int64)
    # Holes as the sensor leaves them: scattered pixels, a dropout band along the box's
    # edge, and no depth at all on a corner patch (out of range, a shiny spot).
    holes = rng.random((h, w)) < rng.uniform(0.02, 0.1)
    edge = box ^ (np.roll(box, 1, axis=1) | np.roll(box, -1, axis=1))
    holes |= edge
    holes[:int(rng.integers(2, 8)), :int(rng.integers(2, 12))] = True
    raw[holes] = 0
    truth = _true_backproject(raw, K, scale)
    return Trial(args=(raw, K, scale), truth=truth, tol=dict(BACKPROJECT_TOL),
                 label=f"{h} x {w} image, depth scale {scale:g} m")


# Exact arithmetic: float64 lands within 1e-9 mm; float32 (the RealSense SDK hands out
# float32 metres) within |p| * a few eps32 = 2.5 m * 3 * 6e-8 = 5e-4 mm. 0.01 mm keeps both at
# full credit; each mistake is off by centimetres to kilometres, and a hole at z = 0 shows
# in the count of holes that are not NaN.
BACKPROJECT_TOL = {"points": 0.01, "holes": 0.5}

MM_WORDS = ("the depth is in sensor units (millimetres on a D435), not metres: multiply the "
            "raw depth by depth_scale")
UV_WORDS = ("u and v are swapped: u is the column (x), v the row (y); with np.indices the "
            "row index comes first")
K_INVERTED_WORDS = ("the intrinsics are applied the wrong way round: x = (u - cx) z / fx, not "
                    "(u - cx) z fx (pixels to metres divides by the focal length)")
HOLES_WORDS = ("the holes (raw == 0) are points at z = 0: set them to NaN, a missing "
               "measurement is not a point on the camera's centre")


DEPTH_SCALE_WORDS = ("depth_scale is taken as 0.001 m per unit: cameras differ (a D405 reports "
                     "0.0001); multiply by the depth_scale argument")


RAY_LENGTH_WORDS = ("the depth is taken as the length of the viewing ray: it is the z "
                    "coordinate, so p = z K^-1 [u, v, 1], not the unit ray times the depth")
INDEX_WORDS = ("the depth image is read as depth[u, v]: it is indexed depth[v, u] (row v, "
               "column u), and the points keep the image's (H, W) layout")


def _backproject_with(depth_raw, K, depth_scale, scale=None, swap=False, inverted=False,
                      holes_nan=True, ray_length=False) -> np.ndarray:
    """Back-projection with one of the classic mistakes switched on."""
    z = np.asarray(depth_raw, dtype=float) * (depth_scale if scale is None else scale)
    if holes_nan:
        z[np.asarray(depth_raw) == 0] = np.nan
    v, u = np.indices(z.shape)
    if swap:
        u, v = v, u
    fx, fy = (1 / K[0, 0], 1 / K[1, 1]) if inverted else (K[0, 0], K[1, 1])
    ray = np.stack([(u - K[0, 2]) / fx, (v - K[1, 2]) / fy, np.ones(z.shape)], axis=-1)
    if ray_length:
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    return ray * z[..., None]


def _backproject_units(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, scale=1.0)


def _backproject_fixed_scale(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, scale=0.001)


def _backproject_uv_swapped(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, swap=True)


def _backproject_k_inverted(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, inverted=True)


def _backproject_holes_at_zero(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, holes_nan=False)


def _backproject_ray_length(depth_raw, K, depth_scale):
    return _backproject_with(depth_raw, K, depth_scale, ray_length=True)


def _backproject_index_uv(depth_raw, K, depth_scale):
    """depth[u, v] for depth[v, u]: the image read column-first, (W, H, 3) points (a loop
    over u then v that indexes depth[u, v] gets the same, or an IndexError)."""
    return _backproject_with(np.asarray(depth_raw).T, K, depth_scale, swap=True)


BACKPROJECT_MISTAKES = (
    CodeMistake(MM_WORDS, _backproject_units),
    CodeMistake(DEPTH_SCALE_WORDS, _backproject_fixed_scale),
    CodeMistake(UV_WORDS, _backproject_uv_swapped),
    CodeMistake(K_INVERTED_WORDS, _backproject_k_inverted),
    CodeMistake(HOLES_WORDS, _backproject_holes_at_zero),
    CodeMistake(RAY_LENGTH_WORDS, _backproject_ray_length),
    CodeMistake(INDEX_WORDS, _backproject_index_uv),
)


# --------------------------------------------------------------------------- RANSAC plane


def _flange_scene(rng, min_tilt_deg: float = 0.0):
    """A flange face seen by a depth camera: (centre, normal towards the camera, radius,
    focal length px, noise k, e1, e2 in-plane axes); the face turned ``min_tilt_deg`` to 50
    deg from the optical axis."""
    f = rng.uniform(400.0, 900.0)
    radius = rng.choice(FLANGE_RADII)
    n = _tilted_normal(rng, 50.0, min_tilt_deg)
    centre = np.array([*rng.uniform(-0.08, 0.08, 2), rng.uniform(0.3, 0.5)])
    return centre, n, float(radius), f, rng.uniform(*NOISE_K), *_plane_basis(n)


# ISO 9409-1 outer radii (D / 2) of the sizes on cobots: 31.5 mm (ISO 50: Panda, UR, Aubo),
# 20 and 25 mm (small arms such as the Cobotta), 40 and 50 mm (heavier arms).
FLANGE_RADII = (0.02, 0.025, 0.0315, 0.04, 0.05)
HOUSING_BEHIND_M = 0.0065  # sim_backends.flanges.FLANGE_PROUD_M: the UR flange's step


def _on_rays(P: np.ndarray, e_n: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Points of the plane (c, e_n) on the rays through P (keeps their pixels)."""
    return P * ((c @ e_n) / (P @ e_n))[:, None]


# The plane problems' faces are turned at least this far from the optical axis: the
# normal's tolerance (2 atan(inlier_m / r), RANSAC's ambiguity) reaches 17 deg on a 40 mm face
# with a 3 mm band, so a face square to the camera would let the constant normal (0, 0, -1)
# pass; 20-50 deg keeps it beyond the tolerance on every problem.
PLANE_MIN_TILT_DEG = 20.0


def _trial_plane(rng, index: int) -> Trial:
    c, n, r, f, k, e1, e2 = _flange_scene(rng, PLANE_MIN_TILT_DEG)
    # The face: pixels on it, one point per (decimated) pixel: uniform over the disc.
    n_face = int(rng.integers(150, 320))
    rho = r * np.sqrt(rng.random(n_face))
    phi = rng.uniform(0, 2 * np.pi, n_face)
    face_true = c + np.outer(rho * np.cos(phi), e1) + np.outer(rho * np.sin(phi), e2)
    face = _depth_noise(rng, face_true, k)
    # The wrist housing 6.5 mm behind the face, seen on one side of it (a half annulus out to
    # 1.6 r): parallel, so it shifts a fit on all points and, being one-sided, tilts it.
    n_house = int(n_face * rng.uniform(0.1, 0.35))
    side = rng.uniform(0, 2 * np.pi)
    rho = r * rng.uniform(1.1, 1.6, n_house)
    phi = side + rng.uniform(-np.pi / 2, np.pi / 2, n_house)
    house = c - HOUSING_BEHIND_M * n + np.outer(rho * np.cos(phi), e1) + \
        np.outer(rho * np.sin(phi), e2)
    house = _depth_noise(rng, house, k)
    # Flying pixels on the rim: depth interpolated between the face and what lies behind
    # (the housing, or the floor 0.1-0.4 m further), on the face's outline.
    n_fly = int(n_face * rng.uniform(0.04, 0.12))
    phi = rng.uniform(0, 2 * np.pi, n_fly)
    rim = c + np.outer(r * np.cos(phi), e1) + np.outer(r * np.sin(phi), e2)
    fly = rim * (1 + rng.uniform(0.01, 0.3, n_fly) * rng.uniform(0.02, 0.4) / rim[:, 2])[:, None]
    # Scattered points (speckle, a cable): anywhere in a box around the face.
    n_far = int(n_face * rng.uniform(0.02, 0.08))
    far = c + rng.uniform(-2.5 * r, 2.5 * r, (n_far, 3)) * [1, 1, 2]
    pts = np.vstack([face, house, fly, far])
    pts = pts[rng.permutation(len(pts))]
    # The inlier threshold a student would choose: three sigma of the depth noise at the
    # face's depth (as the notebook's own call does), but never more than 3 mm, half the
    # housing's step, so the two surfaces stay apart.
    sigma = k * c[2] ** 2
    inlier_m = float(min(3.0 * sigma + 0.0002, 0.003))
    # 200 triples: with the face >= 45 % of the points, the chance that none of them is all
    # face is below (1 - 0.45^3)^200 = 1e-11.
    # 100 triples: with the face >= 60 % of the points, the chance that none of them is all
    # face is below (1 - 0.6^3)^100 = 3e-11.
    args = (pts, inlier_m, 100, int(rng.integers(0, 2**31)))
    truth_centre = face_true.mean(axis=0)
    # Tolerances from the noise, through the threshold it sets: RANSAC's consensus cannot
    # tell apart planes that stay within the band +-inlier_m over the face (radius r), so the
    # best triple's plane may be tilted by up to atan(inlier_m / r) and pick up housing or
    # flying pixels on one side before the refit; a refit on its inliers stays within the
    # band. Measured with the reference (one refit) over 10,000 draws: at most 1.1 x that
    # tilt and 0.42 x the band's offset; the plane through all the points is off by a
    # median 7.7 x the tilt and 1.4 x the band (benchmarks/grading_fairness.py).
    tilt_deg = math.degrees(math.atan(inlier_m / r))
    tol = {"normal": PLANE_TILT_FACTOR * tilt_deg, "offset": PLANE_BAND_FACTOR * 1000.0 * inlier_m}
    return Trial(args=args, truth=(truth_centre, n), tol=tol,
                 label=f"face at {c[2]:.2f} m, {len(pts) - n_face} outliers of {len(pts)}")


PLANE_TILT_FACTOR = 2.0
PLANE_BAND_FACTOR = 1.0

NO_RANSAC_WORDS = ("this is the least-squares plane through all the points: the outliers (the "
                   "housing behind the face, flying pixels) pull it; keep only the inliers of "
                   "the best RANSAC plane before the refit")
AWAY_WORDS = ("the normal points away from the camera: flip it when normal @ centre > 0 (the "
              "camera is at the origin)")


UNCENTRED_WORDS = ("the plane's normal comes from the SVD of the points themselves, not "
                   "centred: subtract their mean first (the smallest singular vector of "
                   "uncentred points far from the camera is no normal of their plane)")


def _svd_plane(pts: np.ndarray, centred: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(mean, unit normal towards the camera) of ``pts`` by the SVD; ``centred=False`` is
    the mistake of decomposing the points as they are."""
    centre = pts.mean(axis=0)
    normal = np.linalg.svd(pts - centre if centred else pts, full_matrices=False)[2][2]
    return centre, (-normal if normal @ centre > 0 else normal)


def _ransac_plane(points, inlier_m, iterations=500, seed=0,
                  centred: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The lab's RANSAC: the plane of the random triple with the most inliers, refitted (SVD)
    on them, its normal towards the camera (``centred=False``: the refit's mistake)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(iterations):
        a, b, c = pts[rng.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        inliers = np.abs((pts - a) @ (n / np.linalg.norm(n))) < inlier_m
        if best is None or inliers.sum() > best.sum():
            best = inliers
    return _svd_plane(pts[best], centred)


def _plane_all_points(points, inlier_m, iterations=500, seed=0):
    return _svd_plane(np.asarray(points, dtype=float).reshape(-1, 3))


def _plane_normal_away(points, inlier_m, iterations=500, seed=0):
    centre, normal = _ransac_plane(points, inlier_m, iterations, seed)
    return centre, -normal


def _plane_uncentred(points, inlier_m, iterations=500, seed=0):
    return _ransac_plane(points, inlier_m, iterations, seed, centred=False)


PLANE_MISTAKES = (
    CodeMistake(NO_RANSAC_WORDS, _plane_all_points),
    CodeMistake(AWAY_WORDS, _plane_normal_away),
    CodeMistake(UNCENTRED_WORDS, _plane_uncentred),
)


# --------------------------------------------------------------------------- flange circle


def _arc_angles(rng, step: float) -> tuple[np.ndarray, float]:
    """Angles (rad) of rim points ``step`` rad apart on average along one arc of 90-150 deg:
    the rest of the rim lost to edge dropouts (where the face meets the housing's step, or
    turns to a grazing angle). Returns (angles, the arc's span).

    Why that range (3,000 problems each, the reference's worst error / its tolerance, and how
    often the unrefined algebraic fit is beyond it): 90-200 deg: 0.66, 12 %; 90-150 deg: 0.67,
    21 %; 60-150 deg: 2.2, 40 %. Below 90 deg the first-order tolerance no longer holds for
    correct code, so the arcs stop there; the shorter upper end makes the mistake show on one
    problem in five instead of one in eight."""
    total = math.radians(rng.uniform(90.0, 150.0))
    n = max(40, int(total / step))
    return rng.uniform(0, 2 * np.pi) + rng.random(n) * total, total


def _draw_circle(rng) -> tuple[Trial, float]:
    """One rim problem and the sd (rad) of its rim plane's tilt."""
    c, n, r, f, k, e1, e2 = _flange_scene(rng)
    # One rim point per pixel of the outline, whose footprint on the face is z / f: the
    # outline pixels sit anywhere within one footprint of the true rim (uniform: the edge
    # falls anywhere in a pixel, and the dropouts either side of a depth edge move it by a
    # pixel), plus half a footprint of jitter (flying pixels).
    footprint = c[2] / f
    phi, total = _arc_angles(rng, footprint / r)
    rho = r + (rng.uniform(-1.0, 1.0, len(phi)) + rng.normal(0.0, 0.5, len(phi))) * footprint
    rim = c + np.outer(rho * np.cos(phi), e1) + np.outer(rho * np.sin(phi), e2)
    rim = _depth_noise(rng, rim, k)
    # Tolerances, first order. In the plane a rim point errs radially by
    # sigma_r^2 = footprint^2 (1/3 + 1/4) + (sigma_z sin(theta))^2 (theta: the face's tilt,
    # the depth noise along the ray leaning into the plane); a circle of KNOWN radius fitted
    # to points at angles phi_i has the centre covariance sigma_r^2 (J^T J)^-1,
    # J_i = (cos phi_i, sin phi_i). The rim's plane (SVD) errs by sigma_n / sqrt(N) along
    # the normal (sigma_n = sigma_z cos(theta)) and tilts by sigma_n / sqrt(lambda_min(S)),
    # S the rim's in-plane scatter, which moves the centre, r away from the arc, by r times
    # the tilt. CIRCLE_FACTOR: over 3,000 problems the reference's in-plane error reached
    # 2.9 sd; 5.5 sd keeps the problems of 10,000 draws (a 2-D normal beyond 5.5 sd:
    # p < 1e-6 per problem; 480,000 problems at 48 a draw) while the unrefined algebraic fit,
    # whose centre and radius trade off along a short arc, is beyond it on 21 % of problems.
    sigma_z = k * c[2] ** 2
    sin_t = math.sqrt(max(0.0, 1.0 - n[2] ** 2))
    sigma_r = math.sqrt(footprint ** 2 * (1 / 3 + 1 / 4) + (sigma_z * sin_t) ** 2)
    sigma_n = sigma_z * abs(n[2])
    J = np.column_stack([np.cos(phi), np.sin(phi)])
    in_plane = math.sqrt(np.trace(np.linalg.inv(J.T @ J))) * sigma_r
    xy = np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])
    xy -= xy.mean(axis=0)
    tilt = sigma_n / math.sqrt(np.linalg.eigvalsh(xy.T @ xy)[0])
    tol = {"centre": CIRCLE_FACTOR * 1000.0 * in_plane,
           "depth": TILT_FACTOR * 1000.0 * (sigma_n / math.sqrt(len(phi)) + r * tilt),
           "normal": TILT_FACTOR * math.degrees(tilt) + 0.01}
    return Trial(args=(rim, r), truth=(c, n), tol=tol,
                 label=f"r {1000 * r:.1f} mm at {c[2]:.2f} m, {math.degrees(total):.0f} deg of "
                       "the rim"), tilt



# A rim whose own plane is uncertain by more than this (sd, deg) is drawn again. Its plane,
# and with it the centre, is then off by second-order amounts (r (1 - cos tilt)) that the
# first-order tolerance does not bound: at 10,000 draws (480,000 problems) two such rims
# (r 20 mm, 0.5 m away, 95 deg of arc: the plane 18-29 deg off) cost the reference credit.
# The lab never hands fit_flange_circle such a rim: its rim points lie on the face's plane,
# fitted to thousands of points. About 4 % of rims are redrawn.
MAX_RIM_TILT_SD_DEG = 2.0


def _trial_circle(rng, index: int) -> Trial:
    while True:
        trial, tilt = _draw_circle(rng)
        if math.degrees(tilt) <= MAX_RIM_TILT_SD_DEG:
            return trial


CIRCLE_FACTOR = 5.5
TILT_FACTOR = 6.0

KASA_WORDS = ("this is the algebraic (Kasa) circle fit left unrefined: on a partial arc it is "
              "biased; refine the centre by least squares on |p - c| - r with the radius "
              "known")


def _kasa(rim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The plane of the rim and the algebraic circle fit in it, unrefined (the mistake)."""
    c0, n = _svd_plane(rim)
    e1, e2 = _plane_basis(n)
    xy = np.column_stack([(rim - c0) @ e1, (rim - c0) @ e2])
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    sol = np.linalg.lstsq(A, (xy ** 2).sum(axis=1), rcond=None)[0]
    return c0 + sol[0] * e1 + sol[1] * e2, n


def _refined_circle(rim_points, radius_m, centred: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The lab's fit: the algebraic circle in the rim's plane, refined by Gauss-Newton on
    |p - c| - r with the radius known (``centred=False``: the rim's plane by the SVD of the
    uncentred points, the mistake)."""
    rim = np.asarray(rim_points, dtype=float)
    c0, n = _svd_plane(rim, centred)
    e1, e2 = _plane_basis(n)
    xy = np.column_stack([(rim - c0) @ e1, (rim - c0) @ e2])
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    centre = np.linalg.lstsq(A, (xy ** 2).sum(axis=1), rcond=None)[0][:2]
    for _ in range(50):
        d = xy - centre
        dist = np.linalg.norm(d, axis=1)
        step = np.linalg.lstsq(-d / dist[:, None], dist - radius_m, rcond=None)[0]
        centre = centre - step
        if np.linalg.norm(step) < 1e-12:
            break
    return c0 + centre[0] * e1 + centre[1] * e2, n


def _circle_unrefined(rim_points, radius_m):
    return _kasa(np.asarray(rim_points, dtype=float))


def _circle_normal_away(rim_points, radius_m):
    centre, normal = _refined_circle(rim_points, radius_m)
    return centre, -normal


CENTROID_WORDS = ("the centre is the centroid of the rim points: on a partial arc their mean "
                  "lies inside the circle, towards the arc (0.7-0.9 r from the centre on "
                  "90-150 deg of rim); fit the circle of the known radius to them")
DIAMETER_WORDS = ("the circle was fitted with the diameter as its radius: radius_m is half "
                  "the ISO 9409-1 outer diameter D, the circle has |p - c| = radius_m")


def _circle_centroid(rim_points, radius_m):
    return _svd_plane(np.asarray(rim_points, dtype=float))


def _circle_diameter(rim_points, radius_m):
    return _refined_circle(rim_points, 2.0 * radius_m)


def _circle_uncentred(rim_points, radius_m):
    return _refined_circle(rim_points, radius_m, centred=False)


# The algebraic fit comes before the centroid. Naming (checks) takes the first prediction an
# answer lies within 2 % of (about 21 mm on a centre 0.4 m away with its unit normal), and on
# 20-25 mm flanges the centroid lies within that of the algebraic centre. The algebraic fit
# is a prediction only where it fails (one problem in five), the centroid on every problem:
# in this order about one centroid answer in ten is named the algebraic fit (on 10 x 48
# problems: 48 of 480), in the other most algebraic answers on small flanges would be named
# the centroid. Only naming the nearest prediction (checks) removes the overlap.
CIRCLE_MISTAKES = (
    CodeMistake(KASA_WORDS, _circle_unrefined),
    CodeMistake(CENTROID_WORDS, _circle_centroid),
    CodeMistake(AWAY_WORDS, _circle_normal_away),
    CodeMistake(DIAMETER_WORDS, _circle_diameter),
    CodeMistake(UNCENTRED_WORDS, _circle_uncentred),
)


# --------------------------------------------------------------------------- registration


def _trial_registration(rng, index: int) -> Trial:
    # A fixed camera 0.6-1.5 m from the robot's work area, looking at it.
    n_poses = int(rng.integers(6, 21))
    work = np.array([rng.uniform(0.3, 0.6), rng.uniform(-0.3, 0.3), rng.uniform(0.1, 0.5)])
    cam_pos = work + Rotation.random(random_state=rng).apply([0, 0, 1.0]) * [1, 1, 0.5] \
        * rng.uniform(0.6, 1.5)
    z_axis = (work - cam_pos) / np.linalg.norm(work - cam_pos)
    x_axis = np.cross(z_axis, rng.normal(size=3))
    x_axis /= np.linalg.norm(x_axis)
    base_T_cam = geo.make_pose(np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis]),
                               cam_pos)
    # Flange poses spread over a 0.2-0.5 m box, each turned to face the camera roughly.
    spread = rng.uniform(0.1, 0.25)
    base_T_flanges = np.array([geo.make_pose(
        Rotation.random(random_state=rng).as_matrix(),
        work + rng.uniform(-spread, spread, 3)) for _ in range(n_poses)])
    cam_true = geo.transform_points(geo.invert(base_T_cam), base_T_flanges[:, :3, 3])
    # The circle fit's centre noise: about 0.2-1.5 mm per axis in plane, more in depth.
    sigma = rng.uniform(0.0002, 0.0015)
    noise_sd = sigma * np.array([1.0, 1.0, rng.uniform(1.0, 3.0)])
    cam = cam_true + rng.normal(0.0, 1.0, cam_true.shape) * noise_sd
    # Tolerances, first order for the Kabsch fit with noise only on the camera side: the
    # rotation's covariance is sigma^2 (tr(S) I - S)^-1 (S: scatter of the centred camera
    # points); the translation t = c_base - R c_cam errs by sigma / sqrt(N) plus the rotation
    # error times |c_cam| (the lever from the camera to the points). sigma: the largest
    # axis's. Factor measured with the reference over 10,000 draws (REGISTRATION_FACTOR).
    s_max = float(noise_sd.max())
    a = cam_true - cam_true.mean(axis=0)
    S = a.T @ a
    rot_sd = s_max * math.sqrt(np.trace(np.linalg.inv(np.trace(S) * np.eye(3) - S)))
    lever = float(np.linalg.norm(cam_true.mean(axis=0)))
    tol = {"rotation": REGISTRATION_FACTOR * math.degrees(rot_sd),
           "translation": REGISTRATION_FACTOR * 1000.0 * (s_max * math.sqrt(3 / n_poses)
                                                          + rot_sd * lever)}
    return Trial(args=(cam, base_T_flanges), truth=base_T_cam, tol=tol,
                 label=f"{n_poses} poses, {1000 * sigma:.1f} mm centre noise")


REGISTRATION_FACTOR = 6.0

INVERSE_WORDS = ("this is cam_T_base, the inverse of base_T_cam: the fit maps camera points "
                 "onto base points (base_p = R cam_p + t)")
RT_WORDS = ("its rotation is R^T: the cross-covariance was built the other way round "
            "(sum (base_i - c_base)(cam_i - c_cam)^T); R = V U^T of H = sum (cam_i - c_cam)"
            "(base_i - c_base)^T")


UNCENTRED_H_WORDS = ("the cross-covariance is built from uncentred points: H = sum (cam_i - "
                     "c_cam)(base_i - c_base)^T, with both centroids subtracted first")


def _register(cam_centres, base_T_flanges, base_first: bool = False,
              centred: bool = True) -> np.ndarray:
    """base_T_cam by the SVD of the centres' cross-covariance (the lab's fit); with
    ``base_first`` the covariance built the other way round, which gives R^T, with
    ``centred=False`` built from the points as they are (the mistakes)."""
    a = np.asarray(cam_centres, dtype=float)
    b = np.asarray(base_T_flanges, dtype=float)[:, :3, 3]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    da, db = (a - ca, b - cb) if centred else (a, b)
    H = db.T @ da if base_first else da.T @ db
    U, _, Vt = np.linalg.svd(H)
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T


def _registration_inverse(cam_centres, base_T_flanges):
    return geo.invert(_register(cam_centres, base_T_flanges))


def _registration_rt(cam_centres, base_T_flanges):
    return _register(cam_centres, base_T_flanges, base_first=True)


def _registration_uncentred(cam_centres, base_T_flanges):
    return _register(cam_centres, base_T_flanges, centred=False)


REGISTRATION_MISTAKES = (
    CodeMistake(INVERSE_WORDS, _registration_inverse),
    CodeMistake(RT_WORDS, _registration_rt),
    CodeMistake(UNCENTRED_H_WORDS, _registration_uncentred),
)


# --------------------------------------------------------------------------- rectangle pose

# The chapter's mark is 100 mm x 100 mm; other marks, most of them not square, so that width
# and height cannot be swapped unnoticed (on a square they are the same).
RECTANGLES = ((0.1, 0.1), (0.1, 0.15), (0.15, 0.1), (0.08, 0.12), (0.21, 0.297), (0.12, 0.06))


def _draw_rectangle(rng, index: int) -> tuple[Trial, float]:
    """One rectangle problem and the first-order sd (rad) of its rotation."""
    width, height = RECTANGLES[index % len(RECTANGLES)]
    K = _random_K(rng, 480, 640, (450.0, 1000.0))
    # The mark 0.25-1.2 m ahead, its normal (z, into the mark) up to 55 deg off the optical
    # axis, turned any way in its plane, its centre within the middle of the image.
    dist = rng.uniform(0.25, 1.2)
    axis = rng.normal(size=3)
    axis[2] = 0.0
    axis /= np.linalg.norm(axis)
    R = (Rotation.from_rotvec(axis * math.radians(rng.uniform(0, 55.0)))
         * Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)])).as_matrix()
    t = np.array([*rng.uniform(-0.15, 0.15, 2) * dist, dist])
    cam_T_rect = geo.make_pose(R, t)
    w, h = width / 2, height / 2
    corners = np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])
    p = geo.transform_points(cam_T_rect, corners)
    uv = (p[:, :2] / p[:, 2:]) * [K[0, 0], K[1, 1]] + K[:2, 2]
    sigma_px = rng.uniform(0.05, 0.3)
    uv = uv + rng.normal(0.0, sigma_px, uv.shape)
    # Tolerances, first order: the pose's sensitivity to the corners, J (6 x 8) by central
    # differences of the solution at the true corners (shape constraint and homography
    # decomposition, the larger), gives the covariance
    # sigma_px^2 J J^T of the rotation vector and the translation; the tolerance is
    # RECTANGLE_FACTOR times the square root of its trace (rotation) and of its translation
    # block's trace. Measured with the reference over 10,000 draws (RECTANGLE_FACTOR).
    clean = (p[:, :2] / p[:, 2:]) * [K[0, 0], K[1, 1]] + K[:2, 2]
    rot_sd, trans_sd = _rectangle_sd(clean, width, height, K, sigma_px)
    tol = {"rotation": RECTANGLE_FACTOR * math.degrees(rot_sd),
           "translation": RECTANGLE_FACTOR * 1000.0 * trans_sd}
    return Trial(args=(uv, width, height, K), truth=cam_T_rect, tol=tol,
                 label=f"{1000 * width:.0f} x {1000 * height:.0f} mm mark at {dist:.2f} m, "
                       f"{sigma_px:.2f} px corner noise"), rot_sd



# A view whose rotation is uncertain by more than this (first-order sd, deg) is drawn again:
# a small mark far away (120 x 60 mm at 1.2 m: sd 7.5 deg, a rotation tolerance of 60 deg) is
# beyond the first-order model, and at 10,000 draws two such views cost correct code credit
# (an error 1.09 x its tolerance). Over 2,000 views 22 % are redrawn and the reference's
# worst error on the rest is 0.45 of its tolerance. The lab's figure shows how the shape
# constraint degrades with distance; the grade judges views where a pose can be told.
MAX_RECT_ROT_SD_DEG = 3.0


def _trial_rectangle(rng, index: int) -> Trial:
    while True:
        trial, rot_sd = _draw_rectangle(rng, index)
        if math.degrees(rot_sd) <= MAX_RECT_ROT_SD_DEG:
            return trial


RECTANGLE_FACTOR = 8.0


def _vanishing_directions(corners_px, K, signed: bool = True):
    """(the corners' rays (4, 3), the unit directions of the rectangle's x and y sides in
    the camera frame, from the vanishing points of its opposite sides, signed along the
    corner order 0 -> 1 and 0 -> 3; ``signed=False``: as the cross products give them, the
    mistake the lab's text warns of)."""
    h = np.column_stack([corners_px, np.ones(4)]) @ np.linalg.inv(K).T
    dx = np.cross(np.cross(h[0], h[1]), np.cross(h[3], h[2]))
    dy = np.cross(np.cross(h[0], h[3]), np.cross(h[1], h[2]))
    if signed:
        dx = dx * (np.sign(dx[:2] @ (h[1, :2] - h[0, :2])) or 1.0)
        dy = dy * (np.sign(dy[:2] @ (h[3, :2] - h[0, :2])) or 1.0)
    return h, dx / np.linalg.norm(dx), dy / np.linalg.norm(dy)


def _shape_pose(corners_px, width_m, height_m, K, signed: bool = True) -> np.ndarray:
    """cam_T_rect by the shape constraint (vanishing points, nearest rotation, rays)."""
    h, dx, dy = _vanishing_directions(corners_px, K, signed)
    U, _, Vt = np.linalg.svd(np.column_stack([dx, dy, np.cross(dx, dy)]))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    w, hh = width_m / 2, height_m / 2
    P = np.array([[-w, -hh, 0.0], [w, -hh, 0.0], [w, hh, 0.0], [-w, hh, 0.0]])
    A = np.vstack([geo.skew(x) for x in h])
    b = np.concatenate([-geo.skew(x) @ (R @ p) for x, p in zip(h, P)])
    return geo.make_pose(R, np.linalg.lstsq(A, b, rcond=None)[0])


def _homography_pose(corners_px, width_m, height_m, K) -> np.ndarray:
    """cam_T_rect by the plane-to-image homography (DLT), decomposed and orthogonalised: the
    other accepted method, less accurate in translation (its scale comes from two columns)."""
    w, h = width_m / 2, height_m / 2
    rows = []
    for (X, Y), (u, v) in zip([(-w, -h), (w, -h), (w, h), (-w, h)], corners_px):
        rows += [[X, Y, 1, 0, 0, 0, -u * X, -u * Y, -u], [0, 0, 0, X, Y, 1, -v * X, -v * Y, -v]]
    M = np.linalg.inv(K) @ np.linalg.svd(np.array(rows))[2][-1].reshape(3, 3)
    M /= (np.linalg.norm(M[:, 0]) + np.linalg.norm(M[:, 1])) / 2 * np.sign(M[2, 2])
    U, _, Vt = np.linalg.svd(np.column_stack([M[:, 0], M[:, 1], np.cross(M[:, 0], M[:, 1])]))
    return geo.make_pose(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, M[:, 2])


def _rectangle_sd(corners, width, height, K, sigma_px) -> tuple[float, float]:
    """(rotation sd rad, translation sd m): the larger of the two accepted methods'."""
    return tuple(max(pair) for pair in zip(*(
        _method_sd(method, corners, width, height, K, sigma_px)
        for method in (_shape_pose, _homography_pose))))


def _method_sd(method, corners, width, height, K, sigma_px) -> tuple[float, float]:
    base = method(corners, width, height, K)
    J = np.zeros((6, 8))
    step = 1e-3
    for i in range(8):
        d = np.zeros(8)
        d[i] = step
        plus = method(corners + d.reshape(4, 2), width, height, K)
        minus = method(corners - d.reshape(4, 2), width, height, K)
        J[:3, i] = (Rotation.from_matrix(base[:3, :3].T @ plus[:3, :3]).as_rotvec()
                    - Rotation.from_matrix(base[:3, :3].T @ minus[:3, :3]).as_rotvec()) / (2 * step)
        J[3:, i] = (plus[:3, 3] - minus[:3, 3]) / (2 * step)
    C = sigma_px ** 2 * J @ J.T
    return math.sqrt(np.trace(C[:3, :3])), math.sqrt(np.trace(C[3:, 3:]))


SWAPPED_WORDS = ("width and height are swapped: width_m is the top edge's length (x, TL to TR), "
                 "height_m the left edge's (y, TL to BL)")


K_IGNORED_WORDS = ("K was not applied: pixels are not rays; turn the corners into rays with "
                   "K^-1 [u, v, 1] first")
NOT_ORTHOGONAL_WORDS = ("its rotation is not orthogonal: the vanishing directions dx, dy were "
                        "used as they are; replace [dx, dy, dx x dy] by the nearest rotation "
                        "(SVD)")

UNSIGNED_WORDS = ("the vanishing directions' signs were not chosen: d and -d are the same "
                  "vanishing point, so the pose can turn 180 degrees; point dx along the top "
                  "edge (corner 0 -> 1) and dy along the left edge (corner 0 -> 3)")


def _rectangle_swapped(corners_px, width_m, height_m, K):
    return _shape_pose(corners_px, height_m, width_m, K)


def _rectangle_k_ignored(corners_px, width_m, height_m, K):
    return _shape_pose(corners_px, width_m, height_m, np.eye(3))


def _rectangle_unsigned(corners_px, width_m, height_m, K):
    return _shape_pose(corners_px, width_m, height_m, K, signed=False)


def _rectangle_not_orthogonal(corners_px, width_m, height_m, K):
    _, dx, dy = _vanishing_directions(corners_px, K)
    T = _shape_pose(corners_px, width_m, height_m, K)
    T[:3, :3] = np.column_stack([dx, dy, np.cross(dx, dy)])
    return T


RECTANGLE_MISTAKES = (
    CodeMistake(SWAPPED_WORDS, _rectangle_swapped),
    CodeMistake(K_IGNORED_WORDS, _rectangle_k_ignored),
    CodeMistake(NOT_ORTHOGONAL_WORDS, _rectangle_not_orthogonal),
    CodeMistake(UNSIGNED_WORDS, _rectangle_unsigned),
)


BACKPROJECT = replace(scoring.BACKPROJECT, make_trial=_trial_backproject,
                      code_mistakes=BACKPROJECT_MISTAKES, reference=_true_backproject)
FIT_PLANE_RANSAC = replace(scoring.FIT_PLANE_RANSAC, make_trial=_trial_plane,
                           code_mistakes=PLANE_MISTAKES, reference=_ransac_plane)
FIT_FLANGE_CIRCLE = replace(scoring.FIT_FLANGE_CIRCLE, make_trial=_trial_circle,
                            code_mistakes=CIRCLE_MISTAKES, reference=_refined_circle)
BASE_T_CAM_FROM_FLANGES = replace(scoring.BASE_T_CAM_FROM_FLANGES,
                                  make_trial=_trial_registration,
                                  code_mistakes=REGISTRATION_MISTAKES, reference=_register)
RECTANGLE_POSE = replace(scoring.RECTANGLE_POSE, make_trial=_trial_rectangle,
                         code_mistakes=RECTANGLE_MISTAKES, reference=_shape_pose)

SPECS = (BACKPROJECT, FIT_PLANE_RANSAC, FIT_FLANGE_CIRCLE, BASE_T_CAM_FROM_FLANGES,
         RECTANGLE_POSE)

# What computes a graded quantity (a truth, a solution, a mistaken answer): never in a
# student's copy.
ANSWERS = (_true_backproject, _trial_backproject, _backproject_with, _backproject_units,
           _backproject_fixed_scale, _backproject_uv_swapped, _backproject_k_inverted,
           _backproject_holes_at_zero, _backproject_ray_length, _backproject_index_uv,
           _trial_plane, _svd_plane, _ransac_plane, _plane_all_points, _plane_normal_away,
           _plane_uncentred, _trial_circle, _kasa, _refined_circle, _circle_unrefined,
           _circle_normal_away, _circle_centroid, _circle_diameter, _circle_uncentred,
           _trial_registration, _register, _registration_inverse, _registration_rt,
           _registration_uncentred, _trial_rectangle, _shape_pose,
           _homography_pose, _rectangle_sd, _method_sd, _rectangle_swapped,
           _rectangle_k_ignored, _rectangle_not_orthogonal, _vanishing_directions)
