"""The Franka Panda driver (robots/drivers/franka.py) against a fake panda_py with the same API."""

import inspect
from operator import attrgetter

import numpy as np
import pytest
from fakes import franka_fake
from scipy.spatial.transform import Rotation

import robots.backends
from robots import RobotDisconnectedError, connect, register_backend
from robots.drivers import franka
from robots.geometry import make_pose, pose_from_rotvec, translation_error

contract = pytest.importorskip("contract", reason="tests/contract.py (the backend contract) missing")


def make_cell(**options):
    options.setdefault("realtime", "ignore")  # this test machine has no PREEMPT_RT kernel
    with pytest.warns(RuntimeWarning, match="real-time checks disabled"):
        return franka.create_workcell("127.0.0.31", sdk=franka_fake.make_sdk(), **options)


@pytest.mark.parametrize("check", contract.CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_franka_contract(check):
    # The Panda's impedance controllers settle a little short of the goal (the fake reproduces
    # it), so the contract is held to the tolerances the driver documents and the arm meets.
    tolerances = {"tol_m": franka.POSITION_TOLERANCE_M, "tol_deg": franka.ORIENTATION_TOLERANCE_DEG,
                  "tol_rad": franka.JOINT_TOLERANCE_RAD}
    accepted = inspect.signature(check).parameters
    check(make_cell, **{k: v for k, v in tolerances.items() if k in accepted})


# --------------------------------------------------------------------------- conventions


def test_column_major_round_trip_is_the_transpose_of_row_major():
    T = pose_from_rotvec([0.3, -0.2, 1.1], [0.4, -0.1, 0.5])
    values = franka.column_major_from_pose(T)
    # Column-major: the first four numbers are the first column, the translation is 12..14.
    np.testing.assert_allclose(values[0:4], T[:, 0])
    np.testing.assert_allclose(values[12:15], T[:3, 3])
    np.testing.assert_allclose(values, T.T.reshape(-1))
    np.testing.assert_allclose(franka.pose_from_column_major(values), T, atol=0)
    # Reading the vector row by row gives the transpose, which is not a pose: refuse it.
    with pytest.raises(ValueError):
        franka.pose_from_column_major(T.reshape(-1))
    with pytest.raises(ValueError, match="16"):
        franka.pose_from_column_major(values[:12])


def test_flange_pose_removes_the_hand_offset():
    with make_cell() as cell:
        panda = franka_fake.FakePanda.instances[-1]
        np.testing.assert_allclose(
            cell.robot.flange_pose(), franka_fake.flange_fk(panda.q), atol=1e-12
        )
        hand = cell.robot.tool
        assert isinstance(hand, franka.FrankaGripper)
        np.testing.assert_allclose(hand.flange_T_tcp[2, 3], 0.1034)
        np.testing.assert_allclose(
            cell.robot.tcp_pose(), pose_from_column_major_state(panda), atol=1e-12
        )


def pose_from_column_major_state(panda):
    return np.array(panda.get_state().O_T_EE).reshape(4, 4).T


def test_fake_kinematics_match_panda_py_if_installed():
    panda_py = pytest.importorskip("panda_py", reason="panda-python not installed here")
    hand_panda_py = make_pose(Rotation.from_euler("z", -np.pi / 4).as_matrix(), [0, 0, 0.103])
    rng = np.random.default_rng(0)
    for q in rng.uniform(franka_fake.LOWER, franka_fake.UPPER, size=(5, 7)):
        # panda_py.fk includes its own hand offset of 0.103 m (Desk's default is 0.1034 m).
        np.testing.assert_allclose(
            franka_fake.flange_fk(q), panda_py.fk(q) @ np.linalg.inv(hand_panda_py), atol=1e-9
        )


# --------------------------------------------------------------------------- motion details


def test_move_to_streams_quaternions_xyzw_and_follows_a_line():
    seen = []
    with make_cell() as cell:
        robot = cell.robot
        start = robot.flange_pose()
        target = start @ pose_from_rotvec([0, 0, np.radians(10)], [0.04, 0.0, 0.0])
        panda = franka_fake.FakePanda.instances[-1]
        panda.settles_short = False  # this test is about the streamed line, not the settling
        real_tick = panda._tick

        def watching_tick():
            real_tick()
            seen.append(robot.flange_pose()[:3, 3])

        panda._tick = watching_tick
        robot.move_to(target, speed=0.05)
        assert translation_error(robot.flange_pose(), target) < 1e-4
    path = np.array(seen)
    direction = (target[:3, 3] - start[:3, 3]) / np.linalg.norm(target[:3, 3] - start[:3, 3])
    offsets = path - start[:3, 3]
    off_line = offsets - np.outer(offsets @ direction, direction)
    assert np.abs(off_line).max() < 1e-4, "the flange left the straight line"
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1) * franka.CONTROL_RATE_HZ
    assert steps.max() <= 0.05 * 1.01, f"peak speed {steps.max():.3f} m/s over the 0.05 asked"
    assert len(path) > 50  # 4 cm at 5 cm/s with the min-jerk law takes 1.5 s = 150 ticks


