"""The interfaces, the backend registry, and the contract suite run on the stand-in gantry."""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from contract import CONTRACT_CHECKS, BoardCamera, GantryRobot, make_gantry_cell

import robots
from robots import (
    BackendNotAvailableError,
    Frame,
    Intrinsics,
    Pointer,
    Robot,
    RobotDisconnectedError,
    SafetyError,
    UnreachableError,
    Workcell,
    connect,
    register_backend,
)
from robots.backends import resolve_connect_options
from robots.capture import chessboard_detector
from robots.geometry import make_pose, translation_error

# --------------------------------------------------------------------------- Intrinsics


def test_intrinsics_K_and_validation():
    i = Intrinsics(600, 610, 319.5, 239.5, 640, 480)
    np.testing.assert_array_equal(i.K, [[600, 0, 319.5], [0, 610, 239.5], [0, 0, 1]])
    assert i.size == (640, 480) and i.dist.shape == (5,) and not i.dist.any()
    assert Intrinsics(600, 600, 320, 240, 640, 480, dist=[0.1, -0.2, 0.0, 0.0]).dist[4] == 0.0
    for bad, match in [
        (dict(fx=-1), "positive"),
        (dict(fy=np.nan), "finite"),
        (dict(width=640.5), "whole"),
        (dict(height=0), "positive"),
        (dict(dist=[0.1, 0.2, 0.3]), "5 coefficients"),
        (dict(dist=[np.nan] * 5), "finite"),
        (dict(cx="a"), "number"),
    ]:
        kwargs = dict(fx=600, fy=600, cx=320, cy=240, width=640, height=480) | bad
        with pytest.raises(ValueError, match=match):
            Intrinsics(**kwargs)


def test_intrinsics_are_immutable_comparable_and_round_trip():
    i = Intrinsics(600.25, 600.5, 320.1, 240.2, 640, 480, dist=[0.1, -0.05, 1e-3, -2e-3, 0.01])
    with pytest.raises(dataclasses.FrozenInstanceError):
        i.fx = 1.0
    with pytest.raises(ValueError):
        i.dist[0] = 5.0  # read-only array
    assert Intrinsics.from_dict(i.to_dict()) == i and hash(
        Intrinsics.from_dict(i.to_dict())
    ) == hash(i)
    assert Intrinsics.from_K(i.K, 640, 480, i.dist) == i
    assert i != Intrinsics(600.25, 600.5, 320.1, 240.2, 640, 480)
    with pytest.raises(ValueError, match="K must be"):
        Intrinsics.from_K([[600, 1, 320], [0, 600, 240], [0, 0, 1]], 640, 480)


def test_scaled_intrinsics_match_what_cv2_resize_does_to_the_image():
    """Corners detected in a cv2.resize'd image are where the scaled intrinsics project them."""
    import cv2

    cell = make_gantry_cell()
    camera = cell.camera
    frame = camera.capture()
    small_rgb = cv2.resize(frame.rgb, (320, 240), interpolation=cv2.INTER_AREA)
    small = camera.intrinsics.scaled(320, 240)
    detection = chessboard_detector(8, 5, 0.02)(Frame(small_rgb, None, 0.0), small)
    assert detection is not None
    T = camera.true_cam_T_board()
    projected, _ = cv2.projectPoints(
        detection.object_points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], small.K, small.dist
    )
    error = np.linalg.norm(projected.reshape(-1, 2) - detection.corners_px, axis=1)
    assert error.mean() < 0.08, error.mean()
    # The naive cx * s scaling is a quarter pixel off at half size; this test would see it.
    naive_shift = np.array([0.25, 0.25])
    naive_error = np.linalg.norm(
        projected.reshape(-1, 2) + naive_shift - detection.corners_px, axis=1
    )
    assert naive_error.mean() > 2 * error.mean()


# --------------------------------------------------------------------------- Frame and tools


def test_frame_validation():
    rgb = np.zeros((4, 5, 3), np.uint8)
    f = Frame(rgb, np.ones((4, 5)), 1.5)
    assert f.depth.dtype == np.float32 and (f.height, f.width) == (4, 5) and f.camera_name == "cam"
    with pytest.raises(ValueError, match="uint8"):
        Frame(rgb.astype(float), None, 0.0)
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        Frame(np.zeros((4, 5), np.uint8), None, 0.0)
    with pytest.raises(ValueError, match="aligned"):
        Frame(rgb, np.ones((5, 4), np.float32), 0.0)
    with pytest.raises(ValueError, match="millimetres"):
        Frame(rgb, np.ones((4, 5), np.uint16), 0.0)
    with pytest.raises(ValueError, match="finite"):
        Frame(rgb, None, np.nan)


