"""A simulated arm in a MuJoCo world, and its controller's kinematics on MuJoCo.

:class:`MujocoArm` is an ``arm_motion.ArmMotion`` (encoder offsets, verified IK, joint and
linear paths, Safety through ``SimRobot``: all shared with the PyBullet arm); here are only
the engine's four parts. Motion is kinematic, as in the PyBullet engine: the joints are set
(``qpos``) and forward kinematics run at every waypoint, with one physics step per waypoint
when something in the world moves by itself (the chess pieces); bodies fixed to the flange
in the model (the flange target, the tool) ride along exactly, and a held piece is carried
(its free joint set from the flange pose) until it is released.

:class:`MujocoKinematics` is the controller's nominal model (the arm's own URDF, base at the
identity, in its own ``MjData`` so solving never moves the arm the cameras see), giving
``ik_core.KinematicSolver`` forward kinematics (``mj_kinematics``) and the flange origin's
geometric Jacobian (``mj_jacBody``, world = base frame). It has no IK guess of its own; the
solver's seed, rest pose and seeded random restarts find the branch.
"""

from __future__ import annotations

import itertools

import numpy as np

from robots.geometry import invert, make_pose
from sim_backends.arm_motion import ArmMotion
from sim_backends.ik_core import KinematicSolver
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.mujoco_model import mj_quat

mujoco = import_mujoco()

__all__ = ["MujocoArm", "MujocoKinematics"]


def _joint_addresses(model, joint_names) -> list[int]:
    missing = [n for n in joint_names if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) < 0]
    if missing:
        raise ValueError(f"the MuJoCo model lacks joints {missing}")
    return [int(model.jnt_qposadr[model.joint(n).id]) for n in joint_names]


def _body_pose(data, body_id: int) -> np.ndarray:
    return make_pose(data.xmat[body_id].reshape(3, 3), data.xpos[body_id])


def _set_free_pose(model, data, body: int, world_T_body: np.ndarray) -> None:
    """Teleport a free body to a world pose, at rest."""
    joint = model.body_jntadr[body]
    qadr, dadr = model.jnt_qposadr[joint], model.jnt_dofadr[joint]
    data.qpos[qadr:qadr + 3] = world_T_body[:3, 3]
    data.qpos[qadr + 3:qadr + 7] = mj_quat(world_T_body[:3, :3])
    data.qvel[dadr:dadr + 6] = 0.0


class MujocoKinematics(KinematicSolver):
    """FK, Jacobian and verified IK of one arm on its nominal MuJoCo model (see module doc).

    ``model``: a compiled ``MjModel`` of the arm alone (``mujoco_model.arm_spec(spec,
    drawn=False).compile()``); the other arguments as ``sim_backends.ik.KinematicModel``.
    """

    def __init__(self, model, joint_names, flange_link: str, limits, rest_pose,
                 reach: float, name: str = "arm"):
        self.name = name
        self.model = model
        self.data = mujoco.MjData(model)
        self._qadr = _joint_addresses(model, joint_names)
        self._dofs = [int(model.jnt_dofadr[model.joint(n).id]) for n in joint_names]
        self.n = len(self._qadr)
        self.flange = int(model.body(flange_link).id)
        self.limits = np.asarray(limits, dtype=float)
        self.rest_pose = np.asarray(rest_pose, dtype=float)
        self.reach = float(reach)
        # The "too far" bound, as in the PyBullet model: joint 2's origin (on joint 1's axis)
        # does not move, and the flange is at most the sum of the following link lengths away.
        self._set(np.zeros(self.n))
        bodies = [int(model.jnt_bodyid[model.joint(n).id]) for n in joint_names[1:]]
        origins = [self.data.xpos[b].copy() for b in bodies + [self.flange]]
        self._shoulder = origins[0]
        self._max_distance = float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(origins)))
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    def _set(self, q: np.ndarray) -> None:
        self.data.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, self.data)

    def fk(self, q) -> np.ndarray:
        """``base_T_flange`` (4, 4) for joint angles ``q`` (n,) rad."""
        self._set(np.asarray(q, dtype=float))
        return _body_pose(self.data, self.flange)

    def jacobian(self, q) -> np.ndarray:
        """(6, n) geometric Jacobian of the flange origin in the base frame: rows vx vy vz wx wy wz."""
        self._set(np.asarray(q, dtype=float))
        mujoco.mj_comPos(self.model, self.data)  # the Jacobian needs the motion subspaces
        mujoco.mj_jacBody(self.model, self.data, self._jacp, self._jacr, self.flange)
        return np.vstack([self._jacp[:, self._dofs], self._jacr[:, self._dofs]])

    def close(self) -> None:
        """Nothing to release (the model and data are plain memory)."""


