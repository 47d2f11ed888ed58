"""Franka Emika Panda driver, through ``panda-python`` (imported as ``panda_py``).

Why panda-python and not pylibfranka
------------------------------------
Both are on PyPI with Python 3.11 wheels. ``pylibfranka`` (0.21) bundles libfranka 0.21, which
speaks only to the Franka Research 3: a Panda (FER, robot system 4.x, research interface
protocol 5) refuses it with an incompatible-version error. Its motion API is also a raw 1 kHz
``readOnce``/``writeOnce`` loop that a Python process cannot hold in real time. ``panda-python``
(1.1) bundles libfranka 0.9.2, the version for the Panda, and runs its torque controllers in a
C++ 1 kHz thread; Python only updates their set-points (``create_context`` loop), so a move
written in Python is smooth, can be timed out, and can be stopped from Python. Its
``libfranka`` submodule exposes the Franka ``Gripper`` and ``Robot.automatic_error_recovery``.

Frames and units
----------------
libfranka reports ``O_T_EE`` (base to end effector) and ``F_T_EE`` (flange to end effector,
set in Desk for the mounted hand: 0.1034 m along z, turned -45 deg for the Franka Hand) as
16-vectors in **column-major** order. :func:`pose_from_column_major` and
:func:`column_major_from_pose` convert them; the flange pose is
``base_T_flange = O_T_EE @ inv(F_T_EE)``, so the tool offset never leaks into
``flange_pose()``. The mounted hand becomes ``robot.tool`` with ``flange_T_tcp = F_T_EE``.

Motion
------
``move_to`` interpolates the end-effector pose along a straight line (SLERP for rotation) with a
minimum-jerk time law whose peak speed is the requested m/s, and streams it to panda_py's
``CartesianImpedance`` controller at 100 Hz, with the posture at the start of the move as the
null-space target (``q_nullspace``; panda_py's default would pull the elbow towards its fixed
home posture during every move). ``move_joints`` does the same with the ``JointPosition``
controller.

Both controllers are impedance controllers without integral action: the arm settles where
friction and model error balance the spring, a little short of the goal, and stays there
(panda-py's own motion generators allow for it the same way; about 2 mm and 2e-3 rad on a
real Panda at the default gains). A move therefore ends successfully once the set-point has
arrived, the joints have come to rest (every ``|dq|`` below ``SETTLED_DQ`` rad/s) and the
pose is within the documented tolerances: ``position_tolerance_m`` (3 mm),
``orientation_tolerance_deg`` (0.5 deg) and ``joint_tolerance_rad`` (0.005 rad). What it
settled to is kept in ``robot.last_move_error`` (:class:`SettleError`: metres and radians).
A move gives up after the planned duration plus ``settle_timeout_s``, stops the controller and
raises :class:`FrankaTimeoutError` with the error it ended at. A controller error (a reflex
after a collision, a joint limit) raises :class:`FrankaMotionError`; call ``robot.recover()``
(libfranka's automatic error recovery) once the cause is cleared.

Gripper: libfranka estimates the Hand's ``max_width`` by homing, so ``connect`` homes the
gripper (``Gripper.homing()``: the fingers close and open fully once; keep the jaws clear)
unless ``home_gripper=False``.

Real-time kernel
----------------
The Franka Control Interface needs a PREEMPT_RT kernel on the workstation. ``connect("franka",
...)`` checks ``/sys/kernel/realtime`` and ``uname -v`` first and raises
:class:`FrankaRealtimeError` with the fix if the kernel is not real-time; with
``realtime="ignore"`` it connects anyway (libfranka's ``kIgnore``) and warns that motions may
abort with ``communication_constraints_violation``. See docs/robots/franka.md.
"""

from __future__ import annotations

import importlib
import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from robots.backends import BackendNotAvailableError
from robots.drivers._common import ROTATION_LEVER_M
from robots.geometry import as_pose, invert, rotation_error_deg, translation_error
from robots.interfaces import Gripper, Robot, RobotDisconnectedError, Workcell

__all__ = [
    "FrankaError",
    "FrankaGripper",
    "FrankaMotionError",
    "FrankaRealtimeError",
    "FrankaRobot",
    "FrankaTimeoutError",
    "SettleError",
    "column_major_from_pose",
    "create_workcell",
    "host_has_realtime_kernel",
    "pose_from_column_major",
]

