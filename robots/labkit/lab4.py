"""Lab 4 plumbing: the stereo calibration views, rectification and SGBM, and the figures."""

from __future__ import annotations

import cv2
import numpy as np

from robots import geometry as geo
from robots.interfaces import SafetyError, UnreachableError

__all__ = ["view_goals", "find_corners", "whole_in_view", "capture_stereo_views", "park", "rectify",
           "sgbm_disparity", "show_rectified", "show_residuals_mm", "bars_along_camera_axes"]


def view_goals(cell, rng: np.random.Generator, n: int):
    """``n`` flange poses (base_T_flange) that hold the flange board 0.4-0.6 m in front of the
    left camera, facing it within 30 degrees. Sim only: aims with the truth (where the cameras
    and the board are), as you would aim by jogging a real arm."""
    truth = cell.truth
    target = truth.flange_target
    w, h = target.size
    centre = (geo.invert(target.print_T_target) @ [w / 2, h / 2, 0, 1])[:3]
    for _ in range(n):
        cam_T_centre = geo.compose(
            geo.make_pose(t=[*rng.uniform(-0.08, 0.08, 2), rng.uniform(0.4, 0.6)]),
            geo.pose_from_rotvec(np.deg2rad(rng.uniform(-30, 30, 3))))
        yield geo.compose(truth.base_T_cam, cam_T_centre, geo.make_pose(t=-centre),
                          geo.invert(truth.flange_T_marker))


