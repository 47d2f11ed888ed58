"""A stand-in for the ``pyaubo_sdk`` module: the exact API surface robots/drivers/aubo.py uses.

It simulates an AUBO-i5-sized 6R arm (standard DH with the i5's link lengths) behind the RPC
client: poses are ``[x, y, z, rx, ry, rz]`` in metres with ``R = Rz(rz) Ry(ry) Rx(rx)``
(written out with elementary rotations here, independently of robots.geometry), joint angles
in radians. ``moveLine`` moves the **TCP** (flange times the TCP offset) and is asynchronous:
it returns at once, ``getExecId()`` then reports the command's id until the move's duration
has passed (controller seconds divided by ``time_scale``, and at least ``ticks_per_move``
polls) and -1 once the arm has arrived.

Like the controller (pyaubo-sdk's MotionControl documentation):

* return codes: 0 accepted; **positive codes are refusals too**: 1 (AUBO_BAD_STATE) whenever
  ``safety_mode`` is not Normal, ReducedMode or Recovery (a protective or safeguard stop,
  an emergency stop), 2 / 3 via ``reject_code``; negative codes via ``reject_code``.
* units: ``moveLine``'s ``a`` and ``v`` are m/s^2 and m/s, except when the TCP moves less than
  1 mm while turning more than 1e-4 rad: then they are rad/s^2 and rad/s. The duration and
  the turn rate that follow are recorded in ``arm.last_plan``; the turn never exceeds
  ``MAX_TCP_ROTATION_SPEED`` (what the controller saturates at).

``SDK_NAMES`` lists every attribute the driver touches; tests check the fake has them and,
where pyaubo-sdk is installed, that the real module does too.
"""

from __future__ import annotations

import enum
import time
import types
import typing

import numpy as np

SDK_NAMES = [
    "RpcClient",
    "RpcClient.setRequestTimeout",
    "RpcClient.connect",
    "RpcClient.hasConnected",
    "RpcClient.login",
    "RpcClient.logout",
    "RpcClient.disconnect",
    "RpcClient.getRobotNames",
    "RpcClient.getRobotInterface",
    "RobotInterface.getRobotState",
    "RobotInterface.getMotionControl",
    "RobotInterface.getRobotConfig",
    "RobotInterface.getIoControl",
    "RobotState.getToolPose",
    "RobotState.getTcpPose",
    "RobotState.getJointPositions",
    "RobotState.getSafetyModeType",
    "RobotConfig.getTcpOffset",
    "RobotConfig.getJointMinPositions",
    "RobotConfig.getJointMaxPositions",
    "MotionControl.moveLine",
    "MotionControl.moveJoint",
    "MotionControl.getExecId",
    "MotionControl.stopLine",
    "MotionControl.stopJoint",
    "IoControl.setStandardDigitalOutput",
    "IoControl.getStandardDigitalOutput",
    "IoControl.getStandardDigitalInput",
]

# Standard DH (d, a, alpha) of a UR-style 6R arm with the AUBO-i5's link lengths, metres.
_DH = np.array(
    [
        [0.0985, 0.0, np.pi / 2],
        [0.0, -0.408, 0.0],
        [0.0, -0.376, 0.0],
        [0.1215, 0.0, np.pi / 2],
        [0.1025, 0.0, -np.pi / 2],
        [0.094, 0.0, 0.0],
    ]
)
LIMIT = np.radians(175.0)
MAX_TCP_ROTATION_SPEED = np.pi  # rad/s the fake controller's turn saturates at
ROTATION_MODE_BELOW_M, ROTATION_THRESHOLD_RAD = 1e-3, 1e-4


class SafetyModeType(enum.IntEnum):
    """pyaubo_sdk.SafetyModeType (same member names and values)."""

    Undefined = 0
    Normal = 1
    ReducedMode = 2
    Recovery = 3
    Violation = 4
    ProtectiveStop = 5
    SafeguardStop = 6
    SystemEmergencyStop = 7
    RobotEmergencyStop = 8
    Fault = 9


MOVABLE_MODES = (SafetyModeType.Normal, SafetyModeType.ReducedMode, SafetyModeType.Recovery)
AUBO_BAD_STATE = 1
START_Q = np.array([0.0, -1.2, 1.6, -1.97, -1.57, 0.0])


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def matrix_from_pose6(p) -> np.ndarray:
    """AUBO's documented convention: R = Rz(rz) @ Ry(ry) @ Rx(rx)."""
    T = np.eye(4)
    T[:3, :3] = _rz(p[5]) @ _ry(p[4]) @ _rx(p[3])
    T[:3, 3] = p[:3]
    return T


