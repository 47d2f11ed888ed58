"""Lab 5 plumbing: the depth image as a RealSense streams it, the view plan that holds the bare
flange in front of the camera, the region around the flange, the face's rim, the capture loop,
the rectangle mark's corners, and the figures.

Nothing here is graded: the pipeline takes the student's functions (``backproject``,
``fit_plane_ransac``, ``fit_flange_circle``) as arguments. Camera optical frame (x right, y
down, z forward), metres, ``a_T_b`` poses, pixel ``(u, v)`` = (column, row).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from robots import geometry as geo
from robots.interfaces import SafetyError, UnreachableError

__all__ = ["FlangeView", "FlangeCapture", "to_z16", "flange_goals", "flange_region",
           "face_mask", "nearest_plane", "face_plane", "rim_points", "measure_flange",
           "capture_flange_centres",
           "find_rectangle_corners", "true_rectangle_pose", "true_cam_centre", "show_depth",
           "show_face", "show_rim", "show_centre_errors", "show_rectangle",
           "load_depth_vs_board", "show_depth_vs_board", "as_capture"]

# How far from the camera each simulated arm holds its flange (m): near enough for
# millimetre depth (the D435's noise is 0.9 mm at 0.5 m, 2.3 mm at 0.8 m) and within reach.
FLANGE_DISTANCE = {"ur10e": (0.7, 0.85), "cobotta": (0.3, 0.45)}

# The flange face, seen from the camera: +z of the flange frame points back at the lens.
_FACING = np.diag([1.0, -1.0, -1.0])


# --------------------------------------------------------------------------- the sensor


def to_z16(depth_m, depth_scale: float) -> np.ndarray:
    """The depth image as the sensor streams it (RealSense Z16): unsigned 16-bit integers in
    units of ``depth_scale`` metres, 0 where there is no measurement.

    ``depth_m`` (H, W) float metres with NaN for no data, as ``camera.capture().depth`` gives
    it (the driver and the simulator both convert ``raw * depth_scale``; this undoes it)."""
    depth = np.asarray(depth_m, dtype=float)
    ok = np.isfinite(depth) & (depth > 0)
    raw = np.zeros(depth.shape, dtype=np.uint16)
    raw[ok] = np.clip(np.rint(depth[ok] / float(depth_scale)), 1, 65535).astype(np.uint16)
    return raw


# --------------------------------------------------------------------------- view plan


def flange_goals(cell, rng: np.random.Generator, n: int, distance=None,
                 max_tilt_deg: float = 25.0, spread: float = 0.12, roll_deg: float = 30.0):
    """``n`` flange poses (base_T_flange) that hold the bare flange ``distance`` metres in
    front of the camera, its face turned towards the lens within ``max_tilt_deg`` degrees,
    within ``spread`` * distance of the optical axis. The roll about the flange axis is the
    one nearest the arm's current flange pose (read when the next pose is asked for) give or
    take ``roll_deg`` degrees, so no single move turns the wrist by more than the Safety
    layer allows.

    Sim only: aims with the truth (where the camera is), as you would aim by jogging a real
    arm until the flange fills the middle of the depth image. ``distance`` (near, far) m:
    by default :data:`FLANGE_DISTANCE` for the arm (the simulated cell grows with the arm's
    reach, so the UR10e's camera stands farther away, and the Cobotta's nearer)."""
    if distance is None:
        distance = FLANGE_DISTANCE.get(cell.robot.name, (0.35, 0.55))
    base_T_cam = cell.truth.base_T_cam
    for _ in range(n):
        d = rng.uniform(*distance)
        axis = rng.normal(size=2)
        axis /= np.linalg.norm(axis)
        tilt = np.deg2rad(max_tilt_deg) * np.sqrt(rng.uniform())
        R = (base_T_cam[:3, :3] @ geo.pose_from_rotvec(np.r_[tilt * axis, 0.0])[:3, :3]
             @ _FACING)
        # Roll about the flange z axis: the angle that best matches the current x axis.
        x_now = R.T @ cell.robot.flange_pose()[:3, 0]
        roll = np.arctan2(x_now[1], x_now[0]) + np.deg2rad(roll_deg) * rng.uniform(-1, 1)
        R = R @ geo.pose_from_rotvec([0.0, 0.0, roll])[:3, :3]
        t = geo.transform_points(base_T_cam, [*(spread * d * rng.uniform(-1, 1, 2)), d])
        yield geo.make_pose(R, t)


# --------------------------------------------------------------------------- the flange face


def flange_region(points, radius_m: float, fx: float, depth_window_m: float = 0.04,
                  margin: float = 3.0) -> np.ndarray:
    """The pixels (H, W) bool around the flange: the nearest surface in the point cloud and
    a disc around it.

    ``points`` (H, W, 3) metres (NaN = no depth), ``radius_m`` the face's radius, ``fx`` the
    focal length in pixels. The held flange is the surface nearest the camera, but its
    wrist housing stands only 6.5 mm behind the face, over a larger area on some arms: a
    search for the largest plane in the whole image finds the wrist, the arm or the table.
    So: the pixels within ``depth_window_m`` of the nearest depth, their largest connected
    blob, then only the pixels within ``margin`` flange radii (in the image) of its middle."""
    z = np.asarray(points, dtype=float)[..., 2]
    ok = np.isfinite(z)
    if ok.sum() < 50:
        raise ValueError("fewer than 50 pixels with depth: is the flange in view?")
    z_near = np.percentile(z[ok], 0.5)                        # robust to a few flying pixels
    near = (ok & (z < z_near + depth_window_m)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(near, connectivity=8)
    if count < 2:
        raise ValueError("no surface near the camera")
    # The blob whose pixels are nearest on the median, among those of a flange's size at least.
    r_px = radius_m * fx / z_near
    big = [k for k in range(1, count) if stats[k, cv2.CC_STAT_AREA] > 0.3 * np.pi * r_px ** 2]
    if not big:
        raise ValueError("no surface near the camera is as large as the flange face")
    blob = min(big, key=lambda k: np.median(z[labels == k]))
    v, u = np.nonzero(labels == blob)
    zb = np.median(z[v, u])
    # The face is the part of the blob nearest the camera: its middle is where the nearest
    # third of the blob's pixels are.
    front = z[v, u] <= np.percentile(z[v, u], 33)
    uc, vc = u[front].mean(), v[front].mean()
    r_px = radius_m * fx / zb
    vv, uu = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    return (labels == blob) & ((uu - uc) ** 2 + (vv - vc) ** 2 < (margin * r_px) ** 2)


def face_mask(points, region, centre, normal, inlier_m: float) -> np.ndarray:
    """The flange face's pixels (H, W) bool: the ``region``'s pixels within ``inlier_m`` of
    the plane (``centre``, ``normal``), their largest connected blob (inliers of the plane
    elsewhere, e.g. on the wrist where it crosses the plane, are dropped), with its holes
    (a noisy pixel beyond ``inlier_m``) filled: the face's outline is what matters."""
    pts = np.asarray(points, dtype=float)
    dist = np.abs((pts - np.asarray(centre)) @ np.asarray(normal))
    inl = (region & (np.nan_to_num(dist, nan=np.inf) < inlier_m)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(inl, connectivity=4)
    if count < 2:
        return np.zeros(inl.shape, dtype=bool)
    blob = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    contours = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0]
    filled = np.zeros_like(blob)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool) & np.all(np.isfinite(pts), axis=2) | blob.astype(bool)


