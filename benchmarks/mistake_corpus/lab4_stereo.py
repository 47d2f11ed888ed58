"""Lab 4 (stereo, single-shot hand-to-eye): classic mistakes in frame_from_three_points,
reproject, hand_to_eye_from_three_points and per_axis_rmse (see ``mistake_corpus``).

``frame_from_three_points`` below is the student's correct one: the notebook's
hand_to_eye_from_three_points calls it, and the grader substitutes the true frames for the
calls it expects, so a mistake of hand_to_eye is charged to hand_to_eye alone.
"""

from __future__ import annotations

import numpy as np

from mistake_corpus import pose as _pose
from mistake_corpus import register

mistake = register("lab4_stereo")


def frame_from_three_points(p_origin, p_x, p_xy):
    """The student's correct frame (the notebook's), called by hand_to_eye below."""
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    z = z / np.linalg.norm(z)
    return _pose(np.column_stack([x, np.cross(z, x), z]), o)


def _inverse(T):
    R, t = T[:3, :3], T[:3, 3]
    return _pose(R.T, -R.T @ t)


# --------------------------------------------------------------------------- frame_from_three_points


@mistake("frame_from_three_points", "reflection", "I built y as x cross z instead of "
         "z cross x, so my frame is left-handed")
def frame_y_cross_order(p_origin, p_x, p_xy):
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    z = z / np.linalg.norm(z)
    return _pose(np.column_stack([x, np.cross(x, z), z]), o)


@mistake("frame_from_three_points", "none", "I forgot to normalise z after the cross "
         "product", names=r"normali[sz]|\bunit\b")
def frame_z_not_normalised(p_origin, p_x, p_xy):
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    return _pose(np.column_stack([x, np.cross(z, x), z]), o)


@mistake("frame_from_three_points", "inverse/transpose", "I stacked the axes with "
         "np.array([x, y, z]), which makes them rows, not columns")
def frame_axes_as_rows(p_origin, p_x, p_xy):
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    z = z / np.linalg.norm(z)
    return _pose(np.array([x, np.cross(z, x), z]), o)


@mistake("frame_from_three_points", "none", "I put the origin at the centroid of the three "
         "points instead of at p_origin", names=r"origin|centroid")
def frame_origin_at_centroid(p_origin, p_x, p_xy):
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    z = z / np.linalg.norm(z)
    centre = (o + np.asarray(p_x, dtype=float) + np.asarray(p_xy, dtype=float)) / 3.0
    return _pose(np.column_stack([x, np.cross(z, x), z]), centre)


@mistake("frame_from_three_points", "swapped arguments", "my def line read (p_origin, p_xy, "
         "p_x): x points at the third point and the second sets the plane")
def frame_points_swapped(p_origin, p_xy, p_x):
    o = np.asarray(p_origin, dtype=float)
    x = np.asarray(p_x, dtype=float) - o
    x = x / np.linalg.norm(x)
    z = np.cross(x, np.asarray(p_xy, dtype=float) - o)
    z = z / np.linalg.norm(z)
    return _pose(np.column_stack([x, np.cross(z, x), z]), o)


# --------------------------------------------------------------------------- reproject


@mistake("reproject", "none", "I returned Q @ [u, v, d, 1] without dividing by its last "
         "entry W", names=r"\bW\b|homogeneous|divid")
def reproject_no_division(u, v, d, Q):
    X, Y, Z, _ = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return np.array([X, Y, Z])


@mistake("reproject", "inverse/transpose", "I wrote [u, v, d, 1] @ Q, which multiplies by "
         "Q^T")
def reproject_q_transposed(u, v, d, Q):
    X, Y, Z, W = np.array([u, v, d, 1.0]) @ np.asarray(Q, dtype=float)
    return np.array([X, Y, Z]) / W


@mistake("reproject", "swapped arguments", "I put the pixel in as [v, u] (row, column), as "
         "for indexing an image")
def reproject_row_column(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, dtype=float) @ np.array([v, u, d, 1.0])
    return np.array([X, Y, Z]) / W


@mistake("reproject", "none", "I rounded u, v and d to whole pixels first, as for indexing "
         "an image", names=r"round|integer|whole pixel")
def reproject_rounded_pixels(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, dtype=float) @ np.array([round(u), round(v), round(d), 1.0])
    return np.array([X, Y, Z]) / W


@mistake("reproject", "none", "I returned the whole homogeneous point [X, Y, Z, W] / W, four "
         "numbers, not three", names=r"shape|\(3,\)|three")
def reproject_four_numbers(u, v, d, Q):
    h = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return h / h[3]


