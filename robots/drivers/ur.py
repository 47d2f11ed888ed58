"""Universal Robots driver over RTDE (``ur-rtde``): ``connect("ur", host="192.168.1.10")``.

Needs ``pip install "ur-rtde>=1.5,<2"`` (the ``real`` extra); imported only when connecting.

The ur_rtde calls used (names, argument order and units as ur_rtde documents them; checked
against the installed module by tests/test_driver_ur.py):

* ``rtde_control.RTDEControlInterface(hostname)``: ``setTcp(pose)`` / ``getTCPOffset()``,
  ``moveL(pose, speed, acceleration, asynchronous)`` with pose = [x, y, z, rx, ry, rz] in
  metres and a rotation vector in radians, speed m/s, acceleration m/s^2;
  ``moveJ(q, speed, acceleration, asynchronous)`` in rad, rad/s, rad/s^2;
  ``stopL(a)`` / ``stopJ(a)`` (deceleration), ``isConnected()``, ``isSteady()``, ``disconnect()``.
* ``rtde_receive.RTDEReceiveInterface(hostname)``: ``getActualTCPPose()``, ``getActualQ()``,
  ``isProtectiveStopped()``, ``isEmergencyStopped()``, ``getSafetyStatusBits()``,
  ``getSafetyMode()``, ``getSpeedScaling()``, ``isConnected()``, ``disconnect()``.
* ``rtde_io.RTDEIOInterface(hostname)``: ``setStandardDigitalOut(id, level)`` (or
  ``setToolDigitalOut``), ``disconnect()``.

Conventions: the TCP offset is set to zero at connect (and checked), so
``getActualTCPPose`` is the flange (``tool0``) in the controller's ``base`` frame; the tool's
``flange_T_tcp`` is applied in Python, where the safety checks see it. Moves are sent with
``asynchronous=True`` and waited for in Python with a time limit, so a stuck move is stopped
(``stopL``/``stopJ``) and reported, and Ctrl-C reaches the driver mid-move.

Safety stops: every poll during a move reads ``getSafetyStatusBits()`` (RTDE
``safety_status_bits``: bit 0 normal, 1 reduced, 2 protective stopped, 3 recovery, 4 safeguard
stopped, 5 system emergency stopped, 6 robot emergency stopped, 7 emergency stopped,
8 violation, 9 fault, 10 stopped due to safety) and ``getSafetyMode()`` (1 normal, 2 reduced,
3 protective stop, 4 recovery, 5 safeguard stop, 6 system e-stop, 7 robot e-stop, 8 violation,
9 fault, 12 automatic-mode safeguard stop, 13 three-position enabling stop). Any stop raises
:class:`URSafetyStopError` (:class:`URSafeguardStopError` for a safeguard stop: an external
safety input such as a light curtain or a door switch) within one poll, ~10 ms. The move's
time limit counts motion time at ``getSpeedScaling()`` (the pendant's speed slider times any
trajectory slowdown), so a slider at 30% gives the move 1/0.3 as long.

Connecting: the ur_rtde constructors block, holding the interpreter lock, for minutes when
the host accepts TCP on port 30004 but never speaks RTDE (another device at a mistyped
address). :func:`probe_rtde` therefore first sends RTDE's protocol-version request itself,
with a socket timeout, and refuses the host with a clear message if no RTDE reply comes.

Speed caps below ur_rtde's defaults (moveL 0.25 m/s, 1.2 m/s^2; moveJ 1.05 rad/s, 1.4
rad/s^2): at most ``MAX_TCP_SPEED`` and ``MAX_JOINT_SPEED`` whatever ``Safety`` allows.
"""

from __future__ import annotations

import socket
import struct
import time
import warnings
from types import SimpleNamespace

import numpy as np

from robots.backends import BackendNotAvailableError
from robots.drivers._common import as_reading, motion_time_limit_s, wait_for
from robots.geometry import pose_from_rotvec, rotation_angle_deg, rotvec_from_pose
from robots.interfaces import (
    Camera,
    Gripper,
    Robot,
    RobotDisconnectedError,
    SafetyError,
    SuctionCup,
    Workcell,
)
from robots.safety import Safety