CONTROL_RATE_HZ = 100.0  # set-point updates from Python; the torque loop itself runs at 1 kHz
SETTLED_DQ = 1e-3  # rad/s: every joint slower than this counts as at rest (panda-py's dq_threshold)
# What the impedance controllers reliably settle within on a Panda (they stop ~2 mm, ~2e-3 rad
# short); the defaults of FrankaRobot's tolerances.
POSITION_TOLERANCE_M = 0.003
ORIENTATION_TOLERANCE_DEG = 0.5
JOINT_TOLERANCE_RAD = 0.005
_REALTIME_FIX = (
    "install and boot a PREEMPT_RT kernel (Ubuntu: `sudo pro enable realtime-kernel`, or build one "
    "as in Franka's 'Setting up the real-time kernel' guide), and give your user real-time "
    "priority (`@realtime - rtprio 99` in /etc/security/limits.conf, user in group 'realtime'); "
    "see docs/robots/franka.md. To try without it (motions may abort), pass realtime='ignore'"
)


class FrankaError(RuntimeError):
    """Something went wrong talking to the Panda."""


class FrankaRealtimeError(FrankaError):
    """The workstation cannot run the 1 kHz control loop (no PREEMPT_RT kernel or priority)."""


class FrankaMotionError(FrankaError):
    """The controller stopped with an error (reflex, limit); recover with ``robot.recover()``."""


class FrankaTimeoutError(FrankaMotionError, TimeoutError):
    """A move did not reach its target in time; the robot was stopped."""


@dataclass(frozen=True)
class SettleError:
    """Where the last move settled relative to its goal.

    ``position_m`` and ``orientation_rad``: the end effector's distance and rotation angle
    from the goal pose (``move_to``); ``joint_rad``: the largest joint error (``move_joints``).
    The fields that do not apply to the move are None.
    """

    position_m: float | None = None
    orientation_rad: float | None = None
    joint_rad: float | None = None


# --------------------------------------------------------------------------- conversions


def pose_from_column_major(values) -> np.ndarray:
    """(4, 4) pose from libfranka's 16-vector, which stores the matrix column by column.

    ``values[0:4]`` is the first column (the x axis and 0), ``values[12:15]`` the translation.
    """
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.shape != (16,):
        raise ValueError(f"a libfranka transform has 16 numbers, got {v.size}")
    return as_pose(v.reshape(4, 4, order="F"), "libfranka transform")


def column_major_from_pose(T) -> list[float]:
    """libfranka's column-major 16-vector (a list of floats) of a (4, 4) pose."""
    return as_pose(T).reshape(-1, order="F").tolist()


def host_has_realtime_kernel() -> bool:
    """True if this Linux kernel is PREEMPT_RT (``/sys/kernel/realtime`` is 1 or ``uname -v``
    says PREEMPT_RT). The FCI needs it; see docs/robots/franka.md."""
    try:
        with open("/sys/kernel/realtime") as f:
            if f.read().strip() == "1":
                return True
    except OSError:
        pass
    return "PREEMPT_RT" in os.uname().version


def _smooth(s: float) -> float:
    """Minimum-jerk time law on [0, 1]; its peak slope is 1.875."""
    s = min(max(s, 0.0), 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s)


_PEAK_SLOPE = 1.875


# --------------------------------------------------------------------------- gripper