def pose6_from_matrix(T) -> list:
    R = T[:3, :3]
    ry = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    rz = np.arctan2(R[1, 0], R[0, 0])
    rx = np.arctan2(R[2, 1], R[2, 2])
    return [*map(float, T[:3, 3]), float(rx), float(ry), float(rz)]


def flange_fk(q) -> np.ndarray:
    T = np.eye(4)
    for (d, a, alpha), theta in zip(_DH, q):
        step = np.eye(4)
        step[:3, :3] = _rz(theta) @ _rx(alpha)
        step[:3, 3] = [a * np.cos(theta), a * np.sin(theta), d]
        T = T @ step
    return T


def _error(T, goal):
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_matrix(goal[:3, :3] @ T[:3, :3].T).as_rotvec()
    return np.concatenate([goal[:3, 3] - T[:3, 3], rot])


def _ik(q, goal) -> np.ndarray:
    q = np.array(q, float)
    for _ in range(100):
        err = _error(flange_fk(q), goal)
        if np.linalg.norm(err) < 1e-11:
            return q
        J = np.empty((6, 6))
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = 1e-7
            J[:, j] = (err - _error(flange_fk(q + dq), goal)) / 1e-7
        q = q + np.linalg.solve(J.T @ J + 1e-10 * np.eye(6), J.T @ err)
    raise RuntimeError("fake AUBO IK did not converge")


class FakeArm:
    """The simulated arm and controller behind every interface object."""

    def __init__(self):
        self.q = START_Q.copy()
        self.tcp_offset = [0.0, 0.0, 0.12, 0.0, 0.0, 0.3]
        self.outputs = {}
        self.inputs = {}
        self.exec_id = -1
        self.next_id = 100
        self.pending = None  # [target q, polls left, wall-clock end]
        self.ticks_per_move = 3
        self.time_scale = 50.0  # controller seconds per wall-clock second
        self.safety_mode = SafetyModeType.Normal
        self.last_plan = None  # {"rotational", "duration_s", "rotation_rate"} of the last moveLine
        self.stuck = False  # True: a started move never finishes
        self.stops = []
        self.commands = []
        self.reject_code = None  # e.g. -1: moveLine/moveJoint refuse (not Running)


class FakeRobotState:
    def __init__(self, arm):
        self._arm = arm

    def getToolPose(self):
        return pose6_from_matrix(flange_fk(self._arm.q))

    def getTcpPose(self):
        return pose6_from_matrix(flange_fk(self._arm.q) @ matrix_from_pose6(self._arm.tcp_offset))

    def getJointPositions(self):
        return list(map(float, self._arm.q))

    def getSafetyModeType(self):
        return self._arm.safety_mode


class FakeRobotConfig:
    def __init__(self, arm):
        self._arm = arm

    def getTcpOffset(self):
        return list(self._arm.tcp_offset)

    def getJointMinPositions(self):
        return [-LIMIT] * 6

    def getJointMaxPositions(self):
        return [LIMIT] * 6