def rim_points(face, points, K, centre, normal, max_gap_px: int = 8, near_m: float = 0.02):
    """Points on the face's rim (N, 3), camera frame, m, and their pixels (N, 2).

    From each pixel on the face's border, look outwards (right, left, down, up) for the
    first pixel with depth. If it is off the face within ``max_gap_px`` pixels, the rim lies
    in the band between the two, and where depends on what that pixel is:

    * within ``near_m`` behind the face's plane (the wrist housing, 6.5 mm behind): the
      camera lost about as much on either side of that small step, so the rim is the band's
      middle (right between the two pixels when they are neighbours);
    * farther (the table, the room): the band holds the face's edge, which is the same
      small step where the housing's ring shows around the face, and the big edge behind a
      ring thin enough to be lost whole (its middle would be the housing's outer edge). So
      the rim is as far out from the face's last pixel as the half-band of the near bands
      (their median): what the camera loses of the face at a small step, measured in this
      image. With no near band (the ring lost all round) nothing measures that loss here:
      the rim is then right after the face's last pixel, as where a D4xx keeps the near
      side of an edge (its left-right check drops the far side's pixels).

    The ray through the rim's pixel, intersected with the plane (``centre``, ``normal``), is
    a rim point. Where no depth is found (the image border, out of range) no point is made."""
    if not (np.isfinite(near_m) and near_m > 0):
        raise ValueError(f"near_m must be a distance > 0 (m) behind the face's plane, got "
                         f"{near_m!r}: about three times the step to the wrist housing, 0.02")
    pts = np.asarray(points, dtype=float)
    start, step, k = _rim_bands(np.asarray(face, dtype=bool), np.all(np.isfinite(pts), axis=2),
                                max_gap_px)
    centre, normal = np.asarray(centre, float), np.asarray(normal, float)
    towards_camera = -np.sign(centre @ normal) * normal / np.linalg.norm(normal)
    beyond = pts[start[:, 1] + k * step[:, 1], start[:, 0] + k * step[:, 0]]
    far = (centre - beyond) @ towards_camera > near_m
    # Pixels the camera lost on the face's side of a small step, measured at the near bands.
    face_lost = np.median(k[~far] - 1) / 2.0 if (~far).any() else 0.0
    offset = np.where(far, np.minimum(0.5 + face_lost, k / 2.0), k / 2.0)
    uv = start + step * offset[:, None]
    return _on_plane(uv, K, centre, normal), uv