def find_corners(rgb, pattern):
    """Sub-pixel inner corners (N, 2) of a chessboard with ``pattern`` = (columns, rows) inner
    corners in an RGB image, or None when the whole board is not found."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(
        gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)


def whole_in_view(corners, target, image_size) -> bool:
    """Whether the printed board lies wholly inside the image, judged from its detected inner
    ``corners`` (N, 2) px: the homography they give maps the print's outer edge into the image.
    With the board cut by the image edge the detector can return a grid one square off, which
    passes every other check; this one it fails."""
    H, _ = cv2.findHomography(target.object_points[:, :2].astype(np.float64),
                              np.asarray(corners, dtype=np.float64))
    if H is None:
        return False
    w, h = target.size
    target_T_print = geo.invert(target.print_T_target)
    edge = np.array([[0, 0, 0, 1], [w, 0, 0, 1], [w, h, 0, 1], [0, h, 0, 1]], dtype=float)
    xy = (edge @ target_T_print.T)[:, :2]
    px = cv2.perspectiveTransform(xy.reshape(-1, 1, 2), H).reshape(-1, 2)
    width, height = image_size
    return bool(np.all((px >= 0) & (px <= [width - 1, height - 1])))


def capture_stereo_views(cell, rng: np.random.Generator, n_views: int = 20, tries: int = 40,
                         speed: float = 0.25):
    """Move the flange board through up to ``tries`` poses and keep the first ``n_views`` that
    both cameras see whole. Returns ``(object_points, left_px, right_px, image_size)``: lists of
    float32 arrays as ``cv2.stereoCalibrate`` wants them (board points in m, pixels) and the
    image size (width, height). Poses the arm cannot reach are skipped."""
    left, right = cell.cameras["cam"], cell.cameras["right"]
    target = cell.truth.flange_target
    pattern = target.pattern_size
    board_points = target.object_points.astype(np.float32)
    size = (left.intrinsics.width, left.intrinsics.height)
    object_points, left_px, right_px = [], [], []
    for goal in view_goals(cell, rng, tries):
        try:
            cell.robot.move_to(goal, speed=speed)
        except (UnreachableError, SafetyError):
            continue
        a, b = find_corners(left.capture().rgb, pattern), find_corners(right.capture().rgb, pattern)
        if a is None or b is None or not (whole_in_view(a, target, size)
                                          and whole_in_view(b, target, size)):
            continue
        object_points.append(board_points)
        left_px.append(a.astype(np.float32))
        right_px.append(b.astype(np.float32))
        if len(object_points) == n_views:
            break
    return object_points, left_px, right_px, size


def park(robot, q_park, steps: int = 2, speed: float = 1.0) -> None:
    """Move to the joint positions ``q_park`` (rad) in ``steps`` equal joint-space steps (the
    Safety layer limits each step's size)."""
    q_start = robot.joint_positions()
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        robot.move_joints(q_start + s * (np.asarray(q_park) - q_start), speed=speed)


def rectify(rgb, K, dist, R, P, image_size):
    """One camera's image undistorted and rectified with ``cv2.stereoRectify``'s R and P."""
    maps = cv2.initUndistortRectifyMap(K, dist, R, P, image_size, cv2.CV_32FC1)
    return cv2.remap(rgb, *maps, cv2.INTER_LINEAR)


def sgbm_disparity(rect_left, rect_right, num_disparities: int = 96) -> np.ndarray:
    """Dense disparity (H, W) in pixels of a rectified RGB pair by semi-global block matching
    (negative where SGBM found no match)."""
    gray_l, gray_r = (cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in (rect_left, rect_right))
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=5, speckleWindowSize=100,
                                 speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    return sgbm.compute(gray_l, gray_r).astype(np.float32) / 16.0  # SGBM counts 1/16 pixels


def show_rectified(rect_left, rect_right, disparity, corners_left) -> None:
    """The rectified pair side by side with a few image rows drawn, and the SGBM disparity
    with the board corners found in the left image."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    axes[0].imshow(np.hstack([rect_left, rect_right]))
    for v in range(20, rect_left.shape[0], 40):
        axes[0].axhline(v, color="y", lw=0.5)
    axes[0].set_title("rectified pair: rows line up")
    axes[0].set_xlabel("u (px, left | right)")
    axes[0].set_ylabel("v (px)")
    im = axes[1].imshow(np.where(disparity > 0, disparity, np.nan), cmap="viridis")
    axes[1].plot(*np.asarray(corners_left).T, "r.", ms=3)
    axes[1].set_title("SGBM disparity and the board corners")
    fig.colorbar(im, ax=axes[1], label="disparity (px)")
    plt.show()


def show_residuals_mm(base_T_cam, cam_points, base_points, gain: float = 10.0) -> None:
    """Where the calibration misses, at millimetre scale.

    Left: the check points seen from above (base x, y in m) with each residual
    ``r_i = base_T_cam @ c_i - b_i`` drawn as an arrow ``gain`` times its length. Right: every
    residual along the camera's x, y and z axes (``R^T r_i``), in millimetres.
    """
    import matplotlib.pyplot as plt

    R, t = base_T_cam[:3, :3], base_T_cam[:3, 3]
    residuals = np.asarray(cam_points) @ R.T + t - np.asarray(base_points)     # base axes, m
    along_cam = 1000 * residuals @ R                                         # camera axes, mm
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [1, 1.4]})
    ax = axes[0]
    b = np.asarray(base_points)
    ax.plot(b[:, 0], b[:, 1], "k.", ms=6, label="check points")
    ax.quiver(b[:, 0], b[:, 1], gain * residuals[:, 0], gain * residuals[:, 1], angles="xy",
              scale_units="xy", scale=1, color="m", width=0.004,
              label=f"residual in the base xy plane, x{gain:g}")
    tips = b[:, :2] + gain * residuals[:, :2]
    low, high = np.minimum(b[:, :2], tips).min(axis=0), np.maximum(b[:, :2], tips).max(axis=0)
    pad = 0.1 * (high - low).max()
    ax.set_xlim(low[0] - pad, high[0] + pad)
    ax.set_ylim(low[1] - pad, high[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("base x (m)")
    ax.set_ylabel("base y (m)")
    ax.set_title("the check points from above (base frame)")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    bars_along_camera_axes(axes[1], along_cam, "check point", "residual (mm)",
                           "each residual along the camera's axes")
    fig.tight_layout()
    plt.show()


def bars_along_camera_axes(ax, values_mm, xlabel: str, ylabel: str, title: str) -> None:
    """One group of three bars (camera x, y, z) per row of ``values_mm`` (N, 3), on ``ax``."""
    x = np.arange(len(values_mm))
    for k, (name, colour) in enumerate(zip(("camera x", "camera y", "camera z (depth)"), "rgb")):
        ax.bar(x + (k - 1) * 0.27, values_mm[:, k], 0.27, color=colour, label=name)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xticks(x)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
