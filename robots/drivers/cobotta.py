"""DENSO COBOTTA driver over b-CAP: ``connect("cobotta", host="192.168.0.1")``.

Uses this project's own b-CAP client (:mod:`robots.drivers.bcap`); nothing to install.

What the driver sends (b-CAP function, arguments), in order:

* connect, in DENSO's order (the controller refuses ``Robot_Change`` and motion from a client
  that has not taken the arm): ``Service_Start(option)`` (``service_option``, "" by default;
  ``"WDT=<ms>"`` asks for a watchdog), ``Controller_Connect("", "CaoProv.DENSO.VRC",
  "localhost", "")`` (the RC8-family provider, as in DENSO's samples),
  ``Controller_GetRobot(ctrl, "Arm", "")``, ``Robot_Execute(robot, "TakeArm", [0, 0])``, then
  ``Robot_Change(robot, "Tool0")`` so positions are the flange (tool 0 = mechanical interface,
  the UR "TCP set to zero" equivalent), ``Robot_Execute(robot, "Motor", [1, 0])``,
  ``Robot_Execute(robot, "ExtSpeed", [s, a, d])``.
* read: ``Robot_Execute(robot, "CurPos")`` -> ``[x, y, z, rx, ry, rz, fig]`` in mm and degrees;
  ``Robot_Execute(robot, "CurJnt")`` -> joint angles in degrees (6 used; RC8 may append more).
* move: ``Robot_Move(robot, comp, "@E P(x, y, z, rx, ry, rz, fig)", "SPEED=p, NEXT")`` with
  comp = 2 (MOVE L, linear) for ``move_to`` and ``"@E J(j1, ..., j6)"`` with comp = 1
  (MOVE P, point to point) for ``move_joints``. ``@E`` ends the move when the encoders reach
  the target; ``NEXT`` returns at once so this driver can poll
  ``Robot_Execute(robot, "MotionComplete", [-1, 1])`` with a time limit, and Ctrl-C can halt.
  ``fig`` is the arm's current figure (configuration), so a Cartesian move never flips the arm;
  to change configuration, use ``move_joints``.
* stop: ``Robot_Halt(robot, "")``.
* hand (COBOTTA electric gripper, via ``Controller_Execute`` as in DENSO's COBOTTA samples):
  ``"HandMoveA", [width_mm, speed_percent]`` opens to a width; ``"HandMoveH", [force_N, True]``
  closes and holds with a force.
* close: ``Motor [0, 0]``, ``GiveArm`` (the arm is given back before its handle is released,
  so the pendant or another client can take it), ``Robot_Release``, ``Controller_Disconnect``,
  ``Service_Stop``, then the socket; every step runs even if one fails.

Euler convention (verify on your arm, see docs/robots/cobotta.md): DENSO's (RX, RY, RZ) are
taken as rotations about the fixed base axes X, then Y, then Z, i.e. ``R = Rz(RZ) Ry(RY)
Rx(RX)`` (= ``robots.geometry.pose_from_rpy(RX, RY, RZ)``). Two independent public COBOTTA
b-CAP programs use this order (one builds grasp poses with ``tf`` ``euler_matrix(rx, ry, rz,
"sxyz")``; a DENSO RC8 toolchain converts with RoboDK's ``transl * rotz * roty * rotx``), and
the tool-down pose ``P(x, y, z, 180, 0, 180)`` of DENSO's samples is consistent with it. It
was not found stated in a DENSO manual sentence, so the docs give a one-minute check on a
real arm.

Speeds: DENSO speeds are percentages. The effective TCP speed is taken as
``full_speed_m_s * ExtSpeed% * SPEED%``; ``full_speed_m_s`` is an assumption (1.0 m/s): if
the real 100% speed is lower, moves are slower than asked (safe), and the motion time limit
(see :func:`robots.drivers._common.motion_time_limit_s`) has generous margins.
"""

from __future__ import annotations

import warnings

import numpy as np

from robots.drivers._common import (
    MotionTimeoutError,
    as_reading,
    mm_rpy_deg_from_pose,
    motion_time_limit_s,
    pose_from_mm_rpy_deg,
    wait_for,
)
from robots.drivers.bcap import DEFAULT_PORT, BCAPClient, BCAPError
from robots.geometry import rotation_angle_deg
from robots.interfaces import Camera, Gripper, Robot, RobotDisconnectedError, Workcell
from robots.safety import Safety