def _rim_bands(face, valid, max_gap_px: int):
    """The bands between the face and what lies beyond it: for each border pixel of ``face``
    whose first outward pixel with depth (``valid``), within ``max_gap_px`` along a row or a
    column, is off the face: (border pixels (N, 2) int, unit steps (N, 2) int, steps to that
    pixel with depth (N,) int; 1 where the two are neighbours)."""
    H, W = face.shape
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    border = face & ~cv2.erode(face.astype(np.uint8), cross, borderValue=1).astype(bool)
    v, u = np.nonzero(border)
    start, direction, steps = [], [], []
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        step = np.zeros(len(u), dtype=int)          # distance to the first pixel with depth
        alive = np.ones(len(u), dtype=bool)
        for k in range(1, max_gap_px + 1):
            uu, vv = u + k * du, v + k * dv
            alive &= (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
            hit = alive.copy()
            hit[alive] = valid[vv[alive], uu[alive]]
            step[hit] = k
            alive &= ~hit
        ok = step > 0
        ok[ok] = ~face[v[ok] + step[ok] * dv, u[ok] + step[ok] * du]
        start.append(np.column_stack([u[ok], v[ok]]))
        direction.append(np.tile([du, dv], (int(ok.sum()), 1)))
        steps.append(step[ok])
    return np.vstack(start), np.vstack(direction), np.concatenate(steps)


def _on_plane(uv, K, centre, normal) -> np.ndarray:
    """Where the rays through pixels ``uv`` (N, 2) meet the plane (``centre``, ``normal``):
    (N, 3), camera frame, m."""
    K = np.asarray(K, dtype=float)
    rays = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1],
                            np.ones(len(uv))])
    return rays * ((centre @ normal) / (rays @ normal))[:, None]


@dataclass
class FlangeView:
    """One depth image's flange measurement: the face's centre and normal (camera frame, m),
    the region, the plane's face pixels and the rim (points and pixels) for the figures."""

    centre: np.ndarray
    normal: np.ndarray
    plane_centre: np.ndarray
    plane_normal: np.ndarray
    region: np.ndarray
    face: np.ndarray
    rim: np.ndarray
    rim_px: np.ndarray
    points: np.ndarray = field(repr=False)


