"""Simulated robot arms in PyBullet (the engine-neutral part: ``arm_motion``, ``arm_specs``): Franka Panda, UR5e, UR10e, Aubo-i5, Denso Cobotta.

Frames (what ``flange_pose`` returns, chosen to equal what the real controller reports):

* ``panda``: base = ``panda_link0`` (Franka's O frame); flange = ``panda_link8``, 0.107 m
  beyond joint 7 along its z axis. This is Franka's ``O_T_EE`` with the end effector set to
  "none" (``F_T_EE = NE_T_EE = identity``), i.e. ``O_T_F``. With the Franka Hand configured,
  Desk's default is ``F_T_EE = Rz(-45 deg)`` with 0.1034 m along z; that is the gripper tool's
  ``flange_T_tcp`` here, not part of the flange.
* ``ur5e`` / ``ur10e``: base = the controller's ``base`` frame (ROS ``base``, which is ROS
  ``base_link`` turned 180 deg about z); flange = ``tool0`` = DH frame 6. The pose equals
  RTDE ``actual_TCP_pose`` / the teach pendant with a zero TCP offset.
* ``aubo_i5``: base = Aubo's DH frame 0 (98.5 mm below the J2 axis; the mounting face, ROS
  ``base_link``, is 23.5 mm lower, see ``ArmSpec.base_T_mount``); flange = DH frame 6.
* ``cobotta``: base = Denso's ``base_link`` (mounting face on the J1 axis); flange = J6 frame.

Motion is kinematic: joint states are set directly (``resetJointState``) along an
interpolated path and the world is stepped once per waypoint, so held objects (moved with the
flange) and everything else stay deterministic. Realism knob: ``encoder_offsets``, added to
the true joint angles in everything the "controller" reports, so the reported flange pose is
slightly wrong, as on a real robot whose joint zeros are off.
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from robots.geometry import (
    as_pose,
    invert,
    pose_from_quat_xyzw,
    quat_xyzw_from_pose,
    quat_xyzw_from_rotation,
)
from sim_backends.arm_motion import (  # noqa: F401  (re-exported: their home before the split)
    JOINT_STEP_RAD,
    LINEAR_STEP_M,
    LINEAR_STEP_RAD,
    MAX_WAYPOINT_JOINT_JUMP_RAD,
    ArmMotion,
)
from sim_backends.arm_specs import (  # noqa: F401  (re-exported, as above)
    ARM_NAMES,
    ARM_SPECS,
    DEG,
    URDF_DIR,
    ArmSpec,
    _as_q,
    render_urdf,
)
from sim_backends.arm_specs import render_urdf as _render_urdf  # noqa: F401  (its old name)
from sim_backends.ik import KinematicModel

__all__ = ["ARM_NAMES", "ARM_SPECS", "ArmSpec", "SimArm"]


class SimArm(ArmMotion):
    """One arm in a PyBullet world (``client``, a DIRECT physics client id).

    ``name``: one of ``ARM_NAMES``. ``world_T_base`` (4, 4, default identity): where the controller's base frame
    sits in the world. ``encoder_offsets`` (n,) rad: reported = true + offset (None: zeros).
    ``rng``: a ``np.random.Generator`` or int; it picks the seed of the IK restarts, so a run
    is reproducible for a seed. The arm starts at ``spec.home`` (as reported).

    Attributes: ``body_id``, ``flange_link`` (tool0 link index in the world body),
    ``n_joints``, ``spec`` (:class:`ArmSpec`), ``model`` (the controller's
    :class:`~sim_backends.ik.KinematicModel`), ``motion_time`` (s of simulated motion so far).
    """

    def __init__(self, client: int, name: str, world_T_base=None, encoder_offsets=None,
                 rng=None):
        if not p.isConnected(physicsClientId=client):
            raise ValueError(f"PyBullet client {client} is not connected; create it with "
                             "pybullet.connect(pybullet.DIRECT) first")
        self.client = client
        self._init_state(name, world_T_base, encoder_offsets, rng)
        spec = self.spec

        pos, quat = self.world_T_base[:3, 3], quat_xyzw_from_pose(self.world_T_base)[0]
        visual_urdf = render_urdf(spec)
        self.body_id = p.loadURDF(str(visual_urdf), list(pos), list(quat), useFixedBase=True,
                                  physicsClientId=client)
        index = {}
        for j in range(p.getNumJoints(self.body_id, physicsClientId=client)):
            info = p.getJointInfo(self.body_id, j, physicsClientId=client)
            index[info[1].decode()] = j
            index["link:" + info[12].decode()] = j
        self.joint_indices = [index[n] for n in spec.joint_names]
        self.flange_link = index["link:" + spec.flange_link]
        self.hand_link_indices = [index["link:" + n] for n in spec.hand_links]
        self._other = {index[n]: v for n, v in spec.other_joints.items()}
        self.model = KinematicModel(spec.urdf, spec.joint_names, spec.flange_link,
                                    spec.joint_limits, spec.home, spec.reach,
                                    other_joints=spec.other_joints, name=name)
        self.set_joint_positions(spec.home)

    # ----------------------------------------------------------------- engine's part

    def world_T_flange(self) -> np.ndarray:
        """True pose (4, 4) of the flange in the world (ground truth; where the camera really is)."""
        s = p.getLinkState(self.body_id, self.flange_link, computeForwardKinematics=True,
                           physicsClientId=self.client)
        return pose_from_quat_xyzw(s[5], s[4])

    def _step_world(self) -> None:
        p.stepSimulation(physicsClientId=self.client)
        # A step may nudge the joints (gravity against the holding motors); the kinematic
        # state is the truth, so put it back exactly.
        self._apply_true(self._q_true)

    # ----------------------------------------------------------------- attachments

    def attach(self, body_id: int, flange_T_body=None) -> None:
        """Carry ``body_id`` with the flange (kinematically) at ``flange_T_body`` (default: as it is now)."""
        if flange_T_body is None:
            pos, quat = p.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
            flange_T_body = invert(self.world_T_flange()) @ pose_from_quat_xyzw(quat, pos)
        self._attached[int(body_id)] = as_pose(flange_T_body, "flange_T_body")

    def close(self) -> None:
        """Release the private kinematics client. The world body stays (the world owns it)."""
        self.model.close()

    # ----------------------------------------------------------------- internals

    def _apply_true(self, q_true: np.ndarray) -> None:
        self._q_true = np.array(q_true, dtype=float)
        c = self.client
        for j, qi in zip(self.joint_indices, self._q_true):
            p.resetJointState(self.body_id, j, float(qi), physicsClientId=c)
        for j, qi in self._other.items():
            p.resetJointState(self.body_id, j, float(qi), physicsClientId=c)
        # Position motors hold the pose during physics steps.
        joints = self.joint_indices + list(self._other)
        targets = list(self._q_true) + list(self._other.values())
        p.setJointMotorControlArray(self.body_id, joints, p.POSITION_CONTROL,
                                    targetPositions=targets, forces=[500.0] * len(joints),
                                    physicsClientId=c)
        if self._attached:
            world_T_flange = self.world_T_flange()
            for body, flange_T_body in self._attached.items():
                T = world_T_flange @ flange_T_body
                pos, quat = T[:3, 3], quat_xyzw_from_rotation(T[:3, :3])
                p.resetBasePositionAndOrientation(body, list(pos), list(quat), physicsClientId=c)
                p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=c)

    def set_finger_positions(self, opening_each: float) -> None:
        """Set the built-in fingers (Panda) to ``opening_each`` m from the centre, held there."""
        for j in self._other:
            self._other[j] = float(opening_each)
        self._apply_true(self._q_true)

    def __repr__(self) -> str:
        return f"SimArm(name={self.name!r}, client={self.client}, body={self.body_id})"