class FrankaGripper(Gripper):
    """The Franka Hand through libfranka's ``Gripper`` (widths in metres, speed m/s, force N).

    ``grasp()`` closes on whatever is between the fingers and succeeds if it stops at a width
    between ``min_object_width`` and the hand's maximum (so closing on nothing reports False).
    ``release()`` opens fully. ``flange_T_tcp`` is the robot's ``F_T_EE``.
    """

    def __init__(
        self,
        sdk_gripper,
        flange_T_tcp,
        speed: float = 0.05,
        force: float = 20.0,
        min_object_width: float = 0.002,
    ):
        super().__init__("franka_hand", flange_T_tcp)
        self._gripper = sdk_gripper
        self.speed, self.force, self.min_object_width = float(speed), float(force), min_object_width

    def _require(self):
        if self._gripper is None:
            raise RobotDisconnectedError("the Franka Hand is closed; connect again")
        return self._gripper

    def opening(self) -> float:
        """Current finger distance, metres."""
        return float(self._require().read_once().width)

    def move(self, width: float, speed: float | None = None) -> None:
        """Move the fingers to ``width`` metres apart (no force control)."""
        gripper = self._require()
        max_width = float(gripper.read_once().max_width)
        if not 0.0 <= width <= max_width:
            raise ValueError(f"gripper width must be within [0, {max_width:.4f}] m, got {width}")
        if not gripper.move(float(width), float(speed or self.speed)):
            raise FrankaError(f"the Franka Hand did not reach {width * 1000:.1f} mm")

    def grasp(self, force: float | None = None) -> bool:
        gripper = self._require()
        max_width = float(gripper.read_once().max_width)
        lo, hi = self.min_object_width, max_width
        # libfranka's grasp succeeds if the final width is within [width - eps_in, width + eps_out].
        middle = 0.5 * (lo + hi)
        return bool(
            gripper.grasp(middle, self.speed, float(force or self.force), middle - lo, hi - middle)
        )

    def release(self) -> None:
        gripper = self._require()
        gripper.move(float(gripper.read_once().max_width), self.speed)

    @property
    def is_holding(self) -> bool:
        return bool(self._require().read_once().is_grasped)

    def close(self) -> None:
        if self._gripper is not None:
            try:
                self._gripper.stop()
            finally:
                self._gripper = None


# --------------------------------------------------------------------------- robot


