"""AUBO-i5 driver, through AUBO's ``pyaubo-sdk`` (imported as ``pyaubo_sdk``), RPC on port 30004.

Conventions of the SDK (from its API documentation) and how they are mapped here
------------------------------------------------------------------------------
* A pose is ``[x, y, z, rx, ry, rz]``: metres, and ZYX Euler angles in radians meaning
  ``R = Rz(rz) @ Ry(ry) @ Rx(rx)`` (roll about the fixed x, then pitch about the fixed y, then
  yaw about the fixed z; the teach pendant's "RPY"). That is exactly
  :func:`robots.geometry.pose_from_rpy` ``(roll=rx, pitch=ry, yaw=rz)``; see
  :func:`pose_from_aubo` / :func:`aubo_from_pose`.
* ``RobotState.getToolPose()`` is the flange centre in the base frame *without* the TCP offset,
  so ``flange_pose()`` reads it directly. ``RobotState.getTcpPose()`` includes the offset.
* ``MotionControl.moveLine(pose, a, v, blend_radius, duration)`` moves the **TCP** (the active
  offset from ``RobotConfig.getTcpOffset()``, same 6-vector convention, in the flange frame), so
  ``move_to`` sends ``base_T_flange @ flange_T_tcp_offset``. The robot's TCP setting is read,
  never changed, so the pendant is left as it was.
* ``moveLine``/``moveJoint`` only queue the motion and return at once. They return 0 when
  the motion was accepted; *every* other value is a refusal and nothing moves: negative codes
  are errors (-1: the arm is not in Running mode, -4: the call timed out, -5: a bad argument)
  and positive codes are refusals too (1 ``AUBO_BAD_STATE``: the safety mode is not Normal,
  Reduced or Recovery, e.g. a protective or safeguard stop; 2 ``AUBO_QUEUE_FULL``: the
  trajectory queue is full; 3 ``AUBO_BUSY``: the previous command is still running). The
  driver raises :class:`AuboRefusedError` naming the cause and the fix at once.
  ``MotionControl.getExecId()`` is the id of the command being executed and -1 when idle;
  :meth:`AuboRobot._wait_arrival` waits for it to start and then to end, and stops the robot
  (``stopLine`` / ``stopJoint``) and raises :class:`AuboTimeoutError` if it takes longer than
  the planned duration plus ``motion_timeout_s``. A move that ends away from its target
  raises :class:`AuboMotionError`, so nothing is reported as done that was not done.
* Units of ``moveLine(pose, a, v, ...)``: ``a`` in m/s^2 and ``v`` in m/s, **except** when
  the TCP moves less than 1 mm while turning more than 1e-4 rad: then the controller reads
  ``a`` and ``v`` as rad/s^2 and rad/s. :func:`plan_line` chooses the units the controller
  will apply, limits the turn to ``max_rotation_speed`` (rad/s) in every case, and times the
  move from whichever of translation and rotation takes longer.
* The suction cup is a standard digital output: ``IoControl.setStandardDigitalOutput(pin, on)``.
"""

from __future__ import annotations

import importlib
import time

import numpy as np

from robots.backends import BackendNotAvailableError
from robots.drivers._common import ROTATION_LEVER_M
from robots.geometry import (
    as_pose,
    pose_from_rpy,
    rotation_error_deg,
    rpy_from_pose,
    translation_error,
)
from robots.interfaces import Robot, RobotDisconnectedError, SuctionCup, Workcell

__all__ = [
    "AuboError",
    "AuboMotionError",
    "AuboRefusedError",
    "AuboRobot",
    "AuboSuctionCup",
    "AuboTimeoutError",
    "aubo_from_pose",
    "create_workcell",
    "plan_line",
    "pose_from_aubo",
]

DEFAULT_PORT = 30004


class AuboError(RuntimeError):
    """The controller refused a request or the connection failed."""


class AuboMotionError(AuboError):
    """A move was rejected or ended away from its target."""


class AuboTimeoutError(AuboMotionError, TimeoutError):
    """A move did not finish in time; the robot was stopped."""