def nearest_plane(points, fit_plane_ransac, inlier_m: float, min_points: int, seed: int = 0,
                  rounds: int = 4):
    """(centre, normal, rounds used) of the plane nearest the camera among ``points`` (N, 3).

    RANSAC finds the plane with the most points, which need not be the flange face: seen at
    an angle, the wrist housing 6.5 mm behind the face can show more pixels than the face
    itself. The face is the surface with nothing in front of it: while at least
    ``min_points`` points lie more than ``inlier_m`` in front of the plane found (towards the
    camera), fit again to those points only. A last fit to all the points within
    ``inlier_m`` of that plane takes in the whole face again (the cut in front of a tilted
    wrist plane can leave part of it out)."""
    pts = np.asarray(points, dtype=float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    front = pts
    for k in range(1, rounds + 1):
        centre, normal = fit_plane_ransac(front, inlier_m, seed=seed)
        centre, normal = np.asarray(centre, float), np.asarray(normal, float)
        in_front = (front - centre) @ normal > inlier_m
        if in_front.sum() < min_points:
            break
        front = front[in_front]
    near = np.abs((pts - centre) @ normal) < inlier_m
    centre, normal = fit_plane_ransac(pts[near], inlier_m, seed=seed)
    return np.asarray(centre, float), np.asarray(normal, float), k


def face_plane(points, centre, normal, fit_plane_ransac, inlier_m: float, radius_m: float,
               inner: float = 0.7, rounds: int = 2, seed: int = 0):
    """(centre, normal) of the flange face's plane fitted to the face's inner disc only:
    ``points`` (N, 3) camera frame, m, within ``inlier_m`` of the plane (``centre``,
    ``normal``) and within ``inner`` * ``radius_m`` of their middle, ``rounds`` times.

    Why: a plane tilted a few degrees through the face also passes within ``inlier_m`` of a
    strip of the wrist housing 6.5 mm behind it on one side, beyond the face's rim, while it
    keeps nearly all of the face (its far side stays inside the band): on a view where that
    strip outnumbers the face pixels the tilt loses, the plane with the most points is the
    tilted one (measured: 5 deg, 2.5 mm off the face's centre on the Panda). The housing
    lies outside the face's radius, so the points of the inner disc are the face's alone; the
    first middle is pulled towards the strip by a few mm, well inside the margin."""
    pts = np.asarray(points, dtype=float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    centre, normal = np.asarray(centre, float), np.asarray(normal, float)
    for _ in range(rounds):
        near = np.abs((pts - centre) @ normal) < inlier_m
        if not near.any():
            break
        disc = near & (_in_plane_distance(pts, pts[near].mean(axis=0), normal)
                       < inner * radius_m)
        if disc.sum() < 3:
            break
        centre, normal = fit_plane_ransac(pts[disc], inlier_m, seed=seed)
        centre, normal = np.asarray(centre, float), np.asarray(normal, float)
    return centre, normal


def _in_plane_distance(points, centre, normal) -> np.ndarray:
    """How far each of ``points`` (N, 3) lies from ``centre`` along the plane whose unit
    ``normal`` is given: (N,), in the points' units."""
    d = np.asarray(points, float) - centre
    return np.linalg.norm(d - np.outer(d @ normal, normal), axis=1)


def measure_flange(raw, K, depth_scale, radius_m, backproject, fit_plane_ransac,
                   fit_flange_circle, inlier_m: float = 0.003, seed: int = 0,
                   max_rim_rms: float = 0.1) -> FlangeView:
    """The whole flange pipeline on one raw depth image (the functions are yours):
    ``backproject`` -> :func:`flange_region` -> :func:`nearest_plane` and
    :func:`face_plane` (your ``fit_plane_ransac``) -> :func:`face_mask` -> :func:`rim_points` ->
    ``fit_flange_circle(rim, radius_m)``. Raises ``ValueError`` when it finds no flange, or
    when the rim points lie off the fitted circle by more than ``max_rim_rms`` radii (RMS)."""
    K = np.asarray(K, dtype=float)
    points = backproject(raw, K, depth_scale)
    region = flange_region(points, radius_m, K[0, 0])
    z = np.nanmedian(points[region][:, 2])
    face_px = np.pi * (radius_m * K[0, 0] / z) ** 2            # the face's area seen head-on
    plane_centre, plane_normal, _ = nearest_plane(points[region], fit_plane_ransac, inlier_m,
                                                  int(0.3 * face_px), seed=seed)
    plane_centre, plane_normal = face_plane(points[region], plane_centre, plane_normal,
                                            fit_plane_ransac, inlier_m, radius_m, seed=seed)
    face = face_mask(points, region, plane_centre, plane_normal, inlier_m)
    if face.sum() < 0.3 * face_px:
        raise ValueError("the plane nearest the camera is too small to be the flange face")
    rim, rim_px = rim_points(face, points, K, plane_centre, plane_normal)
    if len(rim) < 10:
        raise ValueError(f"only {len(rim)} rim points: is the whole flange face in view?")
    centre, normal = fit_flange_circle(rim, radius_m)
    centre, normal = np.asarray(centre, float), np.asarray(normal, float)
    # A view where the region held something else than the face (part of the wrist, the
    # face seen too obliquely) gives rim points that are no circle of the data sheet's size.
    rms = np.sqrt(np.mean((_in_plane_distance(rim, centre, normal) - radius_m) ** 2))
    if rms > max_rim_rms * radius_m:
        raise ValueError(f"the rim is no circle of radius {radius_m * 1000:.1f} mm (RMS "
                         f"{rms * 1000:.1f} mm off it): the view is skipped")
    return FlangeView(centre, normal,
                      np.asarray(plane_centre, float), np.asarray(plane_normal, float),
                      region, face, rim, rim_px, points)


def true_cam_centre(cell) -> np.ndarray:
    """Sim only: where the flange face's centre (the flange frame's origin) truly is in the
    camera frame (3,), m."""
    base_T_flange = cell.arm.true_flange_pose()
    return geo.transform_points(geo.invert(cell.truth.base_T_cam), base_T_flange[:3, 3])


@dataclass
class FlangeCapture:
    """The flange centres the camera measured (N, 3, camera frame, m) and the robot's flange
    poses at those moments (N, 4, 4); in sim also the true centres (N, 3), else None."""

    cam_centres: np.ndarray
    base_T_flanges: np.ndarray
    true_cam_centres: np.ndarray | None
    skipped: int
    frames: list = field(default_factory=list, repr=False)   # the kept views' Frames


def capture_flange_centres(cell, goals, measure, n_poses: int = 12, speed: float = 0.25,
                           settle_s: float = 0.0) -> FlangeCapture:
    """Move through ``goals`` (base_T_flange poses) until ``n_poses`` flange centres are
    measured: at each, read the robot's ``flange_pose()``, capture a frame and call
    ``measure(frame) -> FlangeView`` (skipped if it raises ``ValueError``). Poses the arm
    cannot reach, or the Safety checks refuse, are skipped too."""
    import time

    centres, flanges, truths, frames, skipped = [], [], [], [], 0
    for goal in goals:
        try:
            cell.robot.move_to(goal, speed=speed)
        except (UnreachableError, SafetyError):
            skipped += 1
            continue
        if settle_s > 0:
            time.sleep(settle_s)
        base_T_flange = cell.robot.flange_pose()
        frame = cell.camera.capture()
        try:
            view = measure(frame)
        except ValueError:
            skipped += 1
            continue
        centres.append(view.centre)
        flanges.append(base_T_flange)
        frames.append(frame)
        if getattr(cell, "truth", None) is not None and hasattr(cell, "arm"):
            truths.append(true_cam_centre(cell))
        if len(centres) == n_poses:
            break
    return FlangeCapture(np.array(centres).reshape(-1, 3), np.array(flanges).reshape(-1, 4, 4),
                         np.array(truths) if truths else None, skipped, frames)


def as_capture(flange_capture: FlangeCapture, camera, robot_name: str = ""):
    """The kept views as a :class:`robots.capture.Capture` (RGB, depth in metres and
    ``base_T_flange`` per view), for ``robots.capture.save_capture``: a session on the real
    cell recorded once can be rerun at a desk with the notebook's "load a capture" cell. The
    bare flange has no target corners, so ``cam_T_target`` is NaN and the corner lists are
    empty."""
    from robots.capture import Capture

    n = len(flange_capture.frames)
    if n != len(flange_capture.base_T_flanges):
        raise ValueError(f"{len(flange_capture.base_T_flanges)} views but {n} frames: record "
                         "with capture_flange_centres, which keeps each view's frame")
    if any(f.depth is None for f in flange_capture.frames):
        raise ValueError("a frame has no depth image: the camera must stream depth")
    return Capture(
        base_T_flange=flange_capture.base_T_flanges,
        cam_T_target=np.full((n, 4, 4), np.nan),
        corners_px=[np.zeros((0, 2)) for _ in range(n)],
        object_points=[np.zeros((0, 3)) for _ in range(n)],
        intrinsics=camera.intrinsics,
        commanded_base_T_flange=flange_capture.base_T_flanges,
        pose_indices=np.arange(n),
        timestamps=np.array([f.timestamp for f in flange_capture.frames], dtype=float),
        images=[f.rgb for f in flange_capture.frames],
        depths=[f.depth for f in flange_capture.frames],
        robot_name=robot_name, camera_name=getattr(camera, "name", ""))


# --------------------------------------------------------------------------- rectangle


def find_rectangle_corners(rgb, dark: int = 60, min_area_px: float = 200.0):
    """The four corners (4, 2) pixels of the dark rectangle mark in an RGB image, ordered
    top-left, top-right, bottom-right, bottom-left (clockwise as displayed, starting at the
    corner nearest the image's top-left), or None if no dark quadrilateral is found.

    The dark pixels (every channel below ``dark``), their connected blobs; the largest one
    that is a filled convex quadrilateral is the mark (the chessboard's squares touch at
    their corners and make one blob that is not). Each side is then a straight line fitted
    to the blob's border pixels away from the corners, moved half a pixel outwards (a border
    pixel's centre lies 0 to 1 pixel inside the true edge), and the corners are where
    neighbouring lines cross: sub-pixel, unlike the polygon's own vertices. (The mark is a
    3 mm card: its side walls, darker than its top, are left out.)"""
    mask = (np.asarray(rgb).max(axis=2) < dark).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    best = None
    for k in np.argsort(-stats[:, cv2.CC_STAT_AREA]):
        if k == 0 or stats[k, cv2.CC_STAT_AREA] < min_area_px:
            continue
        blob = (labels == k).astype(np.uint8)
        contour = max(cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0],
                      key=len)
        hull_area = cv2.contourArea(cv2.convexHull(contour))
        if hull_area <= 0 or stats[k, cv2.CC_STAT_AREA] < 0.9 * hull_area:
            continue
        poly = cv2.approxPolyDP(contour, 0.04 * cv2.arcLength(contour, True), True)
        if len(poly) == 4 and cv2.isContourConvex(poly):
            best = (blob.astype(bool), poly.reshape(4, 2).astype(float))
            break
    if best is None:
        return None
    blob, poly = best
    # The mark is a card: seen at a slant its near side walls are in the blob too, shaded
    # darker than its top. Keep the pixels as bright as the blob's bulk (the top face).
    gray = np.asarray(rgb).max(axis=2).astype(float)
    level = np.median(gray[blob])
    top = (blob & (np.abs(gray - level) <= max(2.0, 0.25 * level))).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(top, connectivity=4)
    if count > 1:
        blob = labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        contour = max(cv2.findContours(blob.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)[0], key=len)
        quad = cv2.approxPolyDP(contour, 0.04 * cv2.arcLength(contour, True), True)
        if len(quad) == 4:
            poly = quad.reshape(4, 2).astype(float)
    # Border pixels: in the blob with a 4-neighbour outside it.
    inner = cv2.erode(blob.astype(np.uint8), np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]],
                                                      np.uint8)).astype(bool)
    v, u = np.nonzero(blob & ~inner)
    border = np.column_stack([u, v]).astype(float)
    centroid = poly.mean(axis=0)
    lines = []
    for i in range(4):
        a, b = poly[i], poly[(i + 1) % 4]
        d = (b - a) / np.linalg.norm(b - a)
        nrm = np.array([d[1], -d[0]])
        if nrm @ (a - centroid) < 0:
            nrm = -nrm                                         # outwards
        s = (border - a) @ d
        length = np.linalg.norm(b - a)
        near = (np.abs((border - a) @ nrm) < 3.0) & (s > 0.15 * length) & (s < 0.85 * length)
        if near.sum() < 3:
            return None
        vx, vy, x0, y0 = cv2.fitLine(border[near].astype(np.float32), cv2.DIST_L2, 0, 0.01,
                                     0.01).ravel()
        n_fit = np.array([vy, -vx]) if np.array([vy, -vx]) @ nrm > 0 else -np.array([vy, -vx])
        p0 = np.array([x0, y0]) + 0.5 * n_fit
        lines.append(np.cross([*p0, 1.0], [*(p0 + [vx, vy]), 1.0]))
    corners = []
    for i in range(4):
        x = np.cross(lines[i - 1], lines[i])                  # sides i-1 and i meet at vertex i
        corners.append(x[:2] / x[2])
    corners = np.array(corners)
    # Clockwise as displayed (v points down), starting at the corner nearest the top-left.
    c = corners.mean(axis=0)
    order = np.argsort(np.arctan2(corners[:, 1] - c[1], corners[:, 0] - c[0]))
    corners = corners[order]
    return np.roll(corners, -int(np.argmin(corners.sum(axis=1))), axis=0)