__all__ = [
    "MAX_JOINT_SPEED",
    "MAX_TCP_SPEED",
    "RTDE_PORT",
    "URDigitalTool",
    "URGripper",
    "URRobot",
    "URSafeguardStopError",
    "URSafetyStopError",
    "URSuctionCup",
    "create_workcell",
    "default_safety",
    "probe_rtde",
]

MAX_TCP_SPEED = 0.20  # m/s (ur_rtde default 0.25)
TCP_ACCELERATION = 0.5  # m/s^2 (default 1.2)
MAX_JOINT_SPEED = 0.80  # rad/s (default 1.05)
JOINT_ACCELERATION = 0.8  # rad/s^2 (default 1.4)
STOP_DECELERATION_L = 2.0  # m/s^2, firm but not a jolt
STOP_DECELERATION_J = 2.0  # rad/s^2
REACHED_TOL_M, REACHED_TOL_RAD = 2e-4, 2e-3  # "at the target" while waiting for a move
UR_JOINT_LIMITS = np.tile([-2 * np.pi, 2 * np.pi], (6, 1))  # e-Series: +-360 deg every joint

RTDE_PORT = 30004
# RTDE framing (UR's RTDE guide): big-endian uint16 package size (header included), uint8
# package type; RTDE_REQUEST_PROTOCOL_VERSION is type 86 ('V') with a uint16 version, and the
# controller answers with type 86 and a uint8 "accepted".
RTDE_REQUEST_PROTOCOL_VERSION = 86
RTDE_PROTOCOL_VERSION = 2

# safety_status_bits (RTDE) -> what it means, in the order they are reported.
SAFETY_STATUS_BITS = {
    2: "a protective stop",
    4: "a safeguard stop",
    5: "a system emergency stop",
    6: "a robot emergency stop",
    7: "an emergency stop",
    8: "a safety violation",
    9: "a safety fault",
}
SAFEGUARD_BIT = 4
# getSafetyMode() values that stop the arm (ur_rtde / UR's SafetyMode enum).
SAFETY_MODE_STOPS = {
    3: "a protective stop", 5: "a safeguard stop", 6: "a system emergency stop",
    7: "a robot emergency stop", 8: "a safety violation", 9: "a safety fault",
    12: "an automatic-mode safeguard stop", 13: "a three-position enabling stop",
}
SAFEGUARD_MODES = (5, 12, 13)


class URSafetyStopError(RuntimeError):
    """The controller stopped the arm for safety (protective, safeguard or emergency stop).

    ``safety_mode`` is ``getSafetyMode()`` and ``status_bits`` ``getSafetyStatusBits()`` at the
    moment it was seen; the driver has already asked the arm to stop.
    """

    def __init__(self, message: str, safety_mode: int, status_bits: int):
        super().__init__(message)
        self.safety_mode, self.status_bits = safety_mode, status_bits


class URSafeguardStopError(URSafetyStopError):
    """A safeguard stop: an external safety input (light curtain, door switch, scanner) opened."""


def probe_rtde(host: str, port: int | None = None, timeout_s: float = 3.0) -> int:
    """Check that ``host`` speaks RTDE before ur_rtde is let near it; return the "accepted" flag.

    Sends RTDE_REQUEST_PROTOCOL_VERSION (version 2) and waits up to ``timeout_s`` seconds for
    the controller's answer. Raises RobotDisconnectedError naming the host if nothing listens,
    the connection fails, or the host stays silent / answers something that is not RTDE
    (the case in which ur_rtde's constructors hang for minutes).
    """
    port = RTDE_PORT if port is None else int(port)
    what = (f"check that {host} is the UR controller's address (pendant: Settings > System > "
            "Network), that the robot is switched on, and that RTDE is not disabled "
            "(Settings > Security > Services)")
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as error:
        raise RobotDisconnectedError(
            f"cannot reach the UR at {host}:{port} ({error}); {what}") from error
    try:
        sock.settimeout(timeout_s)
        sock.sendall(struct.pack(">HBH", 5, RTDE_REQUEST_PROTOCOL_VERSION, RTDE_PROTOCOL_VERSION))
        deadline = time.monotonic() + timeout_s
        reply = b""
        while len(reply) < 4:
            sock.settimeout(max(deadline - time.monotonic(), 0.001))
            chunk = sock.recv(4 - len(reply))
            if not chunk:
                raise OSError("the host closed the connection without an RTDE reply")
            reply += chunk
    except (OSError, TimeoutError) as error:
        detail = "no reply" if isinstance(error, TimeoutError) else str(error)
        raise RobotDisconnectedError(
            f"{host}:{port} accepts connections but does not speak RTDE ({detail} within "
            f"{timeout_s:.0f} s to RTDE's protocol-version request); it is probably not a UR "
            f"controller: {what}") from error
    finally:
        sock.close()
    size, kind, accepted = struct.unpack(">HBB", reply)
    if kind != RTDE_REQUEST_PROTOCOL_VERSION or size < 4:
        raise RobotDisconnectedError(
            f"{host}:{port} answered, but not with RTDE (package type {kind}, size {size}); "
            f"it is probably not a UR controller: {what}")
    return accepted


