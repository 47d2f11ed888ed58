"""The contract every robot backend must pass, simulated or real.

Each ``check_*`` function takes ``make_workcell``, a no-argument callable returning a fresh,
connected :class:`robots.Workcell` (the robot at a pose a few centimetres away from any
limit), and raises AssertionError on a violation. A backend's test file runs them all::

    import pytest
    from contract import CONTRACT_CHECKS
    from robots import connect

    @pytest.mark.parametrize("check", CONTRACT_CHECKS, ids=lambda c: c.__name__)
    def test_sim_contract(check):
        check(lambda: connect("sim", arm="panda", seed=0))

The checks move by a few centimetres and a few degrees from the start pose, so they are safe
on real hardware too (pass ``still_tol`` wider than the encoder noise there). The end of the
file holds ``GantryRobot`` / ``BoardCamera``: the smallest complete backend, used to test this
suite itself and as a stand-in for hardware in unit tests (``robots`` tests may not import the
simulator).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from robots import (
    Frame,
    Pointer,
    Robot,
    RobotDisconnectedError,
    SafetyError,
    Workcell,
)
from robots.geometry import (
    compose,
    euler_zyx_from_pose,
    make_pose,
    pose_from_euler_zyx,
    pose_from_rotvec,
    rotation_error_deg,
    translation_error,
)
from robots.interfaces import Camera, Intrinsics, UnreachableError

# --------------------------------------------------------------------------- helpers


def _small_targets(start: np.ndarray) -> list[np.ndarray]:
    """Targets within 4 cm and 10 degrees of ``start`` (in the flange frame, so reachable)."""
    offsets = [
        pose_from_rotvec([0.0, 0.0, np.radians(10)], [0.03, 0.0, 0.0]),
        pose_from_rotvec([np.radians(8), 0.0, 0.0], [0.0, -0.03, 0.02]),
        pose_from_rotvec([0.0, np.radians(-8), np.radians(5)], [-0.02, 0.02, -0.03]),
    ]
    return [start @ d for d in offsets]


def _joint_target(q: np.ndarray, limits: np.ndarray, step: float = 0.1) -> np.ndarray:
    """``q`` moved by ``step`` rad on every joint, towards the middle of each joint's range."""
    middle = limits.mean(axis=1)
    return q + step * np.where(q < middle, 1.0, -1.0)


def _assert_still(robot: Robot, pose0, q0, tol: float, what: str) -> None:
    moved_m = translation_error(robot.flange_pose(), pose0)
    moved_deg = rotation_error_deg(robot.flange_pose(), pose0)
    moved_q = np.abs(robot.joint_positions() - q0).max()
    assert moved_m <= tol and np.radians(moved_deg) <= tol and moved_q <= tol, (
        f"the robot moved after {what} ({moved_m:.2e} m, {moved_deg:.2e} deg, "
        f"{moved_q:.2e} rad): checks must run before any motion"
    )


def _expect(error, call, what: str) -> None:
    """Assert that ``call()`` raises ``error``; any other outcome is a contract violation."""
    try:
        call()
    except error:
        return
    except Exception as other:
        raise AssertionError(
            f"{what}: expected {error.__name__}, got {type(other).__name__}: {other}"
        ) from other
    raise AssertionError(f"{what}: expected {error.__name__}, but the call went through")


# --------------------------------------------------------------------------- the checks


def check_pose_round_trip(make_workcell, tol_m: float = 5e-4, tol_deg: float = 0.1) -> None:
    """move_to(T) then flange_pose() returns T within tolerance; tcp_pose agrees with the tool."""
    with make_workcell() as cell:
        robot = cell.robot
        for target in _small_targets(robot.flange_pose()):
            robot.move_to(target, speed=0.05)
            reached = robot.flange_pose()
            assert reached.shape == (4, 4) and reached.dtype == np.float64
            assert translation_error(reached, target) <= tol_m, (
                f"move_to missed by {translation_error(reached, target) * 1000:.3f} mm"
            )
            assert rotation_error_deg(reached, target) <= tol_deg, (
                f"move_to missed by {rotation_error_deg(reached, target):.3f} deg"
            )
        flange_T_tcp = np.eye(4) if robot.tool is None else robot.tool.flange_T_tcp
        np.testing.assert_allclose(robot.tcp_pose(), robot.flange_pose() @ flange_T_tcp, atol=1e-9)