class FrankaRobot(Robot):
    """A Franka Emika Panda (7 joints). Build it with ``connect("franka", host=...)``."""

    settle_time_s = 0.3

    def __init__(
        self,
        panda,
        sdk,
        safety=None,
        tool=None,
        position_tolerance_m: float = POSITION_TOLERANCE_M,
        orientation_tolerance_deg: float = ORIENTATION_TOLERANCE_DEG,
        joint_tolerance_rad: float = JOINT_TOLERANCE_RAD,
        settle_timeout_s: float = 5.0,
        max_rotation_speed: float = 0.5,
    ):
        super().__init__("panda", safety=safety, tool=tool)
        self._panda = panda
        self._sdk = sdk
        self.position_tolerance_m = position_tolerance_m
        self.orientation_tolerance_deg = orientation_tolerance_deg
        self.joint_tolerance_rad = joint_tolerance_rad
        self.settle_timeout_s = settle_timeout_s
        self.max_rotation_speed = max_rotation_speed  # rad/s cap for the flange's turn
        self.last_move_error: SettleError | None = None  # set at the end of every move

    # ----- reading

    def _state(self):
        self._require_open()
        return self._panda.get_state()

    def _ee_and_flange(self):
        state = self._state()
        O_T_EE = pose_from_column_major(state.O_T_EE)
        F_T_EE = pose_from_column_major(state.F_T_EE)
        return O_T_EE, F_T_EE

    def flange_pose(self) -> np.ndarray:
        O_T_EE, F_T_EE = self._ee_and_flange()
        return O_T_EE @ invert(F_T_EE)

    def joint_positions(self) -> np.ndarray:
        return np.asarray(self._state().q, dtype=float).reshape(7).copy()

    def joint_limits(self) -> np.ndarray:
        self._require_open()
        lower = np.asarray(self._panda.get_joint_limits_lower(), dtype=float).reshape(7)
        upper = np.asarray(self._panda.get_joint_limits_upper(), dtype=float).reshape(7)
        return np.column_stack([lower, upper])

    # ----- stopping and recovery

    def stop(self) -> None:
        if self._panda is None:
            return
        self._panda.stop_controller()

    def recover(self) -> None:
        """Clear a reflex or error (libfranka ``automatic_error_recovery``).

        Only after the cause is gone: free the arm from the obstacle, release the user stop.
        """
        self._require_open()
        try:
            self._panda.get_robot().automatic_error_recovery()
        except RuntimeError as error:
            raise FrankaMotionError(
                f"error recovery failed: {error}. Release the user stop button, check the "
                "brakes are open in Desk, then try robot.recover() again"
            ) from error

    # ----- moving

    def _at_rest(self) -> bool:
        return bool(np.abs(np.asarray(self._state().dq, dtype=float)).max() < SETTLED_DQ)

    def _stream(self, controller, setpoint, duration: float, settle_error, within, what: str):
        """Run ``controller``; each tick send ``setpoint(t)``; finish once ``t >= duration``, the
        arm is at rest and ``within(settle_error())``; time out ``settle_timeout_s`` later.
        Always stops the controller and records ``last_move_error``."""
        panda = self._panda
        timeout = duration + self.settle_timeout_s
        self.last_move_error = None
        try:
            panda.start_controller(controller)
            with panda.create_context(frequency=CONTROL_RATE_HZ, max_runtime=timeout) as ctx:
                while ctx.ok():
                    t = ctx.num_ticks / CONTROL_RATE_HZ
                    setpoint(t)
                    if t >= duration and self._at_rest():
                        error = self.last_move_error = settle_error()
                        if within(error):
                            return
            panda.raise_error()  # a reflex ends the context early: report it as such
        except RuntimeError as error:
            raise FrankaMotionError(
                f"the Panda stopped during {what}: {error}. Check for a collision or a limit, "
                "free the arm, then call robot.recover() before moving again"
            ) from error
        finally:
            panda.stop_controller()
        error = self.last_move_error = settle_error()
        if error.position_m is not None:
            ended = (f"{error.position_m * 1000:.1f} mm and "
                     f"{np.degrees(error.orientation_rad):.2f} deg from the goal")
        else:
            ended = f"{error.joint_rad:.4f} rad from the goal on one joint"
        raise FrankaTimeoutError(
            f"{what} did not finish within {timeout:.1f} s (planned {duration:.1f} s plus "
            f"settle_timeout_s={self.settle_timeout_s} s); it ended {ended} and the controller "
            "was stopped. The arm may be blocked, or the tolerances tighter than the impedance "
            "controller settles (position_tolerance_m, orientation_tolerance_deg, "
            "joint_tolerance_rad; see docs/robots/franka.md)"
        )

    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        start_ee, F_T_EE = self._ee_and_flange()
        goal_ee = base_T_flange @ F_T_EE
        q_start = self.joint_positions()  # the null-space posture to keep (see module doc)
        distance = float(np.linalg.norm(goal_ee[:3, 3] - start_ee[:3, 3]))
        angle = float(np.radians(rotation_error_deg(start_ee, goal_ee)))
        rot_speed = min(self.max_rotation_speed, speed / ROTATION_LEVER_M)
        duration = _PEAK_SLOPE * max(distance / speed, angle / rot_speed, 0.1)
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix([start_ee[:3, :3], goal_ee[:3, :3]]))
        controller = self._sdk.controllers.CartesianImpedance()

        def setpoint(t):
            s = _smooth(t / duration)
            position = (1 - s) * start_ee[:3, 3] + s * goal_ee[:3, 3]
            # panda_py takes the quaternion as (x, y, z, w), like scipy's as_quat().
            controller.set_control(position, slerp(s).as_quat(), q_start)

        def settle_error():
            ee = self._ee_and_flange()[0]
            return SettleError(
                position_m=translation_error(ee, goal_ee),
                orientation_rad=float(np.radians(rotation_error_deg(ee, goal_ee))),
            )

        def within(error):
            return (error.position_m <= self.position_tolerance_m
                    and np.degrees(error.orientation_rad) <= self.orientation_tolerance_deg)

        self._stream(controller, setpoint, duration, settle_error, within, "the linear move")

    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        start = self.joint_positions()
        duration = _PEAK_SLOPE * max(float(np.abs(q - start).max()) / speed, 0.1)
        controller = self._sdk.controllers.JointPosition()

        def setpoint(t):
            s = _smooth(t / duration)
            ds = 30 * (t / duration) ** 2 * (1 - t / duration) ** 2 / duration if t < duration else 0
            controller.set_control(start + s * (q - start), ds * (q - start))

        def settle_error():
            return SettleError(joint_rad=float(np.abs(self.joint_positions() - q).max()))

        def within(error):
            return error.joint_rad <= self.joint_tolerance_rad

        self._stream(controller, setpoint, duration, settle_error, within, "the joint move")

    def _close(self) -> None:
        if isinstance(self.tool, FrankaGripper):
            try:
                self.tool.close()
            except RuntimeError as error:
                warnings.warn(f"closing the Franka Hand failed: {error}", RuntimeWarning, 2)
        self._panda = None  # panda_py disconnects when the object is released


# --------------------------------------------------------------------------- connect


