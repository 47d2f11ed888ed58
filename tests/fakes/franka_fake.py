"""A stand-in for the ``panda_py`` module: the exact API surface robots/drivers/franka.py uses.

It simulates a Panda with the Franka Hand: joint angles (rad), forward kinematics from Franka's
published modified-DH parameters, ``O_T_EE`` / ``F_T_EE`` as libfranka's column-major
16-vectors, quaternions in (x, y, z, w) order as panda_py takes them, widths in metres.
Controllers track their set-point perfectly at each tick of the context (simulated time, no
sleeping), using damped least-squares IK for the Cartesian impedance controller.

``SDK_NAMES`` lists every attribute the driver touches; tests check the fake has them and,
where panda-python is installed, that the real module does too.
"""

from __future__ import annotations

import enum
import types
import typing

import numpy as np
from scipy.spatial.transform import Rotation

SDK_NAMES = [
    "Panda",
    "Panda.get_state",
    "Panda.get_joint_limits_lower",
    "Panda.get_joint_limits_upper",
    "Panda.start_controller",
    "Panda.stop_controller",
    "Panda.create_context",
    "Panda.raise_error",
    "Panda.get_robot",
    "PandaContext.ok",
    "PandaContext.num_ticks",
    "controllers.CartesianImpedance",
    "controllers.CartesianImpedance.set_control",
    "controllers.JointPosition",
    "controllers.JointPosition.set_control",
    "libfranka.RealtimeConfig.kEnforce",
    "libfranka.RealtimeConfig.kIgnore",
    "libfranka.Robot.automatic_error_recovery",
    "libfranka.RobotState.O_T_EE",
    "libfranka.RobotState.F_T_EE",
    "libfranka.RobotState.q",
    "libfranka.Gripper",
    "libfranka.Gripper.move",
    "libfranka.Gripper.grasp",
    "libfranka.Gripper.read_once",
    "libfranka.Gripper.stop",
    "libfranka.GripperState.width",
    "libfranka.GripperState.max_width",
    "libfranka.GripperState.is_grasped",
]

# Franka's modified (Craig) DH table: a_{i-1}, d_i, alpha_{i-1}; the last row is the flange.
_DH = np.array(
    [
        [0.0, 0.333, 0.0],
        [0.0, 0.0, -np.pi / 2],
        [0.0, 0.316, np.pi / 2],
        [0.0825, 0.0, np.pi / 2],
        [-0.0825, 0.384, -np.pi / 2],
        [0.0, 0.0, np.pi / 2],
        [0.088, 0.0, np.pi / 2],
        [0.0, 0.107, 0.0],
    ]
)
LOWER = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
UPPER = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
HOME_Q = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])


def _hand_F_T_EE() -> np.ndarray:
    """The Franka Hand's default end effector: 0.1034 m along the flange z, turned -45 deg."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", -np.pi / 4).as_matrix()
    T[2, 3] = 0.1034
    return T


def flange_fk(q) -> np.ndarray:
    """``O_T_F`` (base to flange) of the Panda for joint angles ``q`` (7,) radians."""
    T = np.eye(4)
    for (a, d, alpha), theta in zip(_DH, list(q) + [0.0]):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
        T = T @ np.array(
            [
                [ct, -st, 0.0, a],
                [st * ca, ct * ca, -sa, -d * sa],
                [st * sa, ct * sa, ca, d * ca],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
    return T


def _pose_error(T, goal) -> np.ndarray:
    rot = Rotation.from_matrix(goal[:3, :3] @ T[:3, :3].T).as_rotvec()
    return np.concatenate([goal[:3, 3] - T[:3, 3], rot])


class FakeRobotState:
    """libfranka.RobotState: column-major ``O_T_EE``, ``F_T_EE`` (lists of 16) and ``q``."""

    q = O_T_EE = F_T_EE = None  # class-level so the API-surface test sees the names

    def __init__(self, q, F_T_EE):
        O_T_EE = flange_fk(q) @ F_T_EE
        self.q = list(map(float, q))
        self.O_T_EE = O_T_EE.reshape(-1, order="F").tolist()
        self.F_T_EE = F_T_EE.reshape(-1, order="F").tolist()


class FakeCartesianImpedance:
    def __init__(self):
        self.target = None

    def set_control(self, position, orientation):
        position, orientation = np.asarray(position, float), np.asarray(orientation, float)
        assert position.shape == (3,) and orientation.shape == (4,)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(orientation).as_matrix()  # x, y, z, w like panda_py
        T[:3, 3] = position
        self.target = T


class FakeJointPosition:
    def __init__(self):
        self.target = None

    def set_control(self, position, velocity=None):
        position = np.asarray(position, float)
        assert position.shape == (7,)
        self.target = position


class FakeContext:
    num_ticks = 0
    def __init__(self, panda, frequency, max_runtime=0.0, max_iter=0):
        self._panda, self._dt, self._max_runtime = panda, 1.0 / frequency, max_runtime
        self.num_ticks = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def ok(self) -> bool:
        """Advance one tick (simulated time): apply the controller's latest set-point."""
        if self.num_ticks > 0:
            self._panda._tick()
        if self._panda.error is not None or self._panda.controller is None:
            return False
        if self._max_runtime and self.num_ticks * self._dt > self._max_runtime:
            return False
        self.num_ticks += 1
        return True