class AuboRefusedError(AuboMotionError):
    """The controller refused to queue a move (``code`` is its return value); nothing moved."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


# moveLine's rule (pyaubo-sdk's MotionControl documentation): below this TCP displacement,
# with a turn above ROTATION_THRESHOLD_RAD, ``a`` and ``v`` are rotational (rad/s^2, rad/s).
ROTATION_MODE_BELOW_M = 1e-3
ROTATION_THRESHOLD_RAD = 1e-4

# What a refusal code means and what to do about it (pyaubo-sdk's moveLine/moveJoint docs).
_REFUSALS = {
    1: ("the controller's safety mode is {mode}, not Normal",
        "clear the stop on the teach pendant (release the emergency stop button, close the "
        "safeguard or reset the protective stop), then move again"),
    2: ("the controller's trajectory queue is full",
        "call robot.stop() and wait until the arm stands still, then move again"),
    3: ("the previous command is still running",
        "wait for it to finish or call robot.stop(), then move again"),
    -1: ("the arm is not in Running mode",
         "power it on and release the brakes on the pendant (Startup), then move again"),
    -4: ("the request timed out", "check the network link to the controller"),
    -5: ("the target has the wrong length", "this is a driver bug; please report it"),
}


def plan_line(distance_m: float, angle_rad: float, speed: float, acceleration: float,
              max_rotation_speed: float, rotation_acceleration: float):
    """``(a, v, planned_s, rotational)`` for a ``moveLine`` of the TCP.

    ``distance_m``: TCP displacement (m); ``angle_rad``: its turn (rad); ``speed`` (m/s) and
    ``acceleration`` (m/s^2) as asked. The turn runs at ``min(max_rotation_speed, speed /
    ROTATION_LEVER_M)`` rad/s at most. Below 1 mm of displacement (with a turn above 1e-4
    rad) the controller reads a and v as rad/s^2 and rad/s, so they are sent that way
    (``rotational`` True); otherwise the linear speed is lowered until the turn keeps to its
    rate. ``planned_s`` is the cruise time plus one ramp (v / a).
    """
    omega = min(float(max_rotation_speed), speed / ROTATION_LEVER_M)
    if distance_m < ROTATION_MODE_BELOW_M and angle_rad > ROTATION_THRESHOLD_RAD:
        return rotation_acceleration, omega, angle_rad / omega + omega / rotation_acceleration, True
    v = speed
    if angle_rad > 0 and distance_m > 0 and angle_rad / omega > distance_m / speed:
        v = distance_m * omega / angle_rad  # the turn sets the pace: slow the line to it
    return acceleration, v, distance_m / v + v / acceleration, False


def pose_from_aubo(pose6) -> np.ndarray:
    """(4, 4) pose from AUBO's ``[x, y, z, rx, ry, rz]`` (m, rad; R = Rz(rz) Ry(ry) Rx(rx))."""
    p = np.asarray(pose6, dtype=float).reshape(-1)
    if p.shape != (6,) or not np.all(np.isfinite(p)):
        raise ValueError(f"an AUBO pose is 6 finite numbers [x, y, z, rx, ry, rz], got {pose6!r}")
    return pose_from_rpy(p[3], p[4], p[5], t=p[:3])


def aubo_from_pose(T) -> list[float]:
    """AUBO's ``[x, y, z, rx, ry, rz]`` (m, rad) of a (4, 4) pose."""
    T = as_pose(T)
    return [*T[:3, 3].tolist(), *rpy_from_pose(T).tolist()]


def _check(rc, what: str) -> int:
    """AUBO calls return 0 on success; any other code (negative or positive) is a failure."""
    if rc is not None and int(rc) != 0:
        raise AuboError(f"{what} failed with AUBO code {int(rc)}")
    return rc


class AuboSuctionCup(SuctionCup):
    """A vacuum cup switched by standard digital output ``pin``.

    With ``sensor_pin`` (a standard digital input wired to a vacuum switch) ``grasp()`` reports
    whether a part is held; without it the driver cannot tell and ``grasp()`` returns True once
    the vacuum is on.
    """

    def __init__(self, io, pin: int, flange_T_tcp=None, sensor_pin: int | None = None,
                 sensor_wait_s: float = 0.5):
        super().__init__("suction", flange_T_tcp)
        self._io, self.pin, self.sensor_pin, self.sensor_wait_s = io, int(pin), sensor_pin, sensor_wait_s

    def _require(self):
        if self._io is None:
            raise RobotDisconnectedError("the AUBO connection is closed; connect again")
        return self._io

    def grasp(self) -> bool:
        io = self._require()
        _check(io.setStandardDigitalOutput(self.pin, True), f"switching output {self.pin} on")
        if self.sensor_pin is None:
            return True
        deadline = time.monotonic() + self.sensor_wait_s
        while time.monotonic() < deadline:
            if io.getStandardDigitalInput(self.sensor_pin):
                return True
            time.sleep(0.02)
        return bool(io.getStandardDigitalInput(self.sensor_pin))

    def release(self) -> None:
        _check(self._require().setStandardDigitalOutput(self.pin, False), f"output {self.pin} off")

    @property
    def is_holding(self) -> bool:
        io = self._require()
        if self.sensor_pin is not None:
            return bool(io.getStandardDigitalInput(self.sensor_pin))
        return bool(io.getStandardDigitalOutput(self.pin))


