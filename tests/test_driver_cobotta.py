"""The COBOTTA driver through a b-CAP server on loopback: contract, conventions, failures."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
from contract import CONTRACT_CHECKS
from fakes.bcap_server import E_MOTOR_OFF, FakeCobottaServer

from robots import RobotDisconnectedError, Safety, SafetyError, connect
from robots.drivers._common import ConnectionTimeoutError, MotionTimeoutError
from robots.drivers.bcap import BCAPError, decode_packet
from robots.drivers.cobotta import CobottaGripper, create_workcell


@pytest.fixture
def server():
    srv = FakeCobottaServer(time_scale=20.0).start()
    yield srv
    srv.stop()


def commands(server) -> list[str]:
    """Function names (or Execute command names) the client sent, in order."""
    out = []
    for raw in server.packets:
        p = decode_packet(raw)
        out.append(p.args[1] if p.code in (17, 64) else {
            1: "Service_Start", 2: "Service_Stop", 3: "Controller_Connect",
            4: "Controller_Disconnect", 7: "Controller_GetRobot", 66: "Robot_Change",
            70: "Robot_Halt", 72: "Robot_Move", 84: "Robot_Release"}[p.code])
    return out


@pytest.mark.parametrize("check", CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_cobotta_contract(server, check):
    check(lambda: connect("cobotta", host="127.0.0.1", port=server.port, timeout_s=1.0))


def test_connect_and_close_sequence(server):
    with connect("cobotta", host="127.0.0.1", port=server.port) as cell:
        assert server.tool == "Tool0" and server.arm_taken and server.motor_on
        assert server.ext_speed == 50.0
        assert isinstance(cell.robot.tool, CobottaGripper)
    assert commands(server) == [
        "Service_Start", "Controller_Connect", "Controller_GetRobot", "TakeArm",
        "Robot_Change", "Motor", "ExtSpeed", "Robot_Halt", "Robot_Halt", "Motor", "GiveArm",
        "Robot_Release", "Controller_Disconnect", "Service_Stop",
    ]
    assert not server.motor_on and not server.arm_taken


def test_take_arm_comes_before_robot_change_and_give_arm_at_the_end(server):
    # DENSO's order: the controller refuses Robot_Change (and motion) before TakeArm.
    with connect("cobotta", host="127.0.0.1", port=server.port, service_option="WDT=400") as cell:
        sent = commands(server)
        assert sent.index("TakeArm") < sent.index("Robot_Change") < sent.index("Motor")
        assert server.tool == "Tool0" and server.service_options == ["WDT=400"]
        cell.robot.move_to(cell.robot.flange_pose(), 0.05)
    sent = commands(server)
    assert sent[-4:] == ["GiveArm", "Robot_Release", "Controller_Disconnect", "Service_Stop"]
    assert not server.arm_taken


def test_call_with_interim_replies_outlasts_the_reply_limit(server):
    # CurPos answered by S_EXECUTING every 0.25 s for 1 s while a 0.4 s reply limit holds: the
    # controller is busy but alive, so the driver waits instead of dropping the link.
    with connect("cobotta", host="127.0.0.1", port=server.port, timeout_s=0.4) as cell:
        server.executing_notices, server.executing_interval_s = 4, 0.25
        np.testing.assert_allclose(cell.robot.flange_pose()[:3, 3], [0.2, 0.0, 0.2])
        server.executing_notices = 0


def test_failed_connect_releases_what_was_opened(server):
    server.fail_next["Motor"] = E_MOTOR_OFF
    with pytest.raises(BCAPError, match="0x81501003"):
        connect("cobotta", host="127.0.0.1", port=server.port)
    assert commands(server)[-4:] == ["GiveArm", "Robot_Release", "Controller_Disconnect",
                                     "Service_Stop"]
    assert not server.arm_taken


def elementary(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_position_units_and_euler_order(server):
    # DENSO (RX, RY, RZ) = rotations about fixed X, then Y, then Z: R = Rz @ Ry @ Rx.
    server.position = np.array([210.0, -35.0, 180.0, 30.0, 20.0, 10.0])
    with create_workcell("127.0.0.1", server.port) as cell:
        T = cell.robot.flange_pose()
        expected = elementary("z", 10) @ elementary("y", 20) @ elementary("x", 30)
        np.testing.assert_allclose(T[:3, :3], expected, atol=1e-12)
        np.testing.assert_allclose(T[:3, 3], [0.210, -0.035, 0.180], atol=1e-12)
        np.testing.assert_allclose(cell.robot.joint_positions(),
                                   np.radians([0.0, 20.0, 90.0, 0.0, 70.0, 0.0]), atol=1e-12)

        # A move sends mm, degrees in the same order, the current figure, comp 2 (linear).
        target = T.copy()
        target[:3, :3] = elementary("z", 15) @ elementary("y", 20) @ elementary("x", 30)
        target[:3, 3] += [0.01, 0.0, -0.02]
        cell.robot.move_to(target, speed=0.05)
        move = next(decode_packet(p) for p in reversed(server.packets)
                    if decode_packet(p).code == 72)
        _, comp, pose, option = move.args
        assert comp == 2
        assert pose == "@E P(220.0000, -35.0000, 160.0000, 30.00000, 20.00000, 15.00000, 5)"
        assert option == "SPEED=10.0, NEXT"  # 0.05 m/s of 1.0 m/s at ExtSpeed 50%
        np.testing.assert_allclose(cell.robot.flange_pose(), target, atol=1e-9)


def test_joint_move_sends_degrees_point_to_point(server):
    with create_workcell("127.0.0.1", server.port) as cell:
        q = cell.robot.joint_positions() + np.radians([5, -5, 5, 0, 0, 10])
        cell.robot.move_joints(q, speed=0.2)
        move = next(decode_packet(p) for p in reversed(server.packets)
                    if decode_packet(p).code == 72)
        assert move.args[1] == 1
        assert move.args[2] == "@E J(5.00000, 15.00000, 95.00000, 0.00000, 70.00000, 10.00000)"
        np.testing.assert_allclose(cell.robot.joint_positions(), q, atol=1e-9)


def test_motion_timeout_halts_and_raises(server):
    server.stall_motion = True
    with create_workcell("127.0.0.1", server.port) as cell:
        robot = cell.robot
        target = robot.flange_pose()
        target[2, 3] += 0.002  # 2 mm at 0.1 m/s: a 3 s limit at most
        halts = server.halts
        t0 = time.monotonic()
        with pytest.raises(MotionTimeoutError, match="robot was stopped"):
            robot.move_to(target, speed=0.1)
        assert time.monotonic() - t0 < 5.0
        assert server.halts > halts, "a timed-out move must send Robot_Halt"


def test_halt_freezes_a_move_in_progress(server):
    server.time_scale = 0.5  # 2 cm at 0.05 m/s takes 0.8 s of wall time here
    with create_workcell("127.0.0.1", server.port) as cell:
        robot = cell.robot
        start = robot.flange_pose()
        target = start.copy()
        target[0, 3] += 0.02
        robot.client.robot_move(robot.h_robot, 2, "@E P(220.0, 0.0, 200.0, 180.0, 0.0, 180.0, 5)",
                                "SPEED=5.0, NEXT")
        time.sleep(0.2)
        robot.stop()
        x = robot.flange_pose()[0, 3]
        assert start[0, 3] < x < target[0, 3]
        time.sleep(0.2)
        assert robot.flange_pose()[0, 3] == x, "the arm kept moving after Robot_Halt"


def test_dropped_connection_raises_and_close_is_quiet(server):
    cell = create_workcell("127.0.0.1", server.port)
    server.drop()
    with pytest.raises(RobotDisconnectedError):
        cell.robot.flange_pose()
    with pytest.raises(RobotDisconnectedError):
        cell.robot.move_to(np.eye(4), 0.05)
    with pytest.warns(RuntimeWarning, match="emergency stop"):
        cell.close()  # nothing left to release: warns that Halt cannot be sent, does not raise
    assert cell.robot.closed and not cell.robot.client.connected


def test_silent_controller_triggers_the_timeout(server):
    cell = create_workcell("127.0.0.1", server.port, timeout_s=0.3)
    server.mute = True
    t0 = time.monotonic()
    with pytest.raises(ConnectionTimeoutError, match="within 0.3 s"):
        cell.robot.flange_pose()
    assert time.monotonic() - t0 < 2.0
    assert not cell.robot.client.connected
    with pytest.warns(RuntimeWarning, match="emergency stop"):
        cell.close()
    assert cell.robot.closed


def test_speed_beyond_ext_speed_is_refused_before_moving(server):
    safety = Safety(max_speed=0.8)
    with create_workcell("127.0.0.1", server.port, safety=safety, ext_speed_pct=10) as cell:
        target = cell.robot.flange_pose()
        target[0, 3] += 0.01
        n = len(server.packets)
        with pytest.raises(ValueError, match="ExtSpeed"):
            cell.robot.move_to(target, speed=0.2)
        sent = [decode_packet(p).code for p in server.packets[n:]]
        assert 72 not in sent


def test_confirm_mode_option(server):
    asked = []
    with create_workcell("127.0.0.1", server.port, mode="confirm") as cell:
        cell.robot.safety.confirm = lambda message: asked.append(message) or False
        target = cell.robot.flange_pose()
        target[0, 3] += 0.01
        with pytest.raises(SafetyError, match="refused"):
            cell.robot.move_to(target, 0.05)
    assert len(asked) == 1 and "mm" in asked[0]
    assert 72 not in [decode_packet(p).code for p in server.packets]


def test_gripper_commands(server):
    with create_workcell("127.0.0.1", server.port) as cell:
        hand = cell.robot.tool
        assert hand.grasp() is True and hand.is_holding
        hand.release()
        assert not hand.is_holding and server.hand_width_mm == 30.0
        server.hand_object = False
        assert hand.grasp() is False and not hand.is_holding
    execs = [decode_packet(p).args[1:] for p in server.packets if decode_packet(p).code == 17]
    assert execs[:2] == [["HandMoveH", [10.0, True]], ["HandMoveA", [30.0, 50.0]]]


def test_bad_options_are_rejected_before_connecting():
    with pytest.raises(ValueError, match="host"):
        create_workcell(None)
    with pytest.raises(ValueError, match="tool"):
        create_workcell("127.0.0.1", tool="suction")
    with pytest.raises(ValueError, match="ext_speed_pct"):
        create_workcell("127.0.0.1", ext_speed_pct=0)


def test_reply_length_is_checked(server):
    # Sanity of the fake itself: every recorded request is a well-formed packet.
    for raw in server.packets:
        assert struct.unpack_from("<I", raw, 1)[0] == len(raw)


def test_a_camera_that_cannot_open_gives_the_arm_back(server):
    # connect("cobotta", camera="realsense", camera_options=...) like the other drivers; a
    # camera option that cannot be opened raises after the arm was taken and its motor
    # switched on: both are undone before the error reaches the caller.
    with pytest.raises(ValueError, match="camera must be None, 'realsense' or a robots.Camera"):
        create_workcell("127.0.0.1", server.port, camera="kinect")
    sent = commands(server)
    assert "GiveArm" in sent and sent.index("GiveArm") > sent.index("TakeArm"), sent