def test_stuck_arm_times_out_and_stops():
    with make_cell(settle_timeout_s=0.5) as cell:
        panda = franka_fake.FakePanda.instances[-1]
        panda.stuck = True
        stops = panda.stop_count
        target = cell.robot.flange_pose() @ make_pose(t=[0.02, 0, 0])
        with pytest.raises(franka.FrankaTimeoutError, match="did not finish within"):
            cell.robot.move_to(target, 0.05)
        assert panda.stop_count > stops and panda.controller is None


def test_reflex_raises_motion_error_and_recover_clears_it():
    with make_cell() as cell:
        panda = franka_fake.FakePanda.instances[-1]
        panda.fail_after_ticks = 20
        target = cell.robot.flange_pose() @ make_pose(t=[0.03, 0, 0])
        with pytest.raises(franka.FrankaMotionError, match="recover"):
            cell.robot.move_to(target, 0.05)
        panda.fail_after_ticks = None
        with pytest.raises(franka.FrankaMotionError):  # the error is still latched
            cell.robot.move_to(target, 0.05)
        recoveries = panda.recoveries
        cell.robot.recover()
        assert panda.recoveries == recoveries + 1
        cell.robot.move_to(target, 0.05)
        assert translation_error(cell.robot.flange_pose(), target) < franka.POSITION_TOLERANCE_M


def test_move_settles_short_like_the_impedance_controller_and_succeeds():
    # The fake settles 1.5 mm / 1.5e-3 rad short and stays there, as panda-py's controllers do
    # (~2 mm / 2e-3 rad): the move must end successfully and say where it settled.
    with make_cell() as cell:
        robot = cell.robot
        target = robot.flange_pose() @ pose_from_rotvec([0, 0, np.radians(5)], [0.02, 0.01, 0])
        robot.move_to(target, 0.05)
        error = robot.last_move_error
        assert error.position_m == pytest.approx(franka_fake.SHORT_M, rel=0.05)
        assert error.orientation_rad == pytest.approx(franka_fake.SHORT_RAD, rel=0.05)
        assert error.position_m <= robot.position_tolerance_m and error.joint_rad is None
        assert translation_error(robot.flange_pose(), target) == pytest.approx(
            franka_fake.SHORT_M, rel=0.05)
        q = robot.joint_positions() + 0.1
        robot.move_joints(q, 0.3)
        assert robot.last_move_error.joint_rad == pytest.approx(franka_fake.SHORT_RAD, rel=0.05)
        assert robot.last_move_error.position_m is None