def default_safety(mode: str = "auto") -> Safety:
    """Limits for a UR on a table (0.2 m/s, 0.8 rad/s, +-1 m box, floor 1 cm)."""
    return Safety(max_speed=MAX_TCP_SPEED, max_joint_speed=MAX_JOINT_SPEED, mode=mode)


def _load_sdk():
    try:
        import rtde_control
        import rtde_io
        import rtde_receive
    except ModuleNotFoundError as error:
        raise BackendNotAvailableError(
            f"backend 'ur' needs ur_rtde ({error.name!r} is missing); install it with "
            '`pip install "ur-rtde>=1.5,<2"` or `pip install cobotlab[real]`'
        ) from error
    return SimpleNamespace(
        RTDEControlInterface=rtde_control.RTDEControlInterface,
        RTDEReceiveInterface=rtde_receive.RTDEReceiveInterface,
        RTDEIOInterface=rtde_io.RTDEIOInterface,
    )


class URDigitalTool:
    """A tool switched by one digital output (pin ``pin``; tool connector if ``tool_output``).

    ``settle_s``: time for the vacuum to build / fingers to close before reporting.
    """

    def _setup(self, robot: URRobot, pin: int, tool_output: bool, settle_s: float):
        if not (isinstance(pin, int) and 0 <= pin <= (1 if tool_output else 7)):
            raise ValueError(
                f"digital output pin must be 0..{1 if tool_output else 7}, got {pin!r}"
            )
        self._robot, self.pin, self.tool_output, self.settle_s = robot, pin, tool_output, settle_s
        self._holding = False

    def _set(self, level: bool) -> None:
        robot = self._robot
        robot._require_open()
        setter = robot.io.setToolDigitalOut if self.tool_output else robot.io.setStandardDigitalOut
        if setter(self.pin, level) is False:
            raise RuntimeError(
                f"the controller refused to set digital output {self.pin}; check that the "
                "robot is in remote control and that the output is not used by a program"
            )
        time.sleep(self.settle_s)

    def grasp(self) -> bool:
        """Switch the output on. There is no sensor on this pin, so success is assumed."""
        self._set(True)
        self._holding = True
        return True

    def release(self) -> None:
        self._set(False)
        self._holding = False

    @property
    def is_holding(self) -> bool:
        return self._holding


class URSuctionCup(URDigitalTool, SuctionCup):
    def __init__(self, robot, pin=0, tool_output=False, flange_T_tcp=None, settle_s=0.3):
        SuctionCup.__init__(self, "ur_suction", flange_T_tcp)
        self._setup(robot, pin, tool_output, settle_s)


class URGripper(URDigitalTool, Gripper):
    def __init__(self, robot, pin=0, tool_output=False, flange_T_tcp=None, settle_s=0.5):
        Gripper.__init__(self, "ur_gripper", flange_T_tcp)
        self._setup(robot, pin, tool_output, settle_s)