@mistake("reproject", "none", "I worked Z out by hand as 1 / W and forgot the focal length "
         "(Z = f / W)", names=r"focal|\bf\b")
def reproject_depth_without_focal(u, v, d, Q):
    X, Y, _, W = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return np.array([X / W, Y / W, 1.0 / W])


@mistake("reproject", "units m/mm", "I divided the point by 1000 to get metres, but Q's "
         "baseline is in metres already")
def reproject_divided_by_1000(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, dtype=float) @ np.array([u, v, d, 1.0])
    return np.array([X, Y, Z]) / W / 1000.0


# --------------------------------------------------------------------------- hand_to_eye


@mistake("hand_to_eye_from_three_points", "inverse/transpose", "I inverted cam_T_world with "
         ".T, the transpose of the whole 4x4 pose")
def hand_to_eye_transpose_for_inverse(cam_points, base_points):
    cam_T_world = frame_from_three_points(*np.asarray(cam_points, dtype=float))
    base_T_world = frame_from_three_points(*np.asarray(base_points, dtype=float))
    return base_T_world @ cam_T_world.T


@mistake("hand_to_eye_from_three_points", "none", "when inverting cam_T_world I transposed R "
         "but negated t only, without rotating it: -t, not -R^T t", names=r"-R\^T t|-t\b")
def hand_to_eye_inverse_translation_unrotated(cam_points, base_points):
    cam_T_world = frame_from_three_points(*np.asarray(cam_points, dtype=float))
    base_T_world = frame_from_three_points(*np.asarray(base_points, dtype=float))
    R, t = cam_T_world[:3, :3], cam_T_world[:3, 3]
    return base_T_world @ _pose(R.T, -t)


@mistake("hand_to_eye_from_three_points", "none", "I passed the (3, 3) arrays' columns as the "
         "points (*points.T), but each row is a point", names=r"row|column")
def hand_to_eye_points_as_columns(cam_points, base_points):
    cam_T_world = frame_from_three_points(*np.asarray(cam_points, dtype=float).T)
    base_T_world = frame_from_three_points(*np.asarray(base_points, dtype=float).T)
    return base_T_world @ _inverse(cam_T_world)


@mistake("hand_to_eye_from_three_points", "swapped arguments", "I built the frames from the "
         "wrong sets: the camera's frame from base_points and the base's from cam_points",
         also=("inverse/transpose",))
def hand_to_eye_point_sets_swapped(cam_points, base_points):
    cam_T_world = frame_from_three_points(*np.asarray(base_points, dtype=float))
    base_T_world = frame_from_three_points(*np.asarray(cam_points, dtype=float))
    return base_T_world @ _inverse(cam_T_world)


@mistake("hand_to_eye_from_three_points", "none", "I inverted the wrong frame: "
         "inv(base_T_world) @ cam_T_world instead of base_T_world @ inv(cam_T_world)",
         names=r"wrong frame|inv\(base_T_world\)|base frame.{0,20}invert")
def hand_to_eye_wrong_frame_inverted(cam_points, base_points):
    cam_T_world = frame_from_three_points(*np.asarray(cam_points, dtype=float))
    base_T_world = frame_from_three_points(*np.asarray(base_points, dtype=float))
    return _inverse(base_T_world) @ cam_T_world


# --------------------------------------------------------------------------- per_axis_rmse


@mistake("per_axis_rmse", "none", "I took the mean over axis=1, per point, instead of axis=0, "
         "per axis", names=r"\baxis\b")
def rmse_wrong_axis(base_T_cam, cam_points, base_points):
    R, t = base_T_cam[:3, :3], base_T_cam[:3, 3]
    along_cam = (cam_points @ R.T + t - base_points) @ R
    return np.sqrt(np.mean(along_cam ** 2, axis=1))


@mistake("per_axis_rmse", "none", "I returned the largest absolute residual on each axis, not "
         "the RMS", names=r"max|largest|worst")
def rmse_max_abs(base_T_cam, cam_points, base_points):
    R, t = base_T_cam[:3, :3], base_T_cam[:3, 3]
    along_cam = (cam_points @ R.T + t - base_points) @ R
    return np.abs(along_cam).max(axis=0)


@mistake("per_axis_rmse", "inverse/transpose", "I mapped the camera points with "
         "cam_points @ R instead of cam_points @ R.T, so by R^T")
def rmse_mapped_by_r_transposed(base_T_cam, cam_points, base_points):
    R, t = base_T_cam[:3, :3], base_T_cam[:3, 3]
    along_cam = (cam_points @ R + t - base_points) @ R
    return np.sqrt(np.mean(along_cam ** 2, axis=0))
