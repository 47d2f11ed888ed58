"""The AUBO-i5 driver (robots/drivers/aubo.py) against a fake pyaubo_sdk with the same API."""

import time
from operator import attrgetter

import numpy as np
import pytest
from fakes import aubo_fake

from robots import RobotDisconnectedError, SuctionCup
from robots.drivers import aubo
from robots.geometry import make_pose, pose_from_rotvec, translation_error

contract = pytest.importorskip("contract", reason="tests/contract.py (the backend contract) missing")


def make_cell(**options):
    options.setdefault("poll_s", 0.001)
    return aubo.create_workcell("127.0.0.41", sdk=aubo_fake.make_sdk(), **options)


def fake_arm():
    return aubo_fake.FakeRpcClient.instances[-1].arm


@pytest.mark.parametrize("check", contract.CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_aubo_contract(check):
    check(lambda: make_cell(suction_pin=3))


# --------------------------------------------------------------------------- conventions


def test_zyx_euler_convention_matches_the_sdk_documentation():
    # Distinct, large angles so any other order (XYZ intrinsic, ZYX with swapped roles) differs.
    pose6 = [0.4, -0.1, 0.3, 0.7, -0.4, 1.9]
    expected = aubo_fake.matrix_from_pose6(pose6)  # Rz(rz) @ Ry(ry) @ Rx(rx), written out
    np.testing.assert_allclose(aubo.pose_from_aubo(pose6), expected, atol=1e-12)
    np.testing.assert_allclose(aubo.aubo_from_pose(expected), pose6, atol=1e-12)
    # The other plausible reading, R = Rx Ry Rz, is a different matrix for these angles.
    other = aubo_fake._rx(0.7) @ aubo_fake._ry(-0.4) @ aubo_fake._rz(1.9)
    assert np.abs(other - expected[:3, :3]).max() > 0.1
    with pytest.raises(ValueError, match="6 finite"):
        aubo.pose_from_aubo([0, 0, 0, np.nan, 0, 0])


def test_flange_pose_excludes_the_tcp_offset_and_moves_send_tcp_targets():
    with make_cell() as cell:
        arm = fake_arm()
        robot = cell.robot
        flange = robot.flange_pose()
        np.testing.assert_allclose(flange, aubo_fake.flange_fk(arm.q), atol=1e-12)
        tcp = aubo.pose_from_aubo(aubo_fake.FakeRobotState(arm).getTcpPose())
        assert translation_error(flange, tcp) > 0.1  # the 12 cm offset is really there
        np.testing.assert_allclose(robot.tcp_offset(), aubo_fake.matrix_from_pose6(arm.tcp_offset))

        target = flange @ pose_from_rotvec([0, 0.1, 0], [0.02, 0.01, -0.02])
        robot.move_to(target, 0.05)
        kind, sent, _a, v, blend, duration = arm.commands[-1]
        assert kind == "moveLine" and v == 0.05 and blend == 0.0 and duration == 0.0
        np.testing.assert_allclose(
            aubo_fake.matrix_from_pose6(sent),
            target @ aubo_fake.matrix_from_pose6(arm.tcp_offset),
            atol=1e-12,
        )
        np.testing.assert_allclose(robot.flange_pose(), target, atol=1e-9)


def test_move_waits_for_the_exec_id_to_clear():
    with make_cell() as cell:
        arm = fake_arm()
        arm.ticks_per_move = 25
        target = cell.robot.flange_pose() @ make_pose(t=[0.01, 0, 0])
        cell.robot.move_to(target, 0.05)
        assert arm.exec_id == -1 and arm.pending is None
        np.testing.assert_allclose(cell.robot.flange_pose(), target, atol=1e-9)


def test_stuck_move_times_out_and_stops():
    with make_cell(motion_timeout_s=0.2) as cell:
        arm = fake_arm()
        arm.stuck = True
        target = cell.robot.flange_pose() @ make_pose(t=[0.01, 0, 0])
        with pytest.raises(aubo.AuboTimeoutError, match="did not finish within"):
            cell.robot.move_to(target, 0.05)
        assert ("stopLine", 1.0, 2.0) in arm.stops and arm.exec_id == -1


def test_refused_move_raises_with_the_code():
    with make_cell() as cell:
        fake_arm().reject_code = -1
        target = cell.robot.flange_pose() @ make_pose(t=[0.01, 0, 0])
        with pytest.raises(aubo.AuboMotionError, match="code -1"):
            cell.robot.move_to(target, 0.05)
        with pytest.raises(aubo.AuboMotionError, match="code -1"):
            cell.robot.move_joints(cell.robot.joint_positions() + 0.01, 0.2)


def test_positive_codes_are_refusals_raised_at_once_naming_the_cause():
    # The controller answers moveLine/moveJoint with +1 (AUBO_BAD_STATE) while a safeguard
    # stop is active: nothing is queued, so nothing may be reported as done.
    with make_cell() as cell:
        arm, robot = fake_arm(), cell.robot
        arm.safety_mode = aubo_fake.SafetyModeType.SafeguardStop
        q0 = robot.joint_positions()
        target = robot.flange_pose() @ make_pose(t=[0.01, 0, 0])
        for move in (lambda: robot.move_to(target, 0.05), lambda: robot.move_joints(q0 + 0.01, 0.2)):
            started = time.monotonic()
            with pytest.raises(aubo.AuboMotionError, match=r"code 1\).*SafeguardStop.*pendant"):
                move()
            assert time.monotonic() - started < 0.5  # at once, not after a wait
        np.testing.assert_allclose(robot.joint_positions(), q0)
        arm.safety_mode = aubo_fake.SafetyModeType.Normal
        for code, words in ((2, "queue is full"), (3, "still running")):
            arm.reject_code = code
            with pytest.raises(aubo.AuboRefusedError, match=words) as refused:
                robot.move_joints(q0 + 0.01, 0.2)
            assert refused.value.code == code


def test_pure_wrist_turn_is_sent_as_rotational_speed_and_timed_as_rotation():
    # Under 1 mm of TCP travel the controller reads a and v as rad/s^2 and rad/s. A 1 rad turn
    # at speed=0.1 must go at the driver's rotation rate and finish within its time limit.
    with make_cell(motion_timeout_s=0.2) as cell:
        arm, robot = fake_arm(), cell.robot
        arm.time_scale = 20.0
        start = robot.flange_pose()
        offset = robot.tcp_offset()
        turn = pose_from_rotvec([0, 0, 1.0])  # about the TCP's own axis: the TCP stays put
        target = start @ offset @ turn @ np.linalg.inv(offset)
        robot.move_to(target, 0.1)
        _kind, _pose, a, v, _blend, _duration = arm.commands[-1]
        plan = arm.last_plan
        assert plan["rotational"] and v == pytest.approx(robot.max_rotation_speed)
        assert a == pytest.approx(robot.rotation_acceleration)
        np.testing.assert_allclose(robot.flange_pose(), target, atol=1e-9)


def test_turn_with_a_short_translation_keeps_its_rate():
    # 1.5 mm of travel (linear units) with a 1 rad turn: at 0.1 m/s the travel would take 15 ms
    # and the wrist would whip round at the controller's limit; the driver slows the line down.
    with make_cell() as cell:
        arm, robot = fake_arm(), cell.robot
        offset = robot.tcp_offset()
        tcp_step = make_pose(t=[0.0015, 0, 0]) @ pose_from_rotvec([1.0, 0, 0])
        target = robot.flange_pose() @ offset @ tcp_step @ np.linalg.inv(offset)
        robot.move_to(target, 0.1)
        plan = arm.last_plan
        assert not plan["rotational"]
        assert plan["rotation_rate"] <= 0.5 * 1.001  # the driver's default max_rotation_speed


def test_plan_line_units_and_duration():
    a, v, planned, rotational = aubo.plan_line(0.0, 1.0, 0.1, 0.5, 0.5, 1.0)
    assert rotational and (a, v) == (1.0, 0.5) and planned == pytest.approx(1 / 0.5 + 0.5 / 1.0)
    a, v, planned, rotational = aubo.plan_line(0.1, 0.0, 0.1, 0.5, 0.5, 1.0)
    assert not rotational and (a, v) == (0.5, 0.1) and planned == pytest.approx(1.0 + 0.2)
    _a, v, planned, _ = aubo.plan_line(0.01, 1.0, 0.1, 0.5, 0.5, 1.0)  # turn-bound
    assert v == pytest.approx(0.005) and planned >= 2.0


# --------------------------------------------------------------------------- connection


def test_unreachable_controller_and_bad_login(monkeypatch):
    monkeypatch.setattr(aubo_fake.FakeRpcClient, "reachable", False)
    with pytest.raises(aubo.AuboError, match="could not reach"):
        make_cell()
    monkeypatch.setattr(aubo_fake.FakeRpcClient, "reachable", True)
    with pytest.raises(aubo.AuboError, match="login"):
        make_cell(password="wrong")
    assert not aubo_fake.FakeRpcClient.instances[-1].connected


def test_close_logs_out_and_disconnects():
    cell = make_cell(suction_pin=2)
    client = aubo_fake.FakeRpcClient.instances[-1]
    cell.close()
    assert not client.connected and not client.logged_in
    with pytest.raises(RobotDisconnectedError):
        cell.robot.tool.grasp()


# --------------------------------------------------------------------------- suction cup


def test_suction_cup_switches_the_digital_output():
    offset = make_pose(t=[0, 0, 0.09])
    with make_cell(suction_pin=4, tool_offset=offset) as cell:
        cup = cell.robot.tool
        assert isinstance(cup, SuctionCup)
        np.testing.assert_allclose(cup.flange_T_tcp, offset)
        arm = fake_arm()
        assert cup.grasp() is True and arm.outputs[4] is True and cup.is_holding
        cup.release()
        assert arm.outputs[4] is False and not cup.is_holding


def test_suction_cup_with_vacuum_sensor_reports_a_miss():
    with make_cell(suction_pin=4, suction_sensor_pin=1) as cell:
        cup, arm = cell.robot.tool, fake_arm()
        cup.sensor_wait_s = 0.05
        assert cup.grasp() is False  # vacuum on, but the switch never closed
        arm.inputs[1] = True
        assert cup.grasp() is True and cup.is_holding


def test_default_tool_offset_is_the_controllers():
    with make_cell(suction_pin=4) as cell:
        np.testing.assert_allclose(cell.robot.tool.flange_T_tcp, cell.robot.tcp_offset())


# --------------------------------------------------------------------------- the real SDK


def test_fake_has_every_name_the_driver_uses():
    sdk = aubo_fake.make_sdk()
    for name in aubo_fake.SDK_NAMES:
        attrgetter(name)(sdk)


def test_installed_pyaubo_sdk_exposes_the_names_the_driver_uses():
    try:
        sdk = aubo._import_sdk(None)
    except ImportError as error:
        pytest.skip(f"pyaubo-sdk is not installed here ({error}); the `real` extra brings it")
    missing = []
    for name in aubo_fake.SDK_NAMES:
        try:
            attrgetter(name)(sdk)
        except AttributeError:
            missing.append(name)
    assert not missing, f"pyaubo_sdk lacks {missing}; the fake and the driver must follow it"


def test_installed_pyaubo_sdk_codes_units_and_modes_match_the_driver_and_fake():
    try:
        sdk = aubo._import_sdk(None)
    except ImportError as error:
        pytest.skip(f"pyaubo-sdk is not installed here ({error}); the `real` extra brings it")
    codes = sdk.AuboErrorCodes
    assert (int(codes.AUBO_BAD_STATE), int(codes.AUBO_QUEUE_FULL), int(codes.AUBO_BUSY)) == (1, 2, 3)
    assert int(codes.AUBO_TIMEOUT) == 4 and int(codes.AUBO_INVL_ARGUMENT) == 5
    # moveLine(pose, a, v, blend_radius, duration) -> int: five arguments, an int code back.
    for name in ("moveLine", "moveJoint"):
        doc = getattr(sdk.MotionControl, name).__doc__
        signature = doc.strip().splitlines()[0]
        assert "arg0: List[float], arg1: float, arg2: float, arg3: float, arg4: float) -> int" in (
            signature), signature
    real_modes = {name: int(value) for name, value in sdk.SafetyModeType.__members__.items()}
    fake_modes = {m.name: int(m) for m in aubo_fake.SafetyModeType}
    assert fake_modes == real_modes