def check_move_joints_read_back(make_workcell, tol_rad: float = 1e-3) -> None:
    """move_joints(q) then joint_positions() returns q; limits have shape (n, 2)."""
    with make_workcell() as cell:
        robot = cell.robot
        q0 = np.asarray(robot.joint_positions(), dtype=float)
        limits = np.asarray(robot.joint_limits(), dtype=float)
        assert q0.ndim == 1 and limits.shape == (len(q0), 2)
        assert np.all(limits[:, 0] < limits[:, 1])
        target = _joint_target(q0, limits)
        robot.move_joints(target, speed=0.3)
        err = np.abs(robot.joint_positions() - target).max()
        assert err <= tol_rad, f"move_joints missed by {err:.2e} rad"


def check_safety_refuses_before_motion(make_workcell, still_tol: float = 1e-6) -> None:
    """Each unsafe request raises SafetyError (or ValueError if malformed) and nothing moves."""
    with make_workcell() as cell:
        robot = cell.robot
        pose0, q0 = robot.flange_pose(), robot.joint_positions()
        safety = robot.safety

        below_floor = pose0.copy()
        below_floor[2, 3] = safety.workspace_min[2] - 0.05
        beyond_box = pose0.copy()
        beyond_box[0, 3] = safety.workspace_max[0] + 0.05
        near = _small_targets(pose0)[0]
        cases = [
            ("a target below the floor", lambda: robot.move_to(below_floor, 0.05), SafetyError),
            ("a target outside the box", lambda: robot.move_to(beyond_box, 0.05), SafetyError),
            (
                "a speed over the cap",
                lambda: robot.move_to(near, safety.max_speed * 2),
                SafetyError,
            ),
            ("a NaN target", lambda: robot.move_to(np.full((4, 4), np.nan), 0.05), ValueError),
            (
                "a reflection target",
                lambda: robot.move_to(pose0 @ np.diag([1, 1, -1, 1.0]), 0.05),
                ValueError,
            ),
            (
                "a joint speed over the cap",
                lambda: robot.move_joints(q0, safety.max_joint_speed * 2),
                SafetyError,
            ),
        ]
        limits = np.asarray(robot.joint_limits(), dtype=float)
        outside = q0.copy()
        outside[0] = limits[0, 1] + 0.1
        cases.append(
            ("a joint beyond its limit", lambda: robot.move_joints(outside, 0.2), SafetyError)
        )
        nan_q = q0.copy()
        nan_q[-1] = np.nan
        cases.append(("a NaN joint target", lambda: robot.move_joints(nan_q, 0.2), ValueError))
        for what, call, error in cases:
            _expect(error, call, what)
            _assert_still(robot, pose0, q0, still_tol, what)

        # The step limits: shrink them so a small, otherwise valid move is too long.
        safety.max_step, safety.max_rotation_step, safety.max_joint_step = 0.005, 0.01, 0.01
        with pytest.raises(SafetyError, match="max_step"):
            robot.move_to(near, 0.05)
        with pytest.raises(SafetyError, match="max_joint_step"):
            robot.move_joints(_joint_target(q0, limits), 0.2)
        _assert_still(robot, pose0, q0, still_tol, "a step over the limit")