def test_timeout_reports_where_the_arm_ended():
    with make_cell(settle_timeout_s=0.3) as cell:
        panda = franka_fake.FakePanda.instances[-1]
        panda.stuck = True
        target = cell.robot.flange_pose() @ make_pose(t=[0.02, 0, 0])
        with pytest.raises(franka.FrankaTimeoutError, match=r"ended 20\.0 mm"):
            cell.robot.move_to(target, 0.05)
        assert cell.robot.last_move_error.position_m == pytest.approx(0.02, abs=1e-6)


def test_null_space_target_is_the_posture_at_the_start_of_the_move():
    # panda_py's default q_nullspace is its fixed home posture, which would drag the elbow
    # towards home during every Cartesian move made from anywhere else.
    with make_cell() as cell:
        robot = cell.robot
        panda = franka_fake.FakePanda.instances[-1]
        robot.move_joints(franka_fake.HOME_Q + np.array([0.3, 0.1, -0.2, 0.2, 0.1, 0.1, 0.0]), 0.3)
        q_before = robot.joint_positions()
        robot.move_to(robot.flange_pose() @ make_pose(t=[0.0, 0.02, 0.0]), 0.05)
        controller = panda.controllers[-1]
        assert isinstance(controller, franka_fake.FakeCartesianImpedance)
        assert controller.q_nullspace is not None, "q_nullspace left at panda_py's home default"
        np.testing.assert_allclose(controller.q_nullspace, q_before, atol=1e-12)


def test_gripper_is_homed_at_connect_so_release_opens_fully():
    # libfranka knows the Hand's max_width only after homing (the fake reads 0 before).
    with make_cell() as cell:
        hand = franka_fake.FakeGripper.instances[-1]
        assert hand.calls[0] == ("homing",)
        cell.robot.tool.release()
        assert cell.robot.tool.opening() == pytest.approx(franka_fake.FakeGripper.HAND_MAX_WIDTH)


def test_failed_homing_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(franka_fake.FakeGripper, "homing_fails", True)
    with pytest.raises(franka.FrankaError, match="homing the Franka Hand failed.*fingers"):
        make_cell()
    assert franka_fake.FakeGripper.instances[-1].stopped


def test_connect_recovers_a_left_over_error():
    with make_cell() as cell:
        assert franka_fake.FakePanda.instances[-1].recoveries == 1
        assert cell.kind == "franka"
    with make_cell(auto_recover=False):
        assert franka_fake.FakePanda.instances[-1].recoveries == 0


# --------------------------------------------------------------------------- real-time kernel


def test_no_realtime_kernel_gives_a_clear_error(monkeypatch):
    monkeypatch.setattr(franka, "host_has_realtime_kernel", lambda: False)
    with pytest.raises(franka.FrankaRealtimeError, match="PREEMPT_RT.*realtime='ignore'"):
        franka.create_workcell("127.0.0.31", sdk=franka_fake.make_sdk())


def test_sdk_realtime_error_is_translated(monkeypatch):
    # The kernel check passes but libfranka still refuses (e.g. no rtprio for this user).
    monkeypatch.setattr(franka, "host_has_realtime_kernel", lambda: True)
    monkeypatch.setattr(franka_fake.FakePanda, "host_realtime", False)
    with pytest.raises(franka.FrankaRealtimeError, match="libfranka refused.*rtprio"):
        franka.create_workcell("127.0.0.31", sdk=franka_fake.make_sdk())


def test_host_realtime_probe_matches_this_kernel():
    import os

    expected = "PREEMPT_RT" in os.uname().version
    try:
        with open("/sys/kernel/realtime") as f:
            expected = expected or f.read().strip() == "1"
    except OSError:
        pass
    assert franka.host_has_realtime_kernel() is expected


# --------------------------------------------------------------------------- gripper