__all__ = [
    "COBOTTA_JOINT_LIMITS",
    "CobottaGripper",
    "CobottaRobot",
    "MotionTimeoutError",
    "create_workcell",
    "default_safety",
]

DEG = np.pi / 180
# DENSO COBOTTA (CVR038) published joint ranges, degrees -> radians.
COBOTTA_JOINT_LIMITS = np.radians(
    [(-150, 150), (-60, 100), (18, 140), (-170, 170), (-95, 135), (-170, 170)]
)
# Rated joint speeds (rad/s, DENSO's COBOTTA description); SPEED=100% drives the fastest
# joint at most this fast, so percent = speed / max is conservative for the others.
COBOTTA_MAX_JOINT_SPEED = np.array([0.4032, 0.3922, 0.7257, 0.7391, 0.7391, 1.1093])
PROVIDER = "CaoProv.DENSO.VRC"
# HRESULT the controller returns when HandMoveH closes on nothing (reported in a public
# COBOTTA error table); any other hand error is raised.
E_GRIP_NOT_DETECTED = 0x8350048F - 0x100000000


def default_safety(mode: str = "auto") -> Safety:
    """Limits for a COBOTTA on a table: its 342 mm reach, 0.1 m/s, 0.5 rad/s."""
    return Safety(
        workspace_min=np.array([-0.40, -0.40, 0.01]),
        workspace_max=np.array([0.40, 0.40, 0.60]),
        max_speed=0.10,
        max_joint_speed=0.5,
        max_step=0.15,
        mode=mode,
    )


class CobottaGripper(Gripper):
    """The COBOTTA electric gripper (two fingers, 0..30 mm), driven by Controller_Execute.

    ``open_width_mm`` is where ``release`` opens to, ``force_n`` the holding force of
    ``grasp`` and ``speed_percent`` the finger speed. ``flange_T_tcp`` is the fingertip centre
    in the flange frame (measure it; identity if unknown).
    """

    def __init__(self, robot: CobottaRobot, flange_T_tcp=None, open_width_mm: float = 30.0,
                 force_n: float = 10.0, speed_percent: float = 50.0):
        super().__init__("cobotta_gripper", flange_T_tcp)
        if not 0 <= open_width_mm <= 30:
            raise ValueError(f"open_width_mm must be within 0..30 mm, got {open_width_mm}")
        self._robot = robot
        self.open_width_mm, self.force_n, self.speed_percent = open_width_mm, force_n, speed_percent
        self._holding = False

    def grasp(self) -> bool:
        robot = self._robot
        robot._require_open()
        try:
            robot.client.controller_execute(
                robot.h_ctrl, "HandMoveH", [float(self.force_n), True], timeout_s=robot.hand_timeout_s
            )
        except BCAPError as error:
            if error.hresult != E_GRIP_NOT_DETECTED:
                raise
            self._holding = False
        else:
            self._holding = True
        return self._holding

    def release(self) -> None:
        robot = self._robot
        robot._require_open()
        robot.client.controller_execute(
            robot.h_ctrl, "HandMoveA", [float(self.open_width_mm), float(self.speed_percent)],
            timeout_s=robot.hand_timeout_s,
        )
        self._holding = False

    @property
    def is_holding(self) -> bool:
        return self._holding