def check_confirm_mode(make_workcell, still_tol: float = 1e-6, tol_m: float = 5e-4) -> None:
    """In confirm mode a refused move raises SafetyError and does not move; accepted ones move."""
    with make_workcell() as cell:
        robot = cell.robot
        pose0, q0 = robot.flange_pose(), robot.joint_positions()
        target = _small_targets(pose0)[0]
        messages = []
        robot.safety.mode = "confirm"
        robot.safety.confirm = lambda message: messages.append(message) or False
        with pytest.raises(SafetyError, match="refused"):
            robot.move_to(target, 0.05)
        _assert_still(robot, pose0, q0, still_tol, "a refused confirmation")
        assert len(messages) == 1 and "mm" in messages[0] and "deg" in messages[0]
        robot.safety.confirm = lambda message: True
        robot.move_to(target, 0.05)
        assert translation_error(robot.flange_pose(), target) <= tol_m


def check_stop(make_workcell, tol_m: float = 5e-4) -> None:
    """stop() is safe when idle and twice; an interrupted move calls stop() and re-raises."""
    with make_workcell() as cell:
        robot = cell.robot
        robot.stop()
        robot.stop()
        target = _small_targets(robot.flange_pose())[0]
        robot.move_to(target, 0.05)  # still usable after stop
        assert translation_error(robot.flange_pose(), target) <= tol_m

        # Simulate Ctrl-C arriving inside the backend's motion; the base class must stop.
        stops = []
        real_stop, real_move = robot.stop, robot._move_to

        def counting_stop():
            stops.append(1)
            real_stop()

        def interrupted_move(pose, speed):
            raise KeyboardInterrupt

        robot.stop, robot._move_to = counting_stop, interrupted_move
        try:
            with pytest.raises(KeyboardInterrupt):
                robot.move_to(_small_targets(robot.flange_pose())[1], 0.05)
        finally:
            robot.stop, robot._move_to = real_stop, real_move
        assert stops, "an interrupted move_to must call stop() (do not override move_to)"


def check_closed_robot_raises(make_workcell) -> None:
    """After close, every robot call raises RobotDisconnectedError; stop/close stay harmless."""
    cell = make_workcell()
    robot = cell.robot
    pose0, q0 = robot.flange_pose(), robot.joint_positions()
    cell.close()
    assert robot.closed
    for call in (
        robot.flange_pose,
        robot.joint_positions,
        robot.tcp_pose,
        lambda: robot.move_to(pose0, 0.05),
        lambda: robot.move_joints(q0, 0.2),
    ):
        with pytest.raises(RobotDisconnectedError):
            call()
    robot.stop()
    robot.close()
    cell.close()


def check_context_manager_closes_on_exception(make_workcell) -> None:
    """Leaving the with-block through an exception re-raises it and disconnects the robot."""

    class Boom(Exception):
        pass

    with pytest.raises(Boom):
        with make_workcell() as cell:
            robot = cell.robot
            robot.flange_pose()
            raise Boom
    assert robot.closed
    with pytest.raises(RobotDisconnectedError):
        robot.flange_pose()


def check_camera_frame(make_workcell) -> None:
    """camera.capture() returns a Frame matching the camera's intrinsics."""
    with make_workcell() as cell:
        if cell.camera is None:
            return
        assert cell.camera in cell.cameras.values()
        intr = cell.camera.intrinsics
        assert isinstance(intr, Intrinsics)
        frame = cell.camera.capture()
        assert isinstance(frame, Frame)
        assert frame.rgb.shape == (intr.height, intr.width, 3) and frame.rgb.dtype == np.uint8
        if frame.depth is not None:
            assert (
                frame.depth.shape == (intr.height, intr.width) and frame.depth.dtype == np.float32
            )


CONTRACT_CHECKS = [
    check_pose_round_trip,
    check_move_joints_read_back,
    check_safety_refuses_before_motion,
    check_confirm_mode,
    check_stop,
    check_closed_robot_raises,
    check_context_manager_closes_on_exception,
    check_camera_frame,
]