class FakeLibfrankaRobot:
    def __init__(self, panda):
        self._panda = panda

    def automatic_error_recovery(self):
        self._panda.recoveries += 1
        self._panda.error = None


class FakePanda:
    """panda_py.Panda(hostname, name='panda', realtime_config=RealtimeConfig.kIgnore)."""

    # Knobs for the tests, set on the class before connecting or on the instance after.
    host_realtime = True  # False: kEnforce raises like libfranka on a non-RT kernel
    instances: typing.ClassVar[list] = []

    def __init__(self, hostname, name="panda", realtime_config=None):
        if realtime_config == RealtimeConfig.kEnforce and not type(self).host_realtime:
            raise RuntimeError("libfranka: Running kernel does not have realtime capabilities.")
        self.hostname = hostname
        self.q = HOME_Q.copy()
        self.F_T_EE = _hand_F_T_EE()
        self.controller = None
        self.error = None
        self.stuck = False  # True: the arm does not follow (blocked), so moves time out
        self.stop_count = 0
        self.recoveries = 0
        self.fail_after_ticks = None  # an int: raise a reflex after that many ticks
        self._ticks = 0
        FakePanda.instances.append(self)

    def get_state(self):
        return FakeRobotState(self.q, self.F_T_EE)

    def get_joint_limits_lower(self):
        return LOWER.copy()

    def get_joint_limits_upper(self):
        return UPPER.copy()

    def get_robot(self):
        return FakeLibfrankaRobot(self)

    def start_controller(self, controller):
        if self.error is not None:
            raise RuntimeError(f"libfranka: {self.error}")
        self.controller = controller

    def stop_controller(self):
        self.stop_count += 1
        self.controller = None

    def create_context(self, frequency, max_runtime=0.0, max_iter=0):
        return FakeContext(self, frequency, max_runtime, max_iter)

    def raise_error(self):
        if self.error is not None:
            raise RuntimeError(f"libfranka: Motion aborted by reflex! [{self.error}]")

    def _tick(self):
        self._ticks += 1
        if self.fail_after_ticks is not None and self._ticks >= self.fail_after_ticks:
            self.error = "cartesian_reflex"
            self.controller = None
            return
        c = self.controller
        if self.stuck or c is None or c.target is None:
            return
        if isinstance(c, FakeJointPosition):
            self.q = np.clip(c.target, LOWER, UPPER)
        else:
            self.q = self._ik(c.target @ np.linalg.inv(self.F_T_EE))

    def _ik(self, goal_flange) -> np.ndarray:
        q = self.q.copy()
        for _ in range(50):
            err = _pose_error(flange_fk(q), goal_flange)
            if np.linalg.norm(err) < 1e-10:
                break
            J = np.empty((6, 7))
            for j in range(7):
                dq = np.zeros(7)
                dq[j] = 1e-7
                J[:, j] = -_pose_error(flange_fk(q + dq), goal_flange) + err
            J /= 1e-7
            q = np.clip(q + J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), err), LOWER, UPPER)
        return q


class RealtimeConfig(enum.IntEnum):
    kEnforce = 0
    kIgnore = 1


class FakeGripperState:
    width = max_width = is_grasped = None
    def __init__(self, width, max_width, is_grasped):
        self.width, self.max_width, self.is_grasped = width, max_width, is_grasped


class FakeGripper:
    """libfranka.Gripper(franka_address): widths in metres, speed m/s, force N."""

    max_width = 0.08

    def __init__(self, franka_address):
        self.width = self.max_width
        self.object_width = None  # metres; set to put an object between the fingers
        self.grasped = False
        self.stopped = False
        self.calls = []

    def read_once(self):
        return FakeGripperState(self.width, self.max_width, self.grasped)

    def move(self, width, speed):
        self.calls.append(("move", width, speed))
        if self.object_width is not None and width < self.object_width:
            self.width, self.grasped = self.object_width, False
            return False
        self.width, self.grasped = width, False
        return True

    def grasp(self, width, speed, force, epsilon_inner=0.005, epsilon_outer=0.005):
        self.calls.append(("grasp", width, speed, force, epsilon_inner, epsilon_outer))
        self.width = 0.0 if self.object_width is None else self.object_width
        self.grasped = width - epsilon_inner <= self.width <= width + epsilon_outer
        return self.grasped

    def stop(self):
        self.stopped = True
        return True


def make_sdk():
    """A fresh module-like namespace shaped like ``panda_py`` (pass as ``sdk=``)."""
    FakePanda.instances = []
    return types.SimpleNamespace(
        Panda=FakePanda,
        PandaContext=FakeContext,
        controllers=types.SimpleNamespace(
            CartesianImpedance=FakeCartesianImpedance, JointPosition=FakeJointPosition
        ),
        libfranka=types.SimpleNamespace(
            RealtimeConfig=RealtimeConfig,
            Robot=FakeLibfrankaRobot,
            RobotState=FakeRobotState,
            Gripper=FakeGripper,
            GripperState=FakeGripperState,
        ),
    )