def test_pointer_cannot_grasp_and_tools_validate_their_offset():
    p = Pointer(flange_T_tcp=make_pose(t=[0, 0, 0.12]))
    with pytest.raises(RuntimeError, match="cannot grasp.*Gripper or SuctionCup"):
        p.grasp()
    p.release()
    assert not p.is_holding and p.flange_T_tcp[2, 3] == 0.12
    with pytest.raises(ValueError, match="flange_T_tcp"):
        Pointer(flange_T_tcp=np.diag([1, 1, -1, 1.0]))


def test_interfaces_are_abstract():
    with pytest.raises(TypeError):
        Robot("x")
    with pytest.raises(TypeError):
        robots.Camera("x", Intrinsics(1, 1, 0, 0, 2, 2))


# --------------------------------------------------------------------------- Robot template


def test_move_tcp_to_puts_the_tool_tip_on_the_target():
    with make_gantry_cell() as cell:
        target = cell.robot.tcp_pose()
        target[:3, 3] += [0.02, -0.03, 0.01]
        cell.robot.move_tcp_to(target, 0.05)
        assert translation_error(cell.robot.tcp_pose(), target) < 1e-9


def test_an_error_during_the_move_stops_the_robot_and_propagates():
    robot = GantryRobot()
    out_of_travel = robot.flange_pose()
    out_of_travel[0, 3] = 0.7  # inside the safety box, beyond the gantry's 0.6 m travel
    robot.safety.max_step = 1.0
    with pytest.raises(UnreachableError, match="joint 0"):
        robot.move_to(out_of_travel, 0.1)
    assert robot.stop_count == 1

    def interrupt_half_way(r):
        if r.flange_pose()[0, 3] > 0.05:
            raise KeyboardInterrupt

    robot.on_tick = interrupt_half_way
    target = robot.flange_pose()
    target[0, 3] = 0.1
    with pytest.raises(KeyboardInterrupt):
        robot.move_to(target, 0.1)
    assert robot.stop_count == 2
    assert 0.05 < robot.flange_pose()[0, 3] < 0.1  # stopped part-way, as a real arm would