def run_contract(make_workcell) -> None:
    """Run every check in order (for scripts; tests should parametrize over CONTRACT_CHECKS)."""
    for check in CONTRACT_CHECKS:
        check(make_workcell)


# --------------------------------------------------------------------------- a minimal backend


class GantryRobot(Robot):
    """A Cartesian gantry (x, y, z in metres) with a Z-Y-X wrist (yaw, pitch, roll in radians).

    The smallest complete backend: kinematics in closed form, motion by interpolation. It is a
    stand-in for hardware in tests of ``robots`` itself, which may not import the simulator.
    ``resolution`` quantises the joints like an encoder, so the reported pose differs slightly
    from the commanded one (as on a real arm). ``on_tick(robot)`` runs at each motion step.
    """

    settle_time_s = 0.0

    def __init__(self, safety=None, tool=None, resolution: float = 0.0, on_tick=None):
        super().__init__("gantry", safety=safety, tool=tool)
        self._limits = np.array(
            [
                [-0.6, 0.6],
                [-0.6, 0.6],
                [0.05, 1.0],
                [-np.pi, np.pi],
                [-1.4, 1.4],
                [-2 * np.pi, 2 * np.pi],
            ]
        )
        self._q = np.array([0.0, 0.0, 0.5, 0.0, 0.0, np.pi])  # flange pointing down
        self.resolution = resolution
        self.on_tick = on_tick
        self.stop_count = 0
        self.time_s = 0.0

    def _fk(self, q) -> np.ndarray:
        yaw, pitch, roll = q[3:]
        return pose_from_euler_zyx(yaw, pitch, roll, t=q[:3])

    def _ik(self, T) -> np.ndarray:
        yaw, pitch, roll = euler_zyx_from_pose(T)
        q = np.concatenate([T[:3, 3], [yaw, pitch, roll]])
        # Keep roll continuous with the current value (it may wrap by 2 pi).
        q[5] += 2 * np.pi * np.round((self._q[5] - q[5]) / (2 * np.pi))
        lo, hi = self._limits.T
        if np.any(q < lo) or np.any(q > hi):
            j = int(np.flatnonzero((q < lo) | (q > hi))[0])
            raise UnreachableError(
                f"gantry joint {j} would need {q[j]:.3f}, outside [{lo[j]}, {hi[j]}]"
            )
        return q

    def _set(self, q) -> None:
        if self.resolution:
            q = np.round(q / self.resolution) * self.resolution
        self._q = q

    def flange_pose(self) -> np.ndarray:
        self._require_open()
        return self._fk(self._q)

    def joint_positions(self) -> np.ndarray:
        self._require_open()
        return self._q.copy()

    def joint_limits(self) -> np.ndarray:
        return self._limits.copy()

    def stop(self) -> None:
        self.stop_count += 1

    def _move_to(self, base_T_flange, speed) -> None:
        q_goal = self._ik(base_T_flange)  # refuse before the first step
        start = self.flange_pose()
        distance = np.linalg.norm(base_T_flange[:3, 3] - start[:3, 3])
        steps = max(2, int(np.ceil(distance / 0.005)))
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix([start[:3, :3], base_T_flange[:3, :3]]))
        for s in np.linspace(0.0, 1.0, steps)[1:]:
            T = make_pose(slerp(s).as_matrix(), (1 - s) * start[:3, 3] + s * base_T_flange[:3, 3])
            self._set(q_goal if s == 1.0 else self._ik(T))
            self.time_s += distance / speed / (steps - 1)
            if self.on_tick is not None:
                self.on_tick(self)

    def _move_joints(self, q, speed) -> None:
        self._ik(self._fk(q))  # refuses targets outside the gantry's travel
        start = self._q.copy()
        steps = max(2, int(np.ceil(np.abs(q - start).max() / 0.01)))
        for s in np.linspace(0.0, 1.0, steps)[1:]:
            self._set((1 - s) * start + s * q)
            if self.on_tick is not None:
                self.on_tick(self)