class URRobot(Robot):
    """A UR arm behind ur_rtde's control, receive and IO interfaces (see :func:`create_workcell`)."""

    settle_time_s = 0.3

    def __init__(self, control, receive, io, safety=None, name="ur", poll_s=0.01):
        super().__init__(name, safety=default_safety() if safety is None else safety)
        self.control, self.receive, self.io, self.poll_s = control, receive, io, poll_s
        self._last_move = "L"

    def _check_link(self) -> None:
        if not (self.control.isConnected() and self.receive.isConnected()):
            raise RobotDisconnectedError(
                f"RTDE connection to the {self.name} is lost; check the cable and the "
                "controller (remote control mode on the pendant), then reconnect"
            )

    def flange_pose(self) -> np.ndarray:
        self._require_open()
        self._check_link()
        v = as_reading(self.receive.getActualTCPPose(), 6, "TCP pose")
        return pose_from_rotvec(v[3:], v[:3])

    def joint_positions(self) -> np.ndarray:
        self._require_open()
        self._check_link()
        return as_reading(self.receive.getActualQ(), 6, "joint positions")

    def joint_limits(self) -> np.ndarray:
        return UR_JOINT_LIMITS.copy()

    def stop(self) -> None:
        """Decelerate any motion to zero (stopL or stopJ). A no-op once closed or unreachable."""
        if self._closed or not self.control.isConnected():
            return
        if self._last_move == "J":
            self.control.stopJ(STOP_DECELERATION_J)
        else:
            self.control.stopL(STOP_DECELERATION_L)

    def _raise_if_stopped(self) -> None:
        """Raise URSafetyStopError if the controller reports any safety stop."""
        bits = int(self.receive.getSafetyStatusBits())
        mode = int(self.receive.getSafetyMode())
        causes = [text for bit, text in SAFETY_STATUS_BITS.items() if bits >> bit & 1]
        if mode in SAFETY_MODE_STOPS and SAFETY_MODE_STOPS[mode] not in causes:
            causes.append(SAFETY_MODE_STOPS[mode])
        if self.receive.isEmergencyStopped() and not any("emergency" in c for c in causes):
            causes.append("an emergency stop")
        if self.receive.isProtectiveStopped() and "a protective stop" not in causes:
            causes.append("a protective stop")
        if not causes:
            return
        if bits >> SAFEGUARD_BIT & 1 or mode in SAFEGUARD_MODES:
            raise URSafeguardStopError(
                f"the {self.name} is in a safeguard stop (safety mode {mode}, status bits "
                f"{bits:#06x}): an external safety input opened (light curtain, door switch, "
                "area scanner). Clear the area, close or reset the safeguard, and resume on the "
                "pendant if it asks; then move again", mode, bits)
        raise URSafetyStopError(
            f"the {self.name} is in {' and '.join(causes)} (safety mode {mode}, status bits "
            f"{bits:#06x}); find the cause, clear it on the teach pendant, then move again",
            mode, bits)

    def _wait(self, reached, time_limit_s: float, what: str) -> None:
        def done():
            self._check_link()
            self._raise_if_stopped()
            return reached() and self.control.isSteady()

        wait_for(done, time_limit_s, self.stop, what, self.poll_s,
                 pace=self.receive.getSpeedScaling)

    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        if speed > MAX_TCP_SPEED:
            raise SafetyError(
                f"speed {speed:.3f} m/s exceeds the UR driver's cap {MAX_TCP_SPEED} m/s "
                "(set below ur_rtde's default on purpose); move slower"
            )
        start = self.flange_pose()
        rotvec, t = rotvec_from_pose(base_T_flange)
        self._last_move = "L"
        if not self.control.moveL([*t, *rotvec], speed, TCP_ACCELERATION, True):
            raise RuntimeError(
                "the controller refused moveL; check the pendant for an error or an "
                "unreachable target"
            )
        path = np.linalg.norm(t - start[:3, 3]) + 0.1 * np.radians(
            rotation_angle_deg(start[:3, :3].T @ base_T_flange[:3, :3]))

        def reached():
            now = self.flange_pose()
            return (np.linalg.norm(now[:3, 3] - t) < REACHED_TOL_M and np.radians(
                rotation_angle_deg(now[:3, :3].T @ base_T_flange[:3, :3])) < REACHED_TOL_RAD)

        self._wait(reached, motion_time_limit_s(path, speed), "moveL")

    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        if speed > MAX_JOINT_SPEED:
            raise SafetyError(
                f"joint speed {speed:.3f} rad/s exceeds the UR driver's cap {MAX_JOINT_SPEED} "
                "rad/s; move slower"
            )
        step = float(np.abs(q - self.joint_positions()).max())
        self._last_move = "J"
        if not self.control.moveJ([float(v) for v in q], speed, JOINT_ACCELERATION, True):
            raise RuntimeError("the controller refused moveJ; check the pendant for an error")
        self._wait(lambda: np.abs(self.joint_positions() - q).max() < REACHED_TOL_RAD,
                   motion_time_limit_s(step, speed), "moveJ")

    def _close(self) -> None:
        first = None
        for interface in (self.control, self.io, self.receive):
            try:
                interface.disconnect()
            except Exception as error:  # disconnect the others anyway
                first = first or error
        if first is not None:
            raise first