@pytest.mark.parametrize("check", CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_the_gantry_stand_in_passes_the_contract(check):
    check(make_gantry_cell)


class SkipsSafety(GantryRobot):
    """A broken backend: overrides the public move_to and so bypasses the safety checks."""

    def move_to(self, base_T_flange, speed=0.1):
        self._move_to(np.asarray(base_T_flange, float), speed)


class ForgetsClosed(GantryRobot):
    """A broken backend: keeps answering after close."""

    def flange_pose(self):
        return self._fk(self._q)


@pytest.mark.parametrize(
    "broken, check",
    [
        (SkipsSafety, "check_safety_refuses_before_motion"),
        (ForgetsClosed, "check_closed_robot_raises"),
    ],
)
def test_the_contract_catches_broken_backends(broken, check):
    import contract

    def make():
        robot = broken(tool=Pointer())
        cam = BoardCamera(robot, Intrinsics(600, 600, 319.5, 239.5, 640, 480), np.eye(4), np.eye(4))
        return Workcell(robot, cam)

    with pytest.raises((AssertionError, pytest.fail.Exception)):
        getattr(contract, check)(make)


# --------------------------------------------------------------------------- Workcell


class Recorder(GantryRobot):
    def __init__(self, log):
        super().__init__()
        self.log = log

    def stop(self):
        self.log.append("robot.stop")

    def _close(self):
        self.log.append("robot.close")


class LoggingCamera(BoardCamera):
    def __init__(self, robot, log, name, fail=False):
        super().__init__(robot, Intrinsics(600, 600, 319.5, 239.5, 640, 480), np.eye(4), np.eye(4))
        self.name, self.log, self.fail = name, log, fail

    def close(self):
        self.log.append(f"{self.name}.close")
        if self.fail:
            raise OSError("camera unplugged")


def test_workcell_stops_first_then_closes_everything_even_if_a_camera_fails():
    log = []
    robot = Recorder(log)
    left, right = LoggingCamera(robot, log, "left", fail=True), LoggingCamera(robot, log, "right")
    cell = Workcell(robot, cameras={"left": left, "right": right})
    assert cell.camera is left
    with pytest.raises(OSError, match="unplugged"):
        with cell:
            pass
    assert log == ["robot.stop", "left.close", "right.close", "robot.stop", "robot.close"]
    assert robot.closed
    cell.close()  # idempotent
    assert len(log) == 5


def test_workcell_exit_keeps_the_users_exception_when_cleanup_also_fails():
    log = []
    robot = Recorder(log)
    cell = Workcell(robot, LoggingCamera(robot, log, "cam", fail=True))
    with pytest.warns(RuntimeWarning, match="closing the workcell also failed"):
        with pytest.raises(ZeroDivisionError):
            with cell:
                raise ZeroDivisionError
    assert robot.closed


def test_closed_robot_message_says_what_to_do():
    robot = GantryRobot()
    robot.close()
    with pytest.raises(RobotDisconnectedError, match=r"closed.*robots\.connect"):
        robot.move_to(np.eye(4))


# --------------------------------------------------------------------------- connect


def test_unknown_kind_lists_the_known_ones():
    with pytest.raises(ValueError, match="known kinds: aubo, cobotta, franka, sim, ur"):
        connect("kuka")


@pytest.mark.parametrize(
    "kind, sdk_modules",
    [
        ("ur", ["rtde_control", "rtde_io", "rtde_receive"]),
        ("franka", ["panda_py"]),
        ("aubo", ["pyaubo_sdk"]),
    ],
)
def test_a_missing_sdk_says_how_to_install_it(monkeypatch, kind, sdk_modules):
    # A None entry in sys.modules makes `import name` fail as if the SDK were not installed.
    # The host is on loopback so that nothing ever leaves this machine, even if a check slips.
    for name in sdk_modules:
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(BackendNotAvailableError, match=r"pip install cobotlab\[real\]") as info:
        connect(kind, host="127.0.0.1")
    assert isinstance(info.value, ImportError)


def test_registered_backends_get_the_options(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COBOTLAB_KIND", raising=False)
    received = {}

    def factory(**options):
        received.update(options)
        return make_gantry_cell()

    monkeypatch.setitem(robots.backends._registry, "gantry", factory)
    with connect("gantry", resolution=1e-4) as cell:
        assert cell.kind == "gantry" and received == {"resolution": 1e-4}
    assert "gantry" in robots.available_backends()
    monkeypatch.setitem(robots.backends._registry, "broken", lambda **kw: "not a cell")
    with pytest.raises(TypeError, match="not a robots.Workcell"):
        connect("broken")
    with pytest.raises(ValueError, match="callable"):
        register_backend("x", 42)


def test_option_precedence_arguments_then_environment_then_lab_toml(tmp_path):
    (tmp_path / "lab.toml").write_text(
        '[connect]\nkind = "ur"\n[connect.ur]\nhost = "127.0.0.11"\nport = 30004\n'
        '[connect.sim]\narm = "ur5e"\nseed = 3\n'
    )
    assert resolve_connect_options(None, {}, tmp_path, {}) == (
        "ur",
        {"host": "127.0.0.11", "port": 30004},
    )
    env = {"COBOTLAB_KIND": "sim", "COBOTLAB_HOST": "127.0.0.19"}
    # The environment picks sim; the host is a real-robot setting and is not passed to sim.
    assert resolve_connect_options(None, {}, tmp_path, env) == ("sim", {"arm": "ur5e", "seed": 3})
    assert resolve_connect_options("ur", {}, tmp_path, env) == (
        "ur",
        {"host": "127.0.0.19", "port": 30004},
    )
    assert resolve_connect_options("ur", {"host": "h"}, tmp_path, env)[1]["host"] == "h"
    assert resolve_connect_options("sim", {"seed": 7}, tmp_path, {}) == (
        "sim",
        {"arm": "ur5e", "seed": 7},
    )
    assert resolve_connect_options(None, {}, tmp_path / "missing", {}) == ("sim", {})
    (tmp_path / "lab.toml").write_text("[connect\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        resolve_connect_options(None, {}, tmp_path, {})


def test_importing_robots_loads_no_backend_and_no_opencv():
    code = (
        "import sys, robots, robots.capture, robots.calibration_io; "
        "print([m for m in ('pybullet', 'cv2', 'sim_backends') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_safety_error_comes_before_unreachable():
    """The arm is asked nothing (no IK, no motion) when the safety check fails."""
    robot = GantryRobot()
    target = robot.flange_pose()
    target[2, 3] = -0.2
    with pytest.raises(SafetyError):
        robot.move_to(target, 0.1)
    assert robot.stop_count == 0 and robot.time_s == 0.0
