"""Lab 0 (frames and poses): classic mistakes in invert_pose, compose_chain, pose_from_rotvec.

Each function is the notebook's answer with one bug a student really makes; the words are
the student's, the family the one a general rule would name (see ``mistake_corpus``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mistake_corpus import register

mistake = register("lab0_frames")


def _skew(k):
    return np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])


# --------------------------------------------------------------------------- invert_pose


@mistake("invert_pose", "sign",
         "I transposed R but forgot the minus sign: I wrote t' = R^T t, not -R^T t")
def inv_translation_sign(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    b_T_a = np.eye(4)
    b_T_a[:3, :3] = R.T
    b_T_a[:3, 3] = R.T @ t
    return b_T_a


@mistake("invert_pose", "none",
         "I wrote into a_T_b itself (no .copy()), so R, a view, was already transposed when "
         "I computed the translation", names=r"copy|view|in place|overwr")
def inv_overwrites_view(a_T_b):
    b_T_a = a_T_b
    R, t = b_T_a[:3, :3], b_T_a[:3, 3]
    b_T_a[:3, :3] = R.T
    b_T_a[:3, 3] = -R.T @ t
    return b_T_a


@mistake("invert_pose", "none",
         "I took the translation from the last row, T[3, :3], instead of the last column",
         names=r"row|column")
def inv_translation_from_row(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[3, :3]
    b_T_a = np.eye(4)
    b_T_a[:3, :3] = R.T
    b_T_a[:3, 3] = -R.T @ t
    return b_T_a


@mistake("invert_pose", "none",
         "I started from np.zeros((4, 4)) and never set the 1 in the corner",
         names=r"last row")
def inv_zeros_corner(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    b_T_a = np.zeros((4, 4))
    b_T_a[:3, :3] = R.T
    b_T_a[:3, 3] = -R.T @ t
    return b_T_a


# --------------------------------------------------------------------------- compose_chain


@mistake("compose_chain", "none", "I used * between the poses, which multiplies element by "
         "element, not @", names=r"element|@|matmul")
def chain_elementwise(poses):
    out = np.eye(4)
    for T in poses:
        out = out * T
    return out


@mistake("compose_chain", "none", "I started from poses[0] and then looped over all the "
         "poses, so the first one is multiplied in twice",
         names=r"first pose.{0,30}twice|twice|poses\[0\]")
def chain_first_twice(poses):
    out = np.array(poses[0], dtype=float)
    for T in poses:
        out = out @ T
    return out


@mistake("compose_chain", "none", "I used np.linalg.multi_dot, which refuses a chain of "
         "one pose", names=r"one pose|single pose|multi_dot")
def chain_multi_dot(poses):
    return np.linalg.multi_dot([np.asarray(T, dtype=float) for T in poses])


@mistake("compose_chain", "none", "off by one: my loop ran over range(len(poses) - 1), so "
         "the last pose was left out", names=r"last pose|left out|off by one")
def chain_skips_last(poses):
    out = np.eye(4)
    for i in range(len(poses) - 1):
        out = out @ poses[i]
    return out


@mistake("compose_chain", "none", "I stacked the poses into a float32 array to save memory, "
         "so the product lost precision", names=r"float32|precision")
def chain_float32(poses):
    stack = np.array(poses, dtype=np.float32)
    out = np.eye(4, dtype=np.float32)
    for T in stack:
        out = out @ T
    return out


# --------------------------------------------------------------------------- pose_from_rotvec


@mistake("pose_from_rotvec", "none", "I halved the angle, as for a quaternion, in "
         "Rodrigues' formula", names=r"half|twice|angle")
def rotvec_half_angle(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 1e-12:
        K = _skew(rvec / theta)
        half = theta / 2.0
        T[:3, :3] = np.eye(3) + np.sin(half) * K + (1.0 - np.cos(half)) * K @ K
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "none", "I built the quaternion as [w, x, y, z] but scipy's "
         "from_quat reads [x, y, z, w]", names=r"quaternion|xyzw|wxyz|scalar")
def rotvec_quat_wxyz(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    xyz = rvec * (np.sin(theta / 2.0) / theta) if theta > 1e-12 else np.zeros(3)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([np.cos(theta / 2.0), *xyz]).as_matrix()
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "none", "I wrote (1 - cos theta) K instead of (1 - cos theta) "
         "K^2 in Rodrigues' formula", names=r"K\s*@\s*K|K\^2|K²|square of K")
def rotvec_k_not_squared(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 1e-12:
        K = _skew(rvec / theta)
        T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "none", "I did not normalise the axis: K is the skew matrix of "
         "rvec itself, not of rvec / |rvec|", names=r"normali[sz]|\bunit\b")
def rotvec_axis_not_normalised(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    K = _skew(rvec)
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K @ K
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "units rad/deg", "I converted the angle to degrees to print it "
         "and then passed that to np.sin and np.cos")
def rotvec_degrees_in_trig(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 1e-12:
        K = _skew(rvec / theta)
        angle = np.degrees(theta)
        T[:3, :3] = np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "swapped arguments", "my def line had the arguments as (t, "
         "rvec), the other way round from the call")
def rotvec_parameters_swapped(t, rvec):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 1e-12:
        K = _skew(rvec / theta)
        T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K @ K
    T[:3, 3] = t
    return T


@mistake("pose_from_rotvec", "none", "I put t in the last row, T[3, :3], instead of the "
         "last column", names=r"last row|column")
def rotvec_t_in_row(rvec, t):
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    T = np.eye(4)
    if theta > 1e-12:
        K = _skew(rvec / theta)
        T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K @ K
    T[3, :3] = t
    return T