def true_rectangle_pose(cell, corners_px) -> np.ndarray:
    """Sim only: the true cam_T_rect of the mark in the frame the corner order defines
    (origin at the centre, x from the top-left to the top-right corner, y towards the
    bottom-left one, z into the mark). The mark is square, so which true corner is "top-left"
    follows the image: each detected corner is matched to the nearest projected true one."""
    truth = cell.truth
    w, h = truth.rectangle_size
    local = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0],
                      [-w / 2, h / 2, 0]])
    cam = geo.transform_points(geo.invert(truth.base_T_cam) @ truth.base_T_rectangle, local)
    K = cell.camera.intrinsics.K
    uv = (cam @ K.T)[:, :2] / cam[:, 2:3]
    match = [int(np.argmin(np.linalg.norm(uv - c, axis=1))) for c in np.asarray(corners_px)]
    tl, tr, _, bl = cam[match]
    x = (tr - tl) / np.linalg.norm(tr - tl)
    y = bl - tl - ((bl - tl) @ x) * x
    y /= np.linalg.norm(y)
    return geo.make_pose(np.column_stack([x, y, np.cross(x, y)]), cam[match].mean(axis=0))


# --------------------------------------------------------------------------- figures


def show_depth(raw, depth_scale: float, rgb=None) -> None:
    """The raw depth image (sensor units) beside the colour image, with the holes marked."""
    import matplotlib.pyplot as plt

    n = 2 if rgb is not None else 1
    fig, axes = plt.subplots(1, n, figsize=(5.5 * n, 3.6))
    axes = np.atleast_1d(axes)
    raw = np.asarray(raw)
    im = axes[0].imshow(np.where(raw > 0, raw, np.nan), cmap="viridis")
    axes[0].set_title(f"raw depth (units of {depth_scale * 1000:g} mm); white: 0, no depth")
    fig.colorbar(im, ax=axes[0], label="raw value")
    if rgb is not None:
        axes[1].imshow(rgb)
        axes[1].set_title("colour image")
    for ax in axes:
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
    fig.tight_layout()
    plt.show()