def _import_sdk(sdk):
    if sdk is not None:
        return sdk
    try:
        sdk = importlib.import_module("panda_py")
        # Submodules are not loaded by `import panda_py`; the driver needs both.
        importlib.import_module("panda_py.controllers")
        importlib.import_module("panda_py.libfranka")
        return sdk
    except ImportError as error:
        raise BackendNotAvailableError(
            f"the Franka driver needs panda-python ({error}); install it with "
            "`pip install cobotlab[real]` or `pip install panda-python`"
        ) from error


def create_workcell(
    host: str,
    *,
    safety=None,
    gripper: bool = True,
    camera=None,
    camera_options=None,
    realtime: str = "enforce",
    auto_recover: bool = True,
    settle_timeout_s: float = 5.0,
    position_tolerance_m: float = POSITION_TOLERANCE_M,
    orientation_tolerance_deg: float = ORIENTATION_TOLERANCE_DEG,
    joint_tolerance_rad: float = JOINT_TOLERANCE_RAD,
    home_gripper: bool = True,
    sdk=None,
) -> Workcell:
    """Connect to a Panda's FCI at ``host`` and return a :class:`~robots.interfaces.Workcell`.

    ``gripper``: mount the Franka Hand as ``robot.tool``. ``camera``: None, ``"realsense"``
    (with ``camera_options`` for :func:`robots.drivers.realsense.open_realsense`) or a Camera.
    ``realtime``: "enforce" (default; refuse without a PREEMPT_RT kernel) or "ignore".
    ``auto_recover``: clear a left-over error from an earlier session on connect.
    ``home_gripper``: home the Hand at connect (libfranka measures ``max_width`` by homing;
    the fingers close and reopen once). The tolerances are what a move must settle within
    (see the module docstring). ``sdk`` replaces the ``panda_py`` module (tests pass a fake with the same API).
    """
    if realtime not in ("enforce", "ignore"):
        raise ValueError(f"realtime must be 'enforce' or 'ignore', got {realtime!r}")
    if not isinstance(host, str) or not host:
        raise ValueError("host must be the Panda's FCI address, e.g. host='172.16.0.2'")
    sdk = _import_sdk(sdk)
    config = sdk.libfranka.RealtimeConfig
    if realtime == "enforce" and not host_has_realtime_kernel():
        raise FrankaRealtimeError(
            f"this computer runs a kernel without PREEMPT_RT ({os.uname().release}), which the "
            f"Panda's 1 kHz control loop needs: {_REALTIME_FIX}"
        )
    if realtime == "ignore":
        warnings.warn(
            "Franka: real-time checks disabled (realtime='ignore'); motions may abort with "
            "communication_constraints_violation under load",
            RuntimeWarning,
            stacklevel=2,
        )
    mode = config.kEnforce if realtime == "enforce" else config.kIgnore
    try:
        panda = sdk.Panda(host, realtime_config=mode)
    except RuntimeError as error:
        text = str(error).lower()
        if "realtime" in text or "real-time" in text or "scheduling" in text:
            raise FrankaRealtimeError(f"libfranka refused real-time control: {error}. {_REALTIME_FIX}") from error
        raise FrankaError(
            f"could not connect to the Panda at {host}: {error}. Check the cable to the control "
            "box's (not the arm base's) network port, that the brakes are open and FCI is "
            "activated in Desk, and `ping` the address"
        ) from error
    robot = None
    try:
        if auto_recover:
            panda.get_robot().automatic_error_recovery()
        F_T_EE = pose_from_column_major(panda.get_state().F_T_EE)
        tool = None
        if gripper:
            hand = sdk.libfranka.Gripper(host)
            tool = FrankaGripper(hand, F_T_EE)
            if home_gripper and not hand.homing():
                tool.close()
                raise FrankaError(
                    "homing the Franka Hand failed, so its maximum width is unknown; check "
                    "that nothing is between or around the fingers and that the Hand is "
                    "enabled in Desk, then connect again (or pass gripper=False)"
                )
        robot = FrankaRobot(
            panda, sdk, safety=safety, tool=tool, settle_timeout_s=settle_timeout_s,
            position_tolerance_m=position_tolerance_m,
            orientation_tolerance_deg=orientation_tolerance_deg,
            joint_tolerance_rad=joint_tolerance_rad,
        )
        from robots.drivers.realsense import camera_from_option

        cam = camera_from_option(camera, camera_options)
    except BaseException:
        if robot is not None:
            robot.close()
        raise
    return Workcell(robot, cam, kind="franka")
