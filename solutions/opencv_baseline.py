"""OpenCV's hand-eye solvers behind this project's conventions, for side-by-side comparison.

OpenCV names poses "a2b" for the transform that maps a-coordinates to b-coordinates, so its
``gripper2base`` is our ``base_T_flange`` and ``target2cam`` is our ``cam_T_target``.

* ``cv2.calibrateHandEye`` solves eye-in-hand from (gripper2base, target2cam) and returns
  cam2gripper = ``flange_T_cam``. For eye-to-hand its documentation says to pass base2gripper
  (= ``inv(base_T_flange)``) instead; it then returns cam2base = ``base_T_cam``.
* ``cv2.calibrateRobotWorldHandEye`` takes (world2cam, base2gripper) = (``cam_T_target``,
  ``inv(base_T_flange)``) and returns (base2world, gripper2cam) = (``target_T_base``,
  ``cam_T_flange``): both are the inverses of our X and Y.
"""

from __future__ import annotations

import cv2
import numpy as np

from robots import geometry as geo

HAND_EYE_METHODS = {
    "TSAI": cv2.CALIB_HAND_EYE_TSAI,
    "PARK": cv2.CALIB_HAND_EYE_PARK,
    "HORAUD": cv2.CALIB_HAND_EYE_HORAUD,
    "ANDREFF": cv2.CALIB_HAND_EYE_ANDREFF,
    "DANIILIDIS": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
ROBOT_WORLD_METHODS = {
    "SHAH": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "LI": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}


def _split(poses: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    return [T[:3, :3].copy() for T in poses], [T[:3, 3].reshape(3, 1).copy() for T in poses]


def _opencv_rotation(R, routine: str) -> np.ndarray:
    """OpenCV's rotation block, cleaned of rounding; a reflection (det < 0, which PARK's
    closed form returns on poses in the wrong convention) is refused, not projected onto one
    of its equally near rotations at random."""
    R = np.asarray(R, dtype=float)
    det = float(np.linalg.det(R))
    if not np.isfinite(det) or det <= 0.0:
        raise ValueError(f"{routine} returned a matrix that is not a rotation (det {det:.3g}): "
                         "its answer means nothing on these poses (the wrong pose convention, "
                         "or motions it cannot solve)")
    return geo.project_to_so3(R)


def opencv_hand_eye(base_T_flange, cam_T_target, mount: str = "eye_in_hand",
                    method: str = "PARK") -> np.ndarray:
    """X by ``cv2.calibrateHandEye``: ``flange_T_cam`` (eye_in_hand) or ``base_T_cam`` (eye_to_hand)."""
    robot = geo.as_poses(base_T_flange, "base_T_flange", min_count=3)
    cam = geo.as_poses(cam_T_target, "cam_T_target", min_count=3)
    if mount == "eye_to_hand":
        robot = geo.invert(robot)
    elif mount != "eye_in_hand":
        raise ValueError(f"mount must be 'eye_in_hand' or 'eye_to_hand', got {mount!r}")
    R_r, t_r = _split(robot)
    R_c, t_c = _split(cam)
    R, t = cv2.calibrateHandEye(R_r, t_r, R_c, t_c, method=HAND_EYE_METHODS[method])
    return geo.make_pose(_opencv_rotation(R, f"cv2.calibrateHandEye ({method})"), t.ravel())


def opencv_robot_world(base_T_flange, cam_T_target, mount: str = "eye_in_hand",
                       method: str = "SHAH") -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) by ``cv2.calibrateRobotWorldHandEye``, in the same meaning as the hand-eye problem.

    eye_in_hand: X = flange_T_cam, Y = base_T_target; eye_to_hand: X = base_T_cam,
    Y = flange_T_target (the robot poses are inverted, as for ``calibrateHandEye``, so the
    "world" OpenCV solves for is then our flange and its "base" our camera's parent).
    """
    robot = geo.as_poses(base_T_flange, "base_T_flange", min_count=3)
    cam = geo.as_poses(cam_T_target, "cam_T_target", min_count=3)
    if mount == "eye_in_hand":
        base2gripper = geo.invert(robot)
    elif mount == "eye_to_hand":
        base2gripper = robot
    else:
        raise ValueError(f"mount must be 'eye_in_hand' or 'eye_to_hand', got {mount!r}")
    R_w, t_w = _split(cam)
    R_b, t_b = _split(base2gripper)
    R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
        R_w, t_w, R_b, t_b, method=ROBOT_WORLD_METHODS[method])
    routine = f"cv2.calibrateRobotWorldHandEye ({method})"
    target_T_base = geo.make_pose(_opencv_rotation(R_bw, routine), t_bw.ravel())
    cam_T_flange = geo.make_pose(_opencv_rotation(R_gc, routine), t_gc.ravel())
    return geo.invert(cam_T_flange), geo.invert(target_T_base)