class CobottaRobot(Robot):
    """A COBOTTA behind an open b-CAP session (use :func:`create_workcell` to build one).

    ``client`` is the :class:`~robots.drivers.bcap.BCAPClient`, ``h_ctrl`` / ``h_robot`` the
    controller and robot handles. Poses are the flange (Tool0) in the robot base frame, metres.
    """

    settle_time_s = 0.3

    def __init__(self, client: BCAPClient, h_ctrl: int, h_robot: int, safety=None,
                 ext_speed_pct: float = 50.0, full_speed_m_s: float = 1.0,
                 motor_off_on_close: bool = True, poll_s: float = 0.02,
                 hand_timeout_s: float = 10.0):
        super().__init__("cobotta", safety=default_safety() if safety is None else safety)
        self.client, self.h_ctrl, self.h_robot = client, h_ctrl, h_robot
        self.ext_speed_pct, self.full_speed_m_s = float(ext_speed_pct), float(full_speed_m_s)
        self.motor_off_on_close = motor_off_on_close
        self.poll_s, self.hand_timeout_s = poll_s, hand_timeout_s

    # ----- readings

    def _current_position(self) -> np.ndarray:
        """CurPos as (x, y, z mm, rx, ry, rz deg, fig)."""
        self._require_open()
        values = self.client.robot_execute(self.h_robot, "CurPos")
        return as_reading(values if values is None else list(values)[:7], 7, "CurPos")

    def flange_pose(self) -> np.ndarray:
        p = self._current_position()
        return pose_from_mm_rpy_deg(p[:3], p[3:6])

    def joint_positions(self) -> np.ndarray:
        self._require_open()
        values = self.client.robot_execute(self.h_robot, "CurJnt")
        # RC8 reports 8 values (6 arm joints and 2 extra axes); the arm is the first 6.
        return np.radians(as_reading(None if values is None else list(values)[:6], 6, "CurJnt"))

    def joint_limits(self) -> np.ndarray:
        return COBOTTA_JOINT_LIMITS.copy()

    # ----- motion

    def stop(self) -> None:
        """Halt any motion (Robot_Halt). A no-op once closed.

        If the link was already lost (and reported by the call that found out), there is no
        way to reach the controller: this warns instead of raising, so closing still works.
        """
        if self._closed:
            return
        if not self.client.connected:
            warnings.warn(
                "cannot send Robot_Halt: the b-CAP link to the COBOTTA is lost. If the arm is "
                "still moving, press the emergency stop", RuntimeWarning, stacklevel=2,
            )
            return
        self.client.robot_halt(self.h_robot, "")

    def _speed_percent(self, fraction_of_full: float) -> float:
        pct = 100.0 * fraction_of_full / (self.ext_speed_pct / 100.0)
        if pct > 100.0:
            raise ValueError(
                f"the requested speed needs SPEED={pct:.0f}% at ExtSpeed={self.ext_speed_pct:g}%; "
                "move slower or connect with a higher ext_speed_pct"
            )
        return max(pct, 0.1)  # the controller rejects 0

    def _move_and_wait(self, comp: int, pose: str, pct: float, time_limit_s: float,
                       what: str) -> None:
        self.client.robot_move(self.h_robot, comp, pose, f"SPEED={pct:.1f}, NEXT")
        wait_for(
            lambda: bool(self.client.robot_execute(self.h_robot, "MotionComplete", [-1, 1])),
            time_limit_s, self.stop, what, self.poll_s,
        )

    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        current = self._current_position()
        xyz, rpy = mm_rpy_deg_from_pose(base_T_flange)
        fig = int(np.rint(current[6]))
        pose = "@E P({:.4f}, {:.4f}, {:.4f}, {:.5f}, {:.5f}, {:.5f}, {:d})".format(*xyz, *rpy, fig)
        pct = self._speed_percent(speed / self.full_speed_m_s)
        start = pose_from_mm_rpy_deg(current[:3], current[3:6])
        # Rotation counts as path too: 0.1 m per radian keeps pure rotations from timing out.
        path = np.linalg.norm(base_T_flange[:3, 3] - start[:3, 3]) + 0.1 * np.radians(
            rotation_angle_deg(start[:3, :3].T @ base_T_flange[:3, :3])
        )
        self._move_and_wait(2, pose, pct, motion_time_limit_s(path, speed), "linear move")

    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        current = self.joint_positions()
        pose = "@E J({})".format(", ".join(f"{v:.5f}" for v in np.degrees(q)))
        pct = self._speed_percent(speed / COBOTTA_MAX_JOINT_SPEED.max())
        step = float(np.abs(q - current).max())
        self._move_and_wait(1, pose, pct, motion_time_limit_s(step, speed), "joint move")

    # ----- shutdown

    def _close(self) -> None:
        """Motor off, give the arm back, release handles, stop the service, close the socket."""
        steps = []
        if self.motor_off_on_close:
            steps.append(lambda: self.client.robot_execute(self.h_robot, "Motor", [0, 0]))
        steps += [
            lambda: self.client.robot_execute(self.h_robot, "GiveArm"),
            lambda: self.client.robot_release(self.h_robot),
            lambda: self.client.controller_disconnect(self.h_ctrl),
            self.client.service_stop,
        ]
        _run_all(steps, self.client)