class AuboRobot(Robot):
    """An AUBO-i5 (6 joints) over RPC. Build it with ``connect("aubo", host=...)``.

    ``acceleration`` (m/s^2) and ``joint_acceleration`` (rad/s^2) go with every move;
    ``max_rotation_speed`` (rad/s) and ``rotation_acceleration`` (rad/s^2) bound how fast the
    TCP turns during a linear move (see :func:`plan_line`); ``motion_timeout_s`` is added to
    the planned duration before a move counts as stuck; ``poll_s`` is how often ``getExecId``
    is asked. A move that ends farther than ``position_tolerance_m`` /
    ``orientation_tolerance_deg`` / ``joint_tolerance_rad`` from its target raises.
    """

    def __init__(self, client, robot_name: str, safety=None, tool=None,
                 acceleration: float = 0.5, joint_acceleration: float = 1.0,
                 max_rotation_speed: float = 0.5, rotation_acceleration: float = 1.0,
                 motion_timeout_s: float = 10.0, poll_s: float = 0.02,
                 position_tolerance_m: float = 0.001, orientation_tolerance_deg: float = 0.5,
                 joint_tolerance_rad: float = 0.005):
        super().__init__("aubo_i5", safety=safety, tool=tool)
        self._client = client
        self._iface = client.getRobotInterface(robot_name)
        self.robot_name = robot_name
        self.acceleration, self.joint_acceleration = acceleration, joint_acceleration
        self.max_rotation_speed, self.rotation_acceleration = max_rotation_speed, rotation_acceleration
        self.motion_timeout_s, self.poll_s = motion_timeout_s, poll_s
        self.position_tolerance_m = position_tolerance_m
        self.orientation_tolerance_deg = orientation_tolerance_deg
        self.joint_tolerance_rad = joint_tolerance_rad

    # ----- reading

    def _state(self):
        self._require_open()
        return self._iface.getRobotState()

    def flange_pose(self) -> np.ndarray:
        return pose_from_aubo(self._state().getToolPose())

    def tcp_offset(self) -> np.ndarray:
        """The controller's active TCP offset as ``flange_T_tcp`` (4, 4)."""
        self._require_open()
        return pose_from_aubo(self._iface.getRobotConfig().getTcpOffset())

    def joint_positions(self) -> np.ndarray:
        return np.asarray(self._state().getJointPositions(), dtype=float).reshape(6).copy()

    def joint_limits(self) -> np.ndarray:
        self._require_open()
        config = self._iface.getRobotConfig()
        return np.column_stack(
            [np.asarray(config.getJointMinPositions(), float)[:6],
             np.asarray(config.getJointMaxPositions(), float)[:6]]
        )

    # ----- moving

    def stop(self) -> None:
        if self._iface is None:
            return
        motion = self._iface.getMotionControl()
        motion.stopLine(self.acceleration * 2, self.joint_acceleration * 2)
        motion.stopJoint(self.joint_acceleration * 2)

    def _wait_arrival(self, planned_s: float, what: str) -> None:
        """Wait for the queued command to start and finish; stop and raise on timeout."""
        motion = self._iface.getMotionControl()
        deadline = time.monotonic() + planned_s + self.motion_timeout_s
        start_deadline = time.monotonic() + min(1.0, self.motion_timeout_s)
        exec_id = motion.getExecId()
        while exec_id == -1 and time.monotonic() < start_deadline:
            time.sleep(self.poll_s)
            exec_id = motion.getExecId()
        while exec_id != -1:  # -1: nothing executing any more
            if time.monotonic() > deadline:
                self.stop()
                raise AuboTimeoutError(
                    f"{what} did not finish within {planned_s + self.motion_timeout_s:.1f} s "
                    f"(planned {planned_s:.1f} s + motion_timeout_s={self.motion_timeout_s}); "
                    "the robot was stopped. Check the pendant for a protective stop or collision"
                )
            time.sleep(self.poll_s)
            exec_id = motion.getExecId()

    def _safety_mode(self) -> str:
        """The controller's safety mode by name ("Normal", "SafeguardStop", ...), for messages."""
        try:
            mode = self._state().getSafetyModeType()
        except Exception as error:  # only used to explain a refusal; never hide the refusal
            return f"unknown (reading it failed: {error})"
        return str(getattr(mode, "name", mode))

    def _require_accepted(self, rc, command: str) -> None:
        """Raise AuboRefusedError unless ``rc`` is 0; positive codes are refusals as well."""
        code = int(rc)
        if code == 0:
            return
        cause, fix = _REFUSALS.get(code, (f"the controller refused it with code {code}",
                                           "read the error on the teach pendant"))
        if code == 1:
            cause = cause.format(mode=self._safety_mode())
        raise AuboRefusedError(f"{command} was refused (AUBO code {code}): {cause}; {fix}. "
                               "The arm did not move", code)

    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        offset = self.tcp_offset()
        target_tcp = base_T_flange @ offset
        start_tcp = self.flange_pose() @ offset  # moveLine's 1 mm rule is about the TCP
        distance = translation_error(start_tcp, target_tcp)
        angle = float(np.radians(rotation_error_deg(start_tcp, target_tcp)))
        a, v, planned, _rotational = plan_line(
            distance, angle, speed, self.acceleration, self.max_rotation_speed,
            self.rotation_acceleration)
        rc = self._iface.getMotionControl().moveLine(aubo_from_pose(target_tcp), a, v, 0.0, 0.0)
        self._require_accepted(rc, "moveLine")
        self._wait_arrival(planned, "the linear move")
        reached = self.flange_pose()
        if (translation_error(reached, base_T_flange) > self.position_tolerance_m
                or rotation_error_deg(reached, base_T_flange) > self.orientation_tolerance_deg):
            raise AuboMotionError(
                f"the linear move ended {translation_error(reached, base_T_flange) * 1000:.1f} mm "
                f"and {rotation_error_deg(reached, base_T_flange):.2f} deg from its target; "
                "it was probably stopped (pendant, safety plane or singularity)"
            )

    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        start = self.joint_positions()
        planned = float(np.abs(q - start).max()) / speed + speed / self.joint_acceleration
        rc = self._iface.getMotionControl().moveJoint(
            [float(v) for v in q], self.joint_acceleration, speed, 0.0, 0.0
        )
        self._require_accepted(rc, "moveJoint")
        self._wait_arrival(planned, "the joint move")
        off = float(np.abs(self.joint_positions() - q).max())
        if off > self.joint_tolerance_rad:
            raise AuboMotionError(
                f"the joint move ended {np.degrees(off):.2f} deg from its target on one joint; "
                "it was probably stopped (pendant, safety limit or collision detection)"
            )

    def _close(self) -> None:
        client, self._iface, self._client = self._client, None, None
        if isinstance(self.tool, AuboSuctionCup):
            self.tool._io = None
        try:
            client.logout()
        finally:
            client.disconnect()