class MujocoArm(ArmMotion):
    """One arm in a MuJoCo world (``world``: a ``mujoco_world.MujocoWorld``).

    ``name``, ``world_T_base``, ``encoder_offsets`` and ``rng`` as ``arm_motion.ArmMotion``;
    ``nominal_model``: the compiled nominal arm model for the controller's kinematics. The
    arm starts at ``spec.home`` (as reported). ``flange_body`` is tool0's body id.
    """

    def __init__(self, world, name: str, nominal_model, world_T_base=None, encoder_offsets=None,
                 rng=None):
        self._init_state(name, world_T_base, encoder_offsets, rng)
        spec = self.spec
        self.world = world
        self._qadr = _joint_addresses(world.model, spec.joint_names)
        self._dofs = [int(world.model.jnt_dofadr[world.model.joint(n).id])
                      for n in spec.joint_names]
        self.flange_body = int(world.model.body(spec.flange_link).id)
        self._held_joints: dict[int, float] = {}  # qpos address -> value (a tool's fingers)
        self.model = MujocoKinematics(nominal_model, spec.joint_names, spec.flange_link,
                                      spec.joint_limits, spec.home, spec.reach, name=name)
        self.set_joint_positions(spec.home)

    def world_T_flange(self) -> np.ndarray:
        """True pose (4, 4) of the flange in the world (ground truth; where the camera really is)."""
        return _body_pose(self.world.data, self.flange_body)

    def _apply_true(self, q_true: np.ndarray) -> None:
        model, data = self.world.model, self.world.data
        self._q_true = np.array(q_true, dtype=float)
        data.qpos[self._qadr] = self._q_true
        data.qvel[self._dofs] = 0.0
        for adr, value in self._held_joints.items():
            data.qpos[adr] = value
        mujoco.mj_kinematics(model, data)
        if self._attached:
            world_T_flange = self.world_T_flange()
            for body, flange_T_body in self._attached.items():
                _set_free_pose(model, data, body, world_T_flange @ flange_T_body)
            mujoco.mj_kinematics(model, data)

    def _step_world(self) -> None:
        # One physics step for what moves by itself (the chess pieces); the arm and what it
        # carries are then put back exactly where the path says.
        if self.world.dynamic:
            mujoco.mj_step(self.world.model, self.world.data)
            self._apply_true(self._q_true)

    def hold_joint(self, qpos_address: int, value: float) -> None:
        """Keep a tool's joint (a finger) at ``value`` (m or rad) from now on, kinematically."""
        self._held_joints[int(qpos_address)] = float(value)
        self._apply_true(self._q_true)

    def attach(self, body_id: int, flange_T_body=None) -> None:
        """Carry the free body ``body_id`` with the flange at ``flange_T_body`` (default: as it
        is now); it leaves physics until ``detach``."""
        if flange_T_body is None:
            flange_T_body = invert(self.world_T_flange()) @ _body_pose(self.world.data, body_id)
        self._attached[int(body_id)] = np.asarray(flange_T_body, dtype=float)

    def close(self) -> None:
        """Nothing to release: the world owns the model (and frees its renderer)."""

    def __repr__(self) -> str:
        return f"MujocoArm(name={self.name!r})"