def _crop(mask, pad: int = 12):
    v, u = np.nonzero(mask)
    return (max(0, u.min() - pad), u.max() + pad + 1, max(0, v.min() - pad), v.max() + pad + 1)


def show_face(view: FlangeView, inlier_m: float) -> None:
    """Left: depth around the flange (the region outlined). Right: each region point's
    distance from the fitted plane (mm), the plane's inliers and the face's blob."""
    import matplotlib.pyplot as plt

    u0, u1, v0, v1 = _crop(view.region)
    z = view.points[..., 2]
    dist = (view.points - view.plane_centre) @ view.plane_normal
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    im = axes[0].imshow(1000 * z[v0:v1, u0:u1], cmap="viridis",
                        extent=(u0 - 0.5, u1 - 0.5, v1 - 0.5, v0 - 0.5))
    axes[0].contour(np.arange(u0, u1), np.arange(v0, v1), view.region[v0:v1, u0:u1], [0.5],
                    colors="w", linewidths=1)
    axes[0].set_title("depth (mm) and the region around the flange")
    fig.colorbar(im, ax=axes[0])
    shown = np.where(view.region, 1000 * dist, np.nan)[v0:v1, u0:u1]
    im = axes[1].imshow(shown, cmap="coolwarm", vmin=-10, vmax=10,
                        extent=(u0 - 0.5, u1 - 0.5, v1 - 0.5, v0 - 0.5))
    axes[1].contour(np.arange(u0, u1), np.arange(v0, v1), view.face[v0:v1, u0:u1], [0.5],
                    colors="k", linewidths=1)
    axes[1].set_title(f"signed distance from the plane (mm); black: the face "
                      f"(|d| < {inlier_m * 1000:g} mm)", fontsize=9)
    fig.colorbar(im, ax=axes[1])
    for ax in axes:
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
    fig.tight_layout()
    plt.show()