class FakeMotionControl:
    def __init__(self, arm):
        self._arm = arm

    def _queue(self, q_target, duration_s):
        arm = self._arm
        arm.exec_id, arm.next_id = arm.next_id, arm.next_id + 1
        arm.pending = [q_target, arm.ticks_per_move, time.monotonic() + duration_s / arm.time_scale]
        return 0

    def _refusal(self):
        arm = self._arm
        if arm.reject_code is not None:
            return arm.reject_code
        if arm.safety_mode not in MOVABLE_MODES:
            return AUBO_BAD_STATE
        return None

    def moveLine(self, pose, a, v, blend_radius, duration):
        arm = self._arm
        assert len(pose) == 6 and a > 0 and v > 0
        arm.commands.append(("moveLine", list(pose), a, v, blend_radius, duration))
        refused = self._refusal()
        if refused is not None:
            return refused
        start = flange_fk(arm.q) @ matrix_from_pose6(arm.tcp_offset)
        goal = matrix_from_pose6(pose)
        err = _error(start, goal)
        distance, angle = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
        if distance < ROTATION_MODE_BELOW_M and angle > ROTATION_THRESHOLD_RAD:
            rate = min(v, MAX_TCP_ROTATION_SPEED)  # v is rad/s here, a rad/s^2
            seconds = angle / rate + rate / a
            rotational = True
        else:  # v is m/s; the turn is spread over the linear cruise, up to the saturation
            cruise = distance / v
            rate = min(angle / cruise, MAX_TCP_ROTATION_SPEED) if cruise > 0 else 0.0
            seconds = max(cruise, angle / MAX_TCP_ROTATION_SPEED) + v / a
            rotational = False
        arm.last_plan = {"rotational": rotational, "duration_s": seconds, "rotation_rate": rate}
        flange_goal = goal @ np.linalg.inv(matrix_from_pose6(arm.tcp_offset))
        return self._queue(_ik(arm.q, flange_goal), seconds)

    def moveJoint(self, q, a, v, blend_radius, duration):
        arm = self._arm
        assert len(q) == 6 and a > 0 and v > 0
        arm.commands.append(("moveJoint", list(q), a, v, blend_radius, duration))
        refused = self._refusal()
        if refused is not None:
            return refused
        q = np.asarray(q, float)
        return self._queue(q, float(np.abs(q - arm.q).max()) / v + v / a)

    def getExecId(self):
        arm = self._arm
        if arm.pending is not None and not arm.stuck:
            arm.pending[1] -= 1
            if arm.pending[1] <= 0 and time.monotonic() >= arm.pending[2]:
                arm.q, arm.pending, arm.exec_id = arm.pending[0], None, -1
        return arm.exec_id

    def stopLine(self, acc, acc_rot):
        self._arm.stops.append(("stopLine", acc, acc_rot))
        self._arm.pending, self._arm.exec_id = None, -1
        return 0

    def stopJoint(self, acc):
        self._arm.stops.append(("stopJoint", acc))
        self._arm.pending, self._arm.exec_id = None, -1
        return 0


class FakeIoControl:
    def __init__(self, arm):
        self._arm = arm

    def setStandardDigitalOutput(self, pin, value):
        self._arm.outputs[int(pin)] = bool(value)
        return 0

    def getStandardDigitalOutput(self, pin):
        return self._arm.outputs.get(int(pin), False)

    def getStandardDigitalInput(self, pin):
        return self._arm.inputs.get(int(pin), False)


class FakeRobotInterface:
    def __init__(self, arm):
        self._arm = arm

    def getRobotState(self):
        return FakeRobotState(self._arm)

    def getRobotConfig(self):
        return FakeRobotConfig(self._arm)

    def getMotionControl(self):
        return FakeMotionControl(self._arm)

    def getIoControl(self):
        return FakeIoControl(self._arm)


class FakeRpcClient:
    """pyaubo_sdk.RpcClient(): connect(ip, port) -> 0, login(user, password) -> 0, ..."""

    instances: typing.ClassVar[list] = []
    reachable = True
    password = "123456"

    def __init__(self):
        self.arm = FakeArm()
        self.connected = self.logged_in = False
        self.timeout_ms = None
        FakeRpcClient.instances.append(self)

    def setRequestTimeout(self, ms):
        self.timeout_ms = ms
        return 0

    def connect(self, ip, port):
        assert port == 30004
        self.connected = type(self).reachable
        return 0 if self.connected else -8

    def hasConnected(self):
        return self.connected

    def login(self, user, password):
        self.logged_in = self.connected and password == type(self).password
        return 0 if self.logged_in else -1

    def logout(self):
        self.logged_in = False
        return 0

    def disconnect(self):
        self.connected = False
        return 0

    def getRobotNames(self):
        return ["rob1"]

    def getRobotInterface(self, name):
        assert name == "rob1" and self.logged_in
        return FakeRobotInterface(self.arm)


def make_sdk():
    """A fresh module-like namespace shaped like ``pyaubo_sdk`` (pass as ``sdk=``)."""
    FakeRpcClient.instances = []
    return types.SimpleNamespace(
        RpcClient=FakeRpcClient,
        RobotInterface=FakeRobotInterface,
        RobotState=FakeRobotState,
        SafetyModeType=SafetyModeType,
        RobotConfig=FakeRobotConfig,
        MotionControl=FakeMotionControl,
        IoControl=FakeIoControl,
    )