def create_workcell(
    host: str | None = None,
    *,
    tool: str = "suction",
    pin: int = 0,
    tool_output: bool = False,
    flange_T_tcp=None,
    safety: Safety | None = None,
    mode: str | None = None,
    arm: str = "ur5e",
    camera: Camera | str | None = None,
    camera_options: dict | None = None,
    sdk=None,
    probe: bool | None = None,
    probe_timeout_s: float = 3.0,
) -> Workcell:
    """Connect to a UR over RTDE and return a Workcell (``robots.connect("ur", ...)``).

    ``tool``: "suction", "gripper" (switched by digital output ``pin``, on the tool connector
    if ``tool_output``) or "none"; ``flange_T_tcp`` its tip in the flange frame. ``safety``:
    limits (default :func:`default_safety`); ``mode="confirm"`` asks before every move.
    ``camera``: None, ``"realsense"`` (with ``camera_options`` for
    :func:`robots.drivers.realsense.open_realsense`) or an opened Camera.
    ``sdk``: an object with the three ur_rtde classes (tests pass a fake; default: ur_rtde).
    ``probe``: first check that the host answers RTDE's handshake within ``probe_timeout_s``
    (see :func:`probe_rtde`); default: whenever the real ur_rtde is used.
    """
    if not host:
        raise ValueError("connect('ur') needs host=, the robot's IP address, or COBOTLAB_HOST")
    if tool not in ("suction", "gripper", "none"):
        raise ValueError(f"tool must be 'suction', 'gripper' or 'none', got {tool!r}")
    if safety is None:
        safety = default_safety(mode or "auto")
    elif mode is not None:
        safety.mode = mode
        safety.validate()
    if probe is None:
        probe = sdk is None
    sdk = _load_sdk() if sdk is None else sdk
    if probe:
        probe_rtde(host, timeout_s=probe_timeout_s)

    opened = []
    try:
        for cls in (sdk.RTDEReceiveInterface, sdk.RTDEControlInterface, sdk.RTDEIOInterface):
            try:
                opened.append(cls(host))
            except RuntimeError as error:
                raise RobotDisconnectedError(
                    f"cannot open {cls.__name__} to the UR at {host}: {error}. Check the "
                    "address, that the robot is on and in remote control mode, and that no "
                    "other program holds the RTDE connection"
                ) from error
        receive, control, io = opened
        if not control.setTcp([0.0] * 6) or np.abs(control.getTCPOffset()).max() > 1e-9:
            raise RuntimeError(
                "could not set the TCP offset to zero; the flange pose would be wrong. "
                "Check the pendant (a program may be setting the TCP)"
            )
    except BaseException:
        for interface in opened:
            try:
                interface.disconnect()
            except Exception as cleanup_error:  # the connect error is the one to show
                warnings.warn(f"disconnect after a failed connect also failed: {cleanup_error!r}",
                              RuntimeWarning, stacklevel=2)
        raise

    robot = URRobot(control, receive, io, safety, name=arm)
    if tool == "suction":
        robot.tool = URSuctionCup(robot, pin, tool_output, flange_T_tcp)
    elif tool == "gripper":
        robot.tool = URGripper(robot, pin, tool_output, flange_T_tcp)
    try:
        from robots.drivers.realsense import camera_from_option

        camera = camera_from_option(camera, camera_options)
    except BaseException:
        robot.close()   # a camera that fails to open must not leave RTDE connected
        raise
    return Workcell(robot, camera, kind="ur")
