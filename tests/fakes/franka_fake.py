"""A stand-in for the ``panda_py`` module: the exact API surface robots/drivers/franka.py uses.

It simulates a Panda with the Franka Hand: joint angles (rad), forward kinematics from Franka's
published modified-DH parameters, ``O_T_EE`` / ``F_T_EE`` as libfranka's column-major
16-vectors, quaternions in (x, y, z, w) order as panda_py takes them, widths in metres.
Controllers follow their set-point at each tick of the context (simulated time, no sleeping),
using damped least-squares IK for the Cartesian impedance controller, but like the real
impedance controllers (no integral action: friction and model error balance the spring) they
settle **short** and stay there: ``SHORT_M`` = 1.5 mm and ``SHORT_RAD`` = 1.5e-3 rad back
along the move (a pure turn sags 1.5 mm down), and every moved joint ``SHORT_RAD`` short.
``RobotState.dq`` is the joint velocity of the last tick. The Hand reports ``max_width`` 0
until it has been homed, since libfranka measures the maximum width by homing.

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
    "libfranka.RobotState.dq",
    "libfranka.Gripper",
    "libfranka.Gripper.move",
    "libfranka.Gripper.grasp",
    "libfranka.Gripper.read_once",
    "libfranka.Gripper.stop",
    "libfranka.Gripper.homing",
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
SHORT_M, SHORT_RAD = 1.5e-3, 1.5e-3  # where the impedance controllers settle, short of the goal


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

    q = dq = O_T_EE = F_T_EE = None  # class-level so the API-surface test sees the names

    def __init__(self, q, F_T_EE, dq=None):
        O_T_EE = flange_fk(q) @ F_T_EE
        self.q = list(map(float, q))
        self.dq = [0.0] * 7 if dq is None else list(map(float, dq))
        self.O_T_EE = O_T_EE.reshape(-1, order="F").tolist()
        self.F_T_EE = F_T_EE.reshape(-1, order="F").tolist()


class FakeCartesianImpedance:
    def __init__(self):
        self.target = None
        self.q_nullspace = None  # None: the caller left panda_py's default (the home posture)

    def set_control(self, position, orientation, q_nullspace=None):
        position, orientation = np.asarray(position, float), np.asarray(orientation, float)
        assert position.shape == (3,) and orientation.shape == (4,)
        if q_nullspace is not None:
            q_nullspace = np.asarray(q_nullspace, float)
            assert q_nullspace.shape == (7,)
        self.q_nullspace = q_nullspace
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
        self.realtime_config = realtime_config
        self.q = HOME_Q.copy()
        self.F_T_EE = _hand_F_T_EE()
        self.controller = None
        self.error = None
        self.stuck = False  # True: the arm does not follow (blocked), so moves time out
        self.stop_count = 0
        self.recoveries = 0
        self.fail_after_ticks = None  # an int: raise a reflex after that many ticks
        self.settles_short = True  # False: an ideal controller that reaches the set-point
        self.dq = np.zeros(7)
        self.controllers = []  # every controller started, in order
        self._frequency = 1000.0
        self._start_q = self.q.copy()
        self._ticks = 0
        FakePanda.instances.append(self)

    def get_state(self):
        return FakeRobotState(self.q, self.F_T_EE, self.dq)

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
        self.controllers.append(controller)
        self._start_q = self.q.copy()

    def stop_controller(self):
        self.stop_count += 1
        self.controller = None

    def create_context(self, frequency, max_runtime=0.0, max_iter=0):
        self._frequency = frequency
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
        before = self.q.copy()
        if not (self.stuck or c is None or c.target is None):
            if isinstance(c, FakeJointPosition):
                self.q = np.clip(self._short_joints(c.target), LOWER, UPPER)
            else:
                self.q = self._ik(self._short_pose(c.target) @ np.linalg.inv(self.F_T_EE))
        self.dq = (self.q - before) * self._frequency

    def _short_joints(self, target):
        if not self.settles_short:
            return target
        step = target - self._start_q
        return target - np.sign(step) * np.minimum(np.abs(step), SHORT_RAD)

    def _short_pose(self, target_ee):
        """Where the impedance controller settles for set-point ``target_ee``."""
        if not self.settles_short:
            return target_ee
        start = flange_fk(self._start_q) @ self.F_T_EE
        out = target_ee.copy()
        travel = target_ee[:3, 3] - start[:3, 3]
        n = np.linalg.norm(travel)
        out[:3, 3] -= travel / n * min(n, SHORT_M) if n > 1e-6 else [0.0, 0.0, SHORT_M]
        turn = Rotation.from_matrix(target_ee[:3, :3] @ start[:3, :3].T).as_rotvec()
        angle = np.linalg.norm(turn)
        back = -turn / angle * min(angle, SHORT_RAD) if angle > 1e-6 else [SHORT_RAD, 0.0, 0.0]
        out[:3, :3] = Rotation.from_rotvec(back).as_matrix() @ target_ee[:3, :3]
        return out

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
    """libfranka.Gripper(franka_address): widths in metres, speed m/s, force N.

    ``max_width`` reads 0 until ``homing()`` has measured it (``HAND_MAX_WIDTH``).
    """

    HAND_MAX_WIDTH = 0.08
    homing_fails = False  # True: homing reports failure (something blocks the fingers)
    instances: typing.ClassVar[list] = []

    def __init__(self, franka_address):
        self.max_width = 0.0
        self.width = 0.05  # wherever the fingers were left
        self.object_width = None  # metres; set to put an object between the fingers
        self.grasped = False
        self.stopped = False
        self.calls = []
        FakeGripper.instances.append(self)

    def homing(self):
        self.calls.append(("homing",))
        if type(self).homing_fails:
            return False
        self.max_width = self.width = self.HAND_MAX_WIDTH
        return True

    def read_once(self):
        return FakeGripperState(self.width, self.max_width, self.grasped)

    def move(self, width, speed):
        self.calls.append(("move", width, speed))
        if not 0.0 <= width <= self.HAND_MAX_WIDTH:
            raise RuntimeError("libfranka gripper: command width out of range")
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
    FakeGripper.instances = []
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
