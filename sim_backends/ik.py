"""Inverse kinematics that really reaches the target, on a private PyBullet model of the arm.

PyBullet's ``calculateInverseKinematics`` stops centimetres short of many targets. Here it
only supplies a starting guess; a damped least-squares (Levenberg-Marquardt) refinement with
PyBullet's Jacobian then drives the error to ~1e-7 m, and the answer is accepted only after
forward kinematics confirms the reached pose within ``POSITION_TOL_M`` and
``ROTATION_TOL_DEG``. When the seed fails, seeded random restarts try again; when every try
fails, :class:`robots.interfaces.UnreachableError` says by how much it missed and what to do.

The model is the *controller's* kinematic model: nominal URDF, base frame at the identity,
joint angles as the controller reports them. It lives in its own DIRECT client so that
solving never moves the arm that cameras see in the world.
"""

from __future__ import annotations

import itertools
import weakref
from pathlib import Path

import numpy as np
import pybullet as p

from robots.geometry import (
    pose_from_quat_xyzw,
    quat_xyzw_from_rotation,
)
from sim_backends.ik_core import (  # noqa: F401  (re-exported: their home before ik_core)
    POSITION_TOL_M,
    ROTATION_TOL_DEG,
    KinematicSolver,
    _error_vector,
    pose_error,
)

__all__ = ["POSITION_TOL_M", "ROTATION_TOL_DEG", "KinematicModel", "pose_error"]

class KinematicModel(KinematicSolver):
    """Forward kinematics, Jacobian and verified IK for one arm (base frame = identity).

    ``urdf_path``: the arm's URDF; ``joint_names``: the controlled joints in controller order;
    ``flange_link``: name of the tool0 link; ``limits``: (n, 2) rad used by the solver;
    ``rest_pose``: (n,) rad, a comfortable configuration tried early; ``reach``: metres from
    the first joint axis, used only for the "too far" hint; ``other_joints``: fixed values
    for any other movable joints in the URDF (the Panda's fingers).
    """

    def __init__(self, urdf_path, joint_names, flange_link: str, limits, rest_pose,
                 reach: float, other_joints: dict[str, float] | None = None, name: str = "arm"):
        self.name = name
        self.client = p.connect(p.DIRECT)
        # Disconnect the private client even if close() is never called.
        self._finalizer = weakref.finalize(self, _disconnect, self.client)
        self.body = p.loadURDF(str(Path(urdf_path)), useFixedBase=True, physicsClientId=self.client)
        index = {}
        movable = []
        for j in range(p.getNumJoints(self.body, physicsClientId=self.client)):
            info = p.getJointInfo(self.body, j, physicsClientId=self.client)
            index[info[1].decode()] = j
            index["link:" + info[12].decode()] = j
            if info[2] != p.JOINT_FIXED:
                movable.append(j)
        missing = [n for n in joint_names if n not in index]
        if missing or "link:" + flange_link not in index:
            raise ValueError(f"{urdf_path} lacks joints {missing} or link {flange_link!r}")
        self.joints = [index[n] for n in joint_names]
        self.n = len(self.joints)
        self.flange = index["link:" + flange_link]
        self._movable = movable
        # Columns of PyBullet's all-DOF vectors that belong to the controlled joints.
        self._cols = [movable.index(j) for j in self.joints]
        self._full_q = np.zeros(len(movable))
        for jname, value in (other_joints or {}).items():
            p.resetJointState(self.body, index[jname], value, physicsClientId=self.client)
            self._full_q[movable.index(index[jname])] = value
        self.limits = np.asarray(limits, dtype=float)
        self.rest_pose = np.asarray(rest_pose, dtype=float)
        self.reach = float(reach)
        # calculateJacobian wants the point in the link's centre-of-mass frame; we want the
        # Jacobian of the link frame origin (the flange centre).
        state = p.getLinkState(self.body, self.flange, physicsClientId=self.client)
        link_T_com = pose_from_quat_xyzw(state[3], state[2])
        self._flange_in_com = list(np.linalg.inv(link_T_com)[:3, 3])
        self._full_lo = np.full(len(movable), -np.pi)
        self._full_hi = np.full(len(movable), np.pi)
        self._full_lo[self._cols], self._full_hi[self._cols] = self.limits[:, 0], self.limits[:, 1]
        for col, j in enumerate(movable):
            if j not in self.joints:
                self._full_lo[col] = self._full_hi[col] = self._full_q[col]
        # A hard bound for the early "too far" error: the joint-2 origin lies on the joint-1
        # axis for every arm here, so it does not move, and the flange can be no further from
        # it than the sum of the (fixed) distances between the following joint origins.
        self._set(np.zeros(self.n))
        origins = [np.asarray(p.getLinkState(self.body, j, computeForwardKinematics=True,
                                             physicsClientId=self.client)[4])
                   for j in self.joints[1:] + [self.flange]]
        self._shoulder = origins[0]
        self._max_distance = float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(origins)))

    # --------------------------------------------------------------------- kinematics

    def _set(self, q: np.ndarray) -> None:
        for j, qi in zip(self.joints, q):
            p.resetJointState(self.body, j, float(qi), physicsClientId=self.client)

    def fk(self, q) -> np.ndarray:
        """``base_T_flange`` (4, 4) for joint angles ``q`` (n,) rad."""
        self._set(q)
        s = p.getLinkState(self.body, self.flange, computeForwardKinematics=True,
                           physicsClientId=self.client)
        return pose_from_quat_xyzw(s[5], s[4])

    def jacobian(self, q) -> np.ndarray:
        """(6, n) geometric Jacobian of the flange origin in the base frame: rows vx vy vz wx wy wz."""
        full = self._full_q.copy()
        full[self._cols] = q
        zeros = [0.0] * len(full)
        lin, ang = p.calculateJacobian(self.body, self.flange, self._flange_in_com, list(full),
                                       zeros, zeros, physicsClientId=self.client)
        return np.vstack([np.asarray(lin)[:, self._cols], np.asarray(ang)[:, self._cols]])

    # --------------------------------------------------------------------- IK

    def _guess(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """PyBullet's own IK from ``seed``: often centimetres short, a good start."""
        full = self._full_q.copy()
        full[self._cols] = seed
        quat = quat_xyzw_from_rotation(target[:3, :3])
        sol = p.calculateInverseKinematics(
            self.body, self.flange, list(target[:3, 3]), list(quat),
            lowerLimits=list(self._full_lo), upperLimits=list(self._full_hi),
            jointRanges=list(np.maximum(self._full_hi - self._full_lo, 1e-3)),
            restPoses=list(full), currentPositions=list(full),
            maxNumIterations=200, residualThreshold=1e-6, physicsClientId=self.client)
        return np.asarray(sol)[self._cols]

    def close(self) -> None:
        """Disconnect the private PyBullet client. Idempotent."""
        self._finalizer()


def _disconnect(client: int) -> None:
    try:
        p.disconnect(physicsClientId=client)
    except p.error:  # already gone
        pass