def show_rim(view: FlangeView, radius_m: float, K, true_centre=None) -> None:
    """Left: the rim pixels on the depth image. Right: the rim points in the face's plane
    (mm) with the fitted circle and its centre (and the true centre, in sim)."""
    import matplotlib.pyplot as plt

    u0, u1, v0, v1 = _crop(view.region)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    axes[0].imshow(view.points[v0:v1, u0:u1, 2], cmap="gray",
                   extent=(u0 - 0.5, u1 - 0.5, v1 - 0.5, v0 - 0.5))
    axes[0].plot(*view.rim_px.T, "r.", ms=2, label="rim (face | deeper neighbour)")
    K = np.asarray(K, dtype=float)
    c_px = K @ view.centre
    axes[0].plot(c_px[0] / c_px[2], c_px[1] / c_px[2], "y+", ms=12, mew=2, label="fitted centre")
    axes[0].set_title("rim pixels on the depth image")
    axes[0].legend(fontsize=8, loc="lower right")
    n = view.normal / np.linalg.norm(view.normal)
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    xy = 1000 * np.column_stack([(view.rim - view.centre) @ e1, (view.rim - view.centre) @ e2])
    ax = axes[1]
    ax.plot(*xy.T, "r.", ms=3, label="rim points")
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(1000 * radius_m * np.cos(t), 1000 * radius_m * np.sin(t), "b-", lw=1,
            label=f"circle, r = {radius_m * 1000:.1f} mm (data sheet)")
    ax.plot(0, 0, "b+", ms=12, mew=2, label="fitted centre")
    if true_centre is not None:
        d = 1000 * (np.asarray(true_centre) - view.centre)
        ax.plot(d @ e1, d @ e2, "gx", ms=10, mew=2, label="true centre (sim)")
    ax.set_aspect("equal")
    ax.set_xlabel("in-plane e1 (mm)")
    ax.set_ylabel("in-plane e2 (mm)")
    ax.set_title("the rim in the face's plane")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    plt.show()