def test_gripper_grasp_release_and_nothing_held():
    with make_cell() as cell:
        hand = cell.robot.tool
        fake = hand._gripper
        assert hand.grasp() is False and not hand.is_holding  # closed on nothing
        hand.release()
        assert hand.opening() == pytest.approx(fake.max_width)
        fake.object_width = 0.03
        assert hand.grasp(force=30.0) is True and hand.is_holding
        kind, width, _speed, force, eps_in, eps_out = fake.calls[-1]
        assert kind == "grasp" and force == 30.0
        assert width - eps_in == pytest.approx(0.002) and width + eps_out == pytest.approx(0.08)
        hand.release()
        assert not hand.is_holding and hand.opening() == pytest.approx(0.08)
        with pytest.raises(ValueError, match="width"):
            hand.move(0.2)
    assert fake.stopped
    with pytest.raises(RobotDisconnectedError):
        hand.grasp()


def test_no_gripper_option():
    with make_cell(gripper=False) as cell:
        assert cell.robot.tool is None


def test_connect_by_name_through_the_registry(monkeypatch):
    sdk = franka_fake.make_sdk()
    monkeypatch.setattr(robots.backends, "_registry", dict(robots.backends._registry))
    register_backend(
        "franka_fake", lambda **o: franka.create_workcell(sdk=sdk, realtime="ignore", **o)
    )
    with pytest.warns(RuntimeWarning), connect("franka_fake", host="127.0.0.31") as cell:
        assert cell.robot.name == "panda" and cell.camera is None


def test_robot_check_cli_accepts_realtime_ignore(monkeypatch, capsys):
    # A lab PC without PREEMPT_RT: `cobotlab robot check --kind franka --realtime ignore`.
    from cobotlab import cli

    sdk = franka_fake.make_sdk()
    monkeypatch.setattr(franka_fake.FakePanda, "host_realtime", False)
    monkeypatch.setattr(robots.backends, "_registry", dict(robots.backends._registry))
    register_backend("franka", lambda **o: franka.create_workcell(sdk=sdk, **o))
    monkeypatch.setattr(franka, "host_has_realtime_kernel", lambda: False)
    with pytest.warns(RuntimeWarning, match="real-time checks disabled"):
        assert cli.main(["robot", "check", "--kind", "franka", "--host", "172.16.0.2",
                         "--realtime", "ignore"]) == 0
    panda = franka_fake.FakePanda.instances[-1]
    assert panda.realtime_config == franka_fake.RealtimeConfig.kIgnore
    assert "connected: franka / panda" in capsys.readouterr().out
    # Without the flag the same PC is refused with the fix named, in one line.
    assert cli.main(["robot", "check", "--kind", "franka", "--host", "172.16.0.2"]) != 0
    assert "PREEMPT_RT" in capsys.readouterr().err


# --------------------------------------------------------------------------- the real SDK


def test_fake_has_every_name_the_driver_uses():
    sdk = franka_fake.make_sdk()
    for name in franka_fake.SDK_NAMES:
        attrgetter(name)(sdk)


def test_installed_panda_py_exposes_the_names_the_driver_uses():
    try:
        panda_py = franka._import_sdk(None)  # imports panda_py as the driver does
    except ImportError as error:
        pytest.skip(f"panda-python is not installed here ({error}); the `real` extra brings it")
    missing = []
    for name in franka_fake.SDK_NAMES:
        try:
            attrgetter(name)(panda_py)
        except AttributeError:
            missing.append(name)
    assert not missing, f"panda_py lacks {missing}; the fake and the driver must follow it"


def test_installed_panda_py_takes_q_nullspace_and_homes_the_gripper():
    sdk = pytest.importorskip("panda_py", reason="panda-python is not installed here")
    import panda_py.controllers
    import panda_py.libfranka

    doc = panda_py.controllers.CartesianImpedance.set_control.__doc__
    assert "position" in doc and "orientation" in doc and "q_nullspace" in doc, doc
    assert "-> bool" in panda_py.libfranka.Gripper.homing.__doc__
    assert hasattr(panda_py.libfranka.RobotState, "dq") and sdk.Panda is not None