def _import_sdk(sdk):
    if sdk is not None:
        return sdk
    try:
        return importlib.import_module("pyaubo_sdk")
    except ImportError as error:
        raise BackendNotAvailableError(
            f"the AUBO driver needs pyaubo-sdk ({error}); install it with "
            "`pip install cobotlab[real]` or `pip install pyaubo-sdk`"
        ) from error


def create_workcell(
    host: str,
    *,
    port: int = DEFAULT_PORT,
    user: str = "aubo",
    password: str = "123456",
    safety=None,
    suction_pin: int | None = None,
    suction_sensor_pin: int | None = None,
    tool_offset=None,
    camera=None,
    camera_options=None,
    motion_timeout_s: float = 10.0,
    request_timeout_ms: int = 2000,
    sdk=None,
    **robot_options,
) -> Workcell:
    """Connect to an AUBO controller at ``host`` (RPC ``port`` 30004) and log in.

    ``suction_pin``: the standard digital output switching the vacuum (None: no tool).
    ``tool_offset``: the cup's ``flange_T_tcp`` (4, 4) in metres, for ``tcp_pose`` and the
    safety checks (default: the controller's own TCP offset). ``camera``: None, "realsense"
    (``camera_options`` go to ``open_realsense``) or a Camera. ``sdk`` replaces the
    ``pyaubo_sdk`` module (tests pass a fake). Other ``robot_options`` go to :class:`AuboRobot`.
    """
    if not isinstance(host, str) or not host:
        raise ValueError("host must be the AUBO controller's address, e.g. host='192.168.1.100'")
    sdk = _import_sdk(sdk)
    client = sdk.RpcClient()
    client.setRequestTimeout(int(request_timeout_ms))
    if int(client.connect(host, int(port))) != 0 or not client.hasConnected():
        raise AuboError(
            f"could not reach the AUBO controller at {host}:{port}; check the cable and that this "
            "computer is on the controller's subnet (`ping` it), and that the pendant software is running"
        )
    robot = None
    try:
        if int(client.login(user, password)) != 0:
            raise AuboError(f"login as {user!r} refused; check user and password (default aubo/123456)")
        names = list(client.getRobotNames())
        if not names:
            raise AuboError("the controller reports no robot; is the arm connected to it?")
        robot = AuboRobot(client, names[0], safety=safety, motion_timeout_s=motion_timeout_s,
                          **robot_options)
        if suction_pin is not None:
            offset = robot.tcp_offset() if tool_offset is None else as_pose(tool_offset, "tool_offset")
            robot.tool = AuboSuctionCup(
                robot._iface.getIoControl(), suction_pin, offset, sensor_pin=suction_sensor_pin
            )
        from robots.drivers.realsense import camera_from_option

        cam = camera_from_option(camera, camera_options)
    except BaseException:
        if robot is not None:
            robot.close()
        else:
            client.disconnect()
        raise
    return Workcell(robot, cam, kind="aubo")