def show_centre_errors(cam_centres, true_cam_centres) -> None:
    """Each measured flange centre's error against the truth (sim), along the camera's axes."""
    import matplotlib.pyplot as plt

    from robots.labkit.lab4 import bars_along_camera_axes

    err = 1000 * (np.asarray(cam_centres) - np.asarray(true_cam_centres))
    fig, ax = plt.subplots(figsize=(8, 3))
    bars_along_camera_axes(ax, err, "pose", "centre error (mm)",
                           "measured flange centre minus the truth, per pose")
    fig.tight_layout()
    plt.show()


def show_rectangle(rgb, corners_px, projected: dict | None = None) -> None:
    """The mark's neighbourhood with the found corners (labelled TL, TR, BR, BL) and, per
    pose in ``projected`` ({label: (4, 2) pixels}), the corners that pose puts back."""
    import matplotlib.pyplot as plt

    c = np.asarray(corners_px, dtype=float)
    lo, hi = c.min(axis=0) - 25, c.max(axis=0) + 25
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.imshow(rgb)
    ax.plot(*np.vstack([c, c[:1]]).T, "y-", lw=1)
    for name, p in zip(("TL", "TR", "BR", "BL"), c):
        ax.annotate(name, p, color="y", fontsize=9, xytext=(4, -4), textcoords="offset points")
    for (label, uv), marker in zip((projected or {}).items(), "+x1"):
        ax.plot(*np.asarray(uv).T, marker, ms=9, mew=1.5, label=label)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])
    ax.set_title("the rectangle mark and its corners")
    if projected:
        ax.legend(fontsize=8)
    plt.show()


# --------------------------------------------------------------------------- the numbers


def load_depth_vs_board(path) -> dict | None:
    """The markerless-vs-board comparison written by ``benchmarks/depth_calibration.py``
    (``labs/lab5_depth/depth_vs_board.json``), or None if the file is not there."""
    path = Path(path)
    if not path.is_file():
        return None
    return json.loads(path.read_text())


def show_depth_vs_board(data: dict) -> None:
    """Three panels: translation and rotation error per seed of the markerless (flange) and
    the board-based calibration; the error against the depth noise; against the number of
    poses (medians with the inter-quartile range)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    ax = axes[0]
    methods = data["methods"]
    names = list(methods)
    ax.boxplot([methods[m]["translation_mm"] for m in names])
    ax.set_xticks(range(1, len(names) + 1), names)
    ax.set_ylabel("translation error (mm)")
    ax2 = ax.twinx()
    for i, m in enumerate(names):
        r = np.asarray(methods[m]["rotation_deg"])
        ax2.plot(np.full(len(r), i + 1.3), r, "k.", ms=3, alpha=0.6)
    ax2.set_ylabel("rotation error (deg, dots)")
    ax.set_title(f"{data['arm']}: {data['seeds']} seeds, {data['n_poses']} poses each")

    def sweep(ax, rows, key, label):
        x = np.array([r[key] for r in rows], dtype=float)
        for metric, colour, unit in (("translation_mm", "tab:blue", "mm"),):
            q = np.array([np.percentile(r[metric], [25, 50, 75]) for r in rows])
            ax.plot(x, q[:, 1], "o-", color=colour, label=f"translation, median ({unit})")
            ax.fill_between(x, q[:, 0], q[:, 2], color=colour, alpha=0.2)
        ax.set_xlabel(label)
        ax.set_ylabel("translation error (mm)")
        axr = ax.twinx()
        q = np.array([np.percentile(r["rotation_deg"], [25, 50, 75]) for r in rows])
        axr.plot(x, q[:, 1], "s--", color="tab:red", label="rotation, median (deg)")
        axr.set_ylabel("rotation error (deg)", color="tab:red")
        ax.legend(fontsize=8, loc="upper left")

    if data.get("noise_sweep"):
        sweep(axes[1], data["noise_sweep"], "depth_noise_scale", "depth noise (x the D435's)")
        axes[1].set_title("markerless: error vs depth noise")
    if data.get("poses_sweep"):
        sweep(axes[2], data["poses_sweep"], "n_poses", "number of poses")
        axes[2].set_title("markerless: error vs number of poses")
    fig.tight_layout()
    plt.show()