def _run_all(steps, client: BCAPClient) -> None:
    """Run every shutdown step, then close the socket; re-raise the first real error.

    Once the link is gone there is nothing left to release, so a disconnect is not re-raised
    (the caller already saw it, or is closing deliberately).
    """
    first = None
    for step in steps:
        if not client.connected:
            break
        try:
            step()
        except RobotDisconnectedError:
            break
        except Exception as error:
            first = first or error
    client.close()
    if first is not None:
        raise first


def create_workcell(
    host: str | None = None,
    port: int = DEFAULT_PORT,
    *,
    tool: str = "gripper",
    flange_T_tcp=None,
    safety: Safety | None = None,
    mode: str | None = None,
    timeout_s: float = 3.0,
    ext_speed_pct: float = 50.0,
    full_speed_m_s: float = 1.0,
    motor_off_on_close: bool = True,
    camera: Camera | str | None = None,
    camera_options: dict | None = None,
    provider: str = PROVIDER,
    robot_name: str = "Arm",
    service_option: str = "",
) -> Workcell:
    """Connect to a COBOTTA and return a Workcell (``robots.connect("cobotta", ...)`` calls this).

    ``host``/``port``: the controller's address (factory default 192.168.0.1, port 5007).
    ``tool``: "gripper" (the electric hand) or "none". ``safety``: limits (default
    :func:`default_safety`); ``mode="confirm"`` asks before every move. ``timeout_s``: the
    limit for connecting and for each reply (an interim "still executing" reply restarts it).
    ``service_option``: the ``Service_Start`` option, e.g. ``"WDT=400"`` for a 400 ms
    watchdog (see docs/robots/cobotta.md). ``ext_speed_pct``: the controller's external
    speed/acceleration override set at connect. ``camera``: None, ``"realsense"`` (with
    ``camera_options`` for :func:`robots.drivers.realsense.open_realsense`) or an opened Camera.
    On any failure while connecting, whatever was opened is released before the error is raised.
    """
    if not host:
        raise ValueError(
            "connect('cobotta') needs host=, the controller's IP address (factory default "
            "192.168.0.1), or COBOTLAB_HOST in the environment"
        )
    if tool not in ("gripper", "none"):
        raise ValueError(f"tool must be 'gripper' or 'none' for the COBOTTA, got {tool!r}")
    if not 0 < ext_speed_pct <= 100:
        raise ValueError(f"ext_speed_pct must be within (0, 100], got {ext_speed_pct}")
    if safety is None:
        safety = default_safety(mode or "auto")
    elif mode is not None:
        safety.mode = mode
        safety.validate()

    client = BCAPClient(host, port, timeout_s)
    opened = []  # shutdown steps for what is open so far, run in reverse on failure
    try:
        client.service_start(service_option)
        opened.append(client.service_stop)
        h_ctrl = client.controller_connect("", provider, "localhost", "")
        opened.append(lambda: client.controller_disconnect(h_ctrl))
        h_robot = client.controller_get_robot(h_ctrl, robot_name, "")
        opened.append(lambda: client.robot_release(h_robot))
        client.robot_execute(h_robot, "TakeArm", [0, 0])
        opened.append(lambda: client.robot_execute(h_robot, "GiveArm"))
        client.robot_change(h_robot, "Tool0")
        client.robot_execute(h_robot, "Motor", [1, 0], timeout_s=max(timeout_s, 10.0))
        opened.append(lambda: client.robot_execute(h_robot, "Motor", [0, 0]))
        ext = float(ext_speed_pct)
        client.robot_execute(h_robot, "ExtSpeed", [ext, ext, ext])
    except BaseException:
        try:
            _run_all(list(reversed(opened)), client)
        except Exception as cleanup_error:  # the connect error is the one to show
            warnings.warn(f"cleanup after a failed connect also failed: {cleanup_error!r}",
                          RuntimeWarning, stacklevel=2)
        raise

    robot = CobottaRobot(client, h_ctrl, h_robot, safety, ext_speed_pct, full_speed_m_s,
                         motor_off_on_close)
    if tool == "gripper":
        robot.tool = CobottaGripper(robot, flange_T_tcp)
    try:
        from robots.drivers.realsense import camera_from_option

        camera = camera_from_option(camera, camera_options)
    except BaseException:
        robot.close()   # a camera that fails to open must not leave the arm taken and powered
        raise
    return Workcell(robot, camera, kind="cobotta")