class BoardCamera(Camera):
    """An eye-in-hand camera that sees one flat chessboard, rendered by a plane homography.

    ``flange_T_cam`` places the optical frame on the flange; ``base_T_board`` is the board's
    frame (origin at the first inner corner, z into the board). ``inner`` = (cols, rows) of
    inner corners, ``square_m`` the square size. Rendering is exact projective warping of a
    high-resolution texture (2x supersampled), which is all a planar target needs.
    """

    def __init__(
        self,
        robot: Robot,
        intrinsics: Intrinsics,
        flange_T_cam,
        base_T_board,
        inner=(8, 5),
        square_m=0.02,
    ):
        super().__init__("board_cam", intrinsics)
        self.robot, self.flange_T_cam, self.base_T_board = robot, flange_T_cam, base_T_board
        self.inner, self.square_m = inner, square_m
        self.m_per_px = square_m / 40  # texture resolution: 40 px per square
        cols, rows = inner[0] + 1, inner[1] + 1  # squares
        margin = 40
        h, w = rows * 40 + 2 * margin, cols * 40 + 2 * margin
        v, u = np.mgrid[0:h, 0:w]
        # Texture pixel centres at integers; the board origin (first inner corner) sits between
        # pixel centres so no corner is biased by half a pixel.
        self._origin_px = margin + 40 - 0.5
        x = (u - self._origin_px) * self.m_per_px
        y = (v - self._origin_px) * self.m_per_px
        inside = (u >= margin) & (u < w - margin) & (v >= margin) & (v < h - margin)
        black = (np.floor(x / square_m + 1e-9) + np.floor(y / square_m + 1e-9)) % 2 == 0
        self.texture = np.where(inside & black, 20, 235).astype(np.uint8)
        self.clock = 0.0

    def true_cam_T_board(self) -> np.ndarray:
        base_T_cam = compose(self.robot.flange_pose(), self.flange_T_cam)
        return np.linalg.inv(base_T_cam) @ self.base_T_board

    def capture(self) -> Frame:
        import cv2

        k = self.intrinsics
        ss = 2  # supersampling factor
        K = np.diag([ss, ss, 1.0]) @ k.K
        K[0, 2], K[1, 2] = (k.cx + 0.5) * ss - 0.5, (k.cy + 0.5) * ss - 0.5
        T = self.true_cam_T_board()
        board_from_tex = np.array(
            [
                [self.m_per_px, 0, -self._origin_px * self.m_per_px],
                [0, self.m_per_px, -self._origin_px * self.m_per_px],
                [0, 0, 1.0],
            ]
        )
        H = K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ board_from_tex
        big = cv2.warpPerspective(
            self.texture, H, (k.width * ss, k.height * ss), flags=cv2.INTER_LINEAR, borderValue=128
        )
        gray = cv2.resize(big, (k.width, k.height), interpolation=cv2.INTER_AREA)
        self.clock += 1 / 30
        return Frame(np.repeat(gray[:, :, None], 3, axis=2), None, self.clock, self.name)


def make_gantry_cell(resolution: float = 0.0, tool=None) -> Workcell:
    """A gantry with an eye-in-hand camera above a 9 x 6-square chessboard lying on the table."""
    robot = GantryRobot(
        tool=tool if tool is not None else Pointer("pointer", make_pose(t=[0, 0, 0.1])),
        resolution=resolution,
    )
    intrinsics = Intrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
    flange_T_cam = pose_from_rotvec([0.0, 0.0, np.radians(3)], [0.04, 0.01, 0.03])
    # Board z points down into the table, so a camera looking down sees cam_T_board ~ identity.
    base_T_board = make_pose(np.diag([1.0, -1.0, -1.0]), [-0.08, 0.05, 0.0])
    camera = BoardCamera(robot, intrinsics, flange_T_cam, base_T_board)
    return Workcell(robot, camera, kind="gantry")
