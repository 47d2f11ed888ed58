"""The UR driver through a fake of ur_rtde's API: contract, conventions, failures, real names."""

from __future__ import annotations

import inspect
import re
import time

import numpy as np
import pytest
from contract import CONTRACT_CHECKS
from fakes import ur_rtde_fake
from fakes.ur_rtde_fake import FakeUR, make_sdk

from robots import RobotDisconnectedError, SafetyError
from robots.drivers._common import MotionTimeoutError
from robots.drivers.ur import MAX_JOINT_SPEED, MAX_TCP_SPEED, URSuctionCup, create_workcell
from robots.geometry import make_pose, pose_from_rotvec


@pytest.fixture
def arm():
    return FakeUR(time_scale=20.0)


def cell_for(arm, **options):
    return create_workcell("127.0.0.21", sdk=make_sdk(arm), **options)


@pytest.mark.parametrize("check", CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_ur_contract(arm, check):
    check(lambda: cell_for(arm))


def test_tcp_is_zeroed_so_the_pose_is_the_flange(arm):
    flange = ur_rtde_fake.fk(arm.q)
    with cell_for(arm) as cell:
        assert arm.tcp_offset == [0.0] * 6
        np.testing.assert_allclose(cell.robot.flange_pose(), flange, atol=1e-12)
        np.testing.assert_allclose(cell.robot.joint_positions(), ur_rtde_fake.HOME_Q)


def test_move_sends_metres_rotvec_and_capped_speeds(arm):
    with cell_for(arm) as cell:
        start = cell.robot.flange_pose()
        target = start @ pose_from_rotvec([0.0, 0.0, 0.2], [0.02, 0.0, -0.01])
        cell.robot.move_to(target, speed=0.05)
        _, pose, speed, accel, asynchronous = next(e for e in arm.log if e[0] == "moveL")
        np.testing.assert_allclose(pose_from_rotvec(pose[3:], pose[:3]), target, atol=1e-12)
        assert (speed, asynchronous) == (0.05, True) and accel < 1.2
        q = cell.robot.joint_positions() + 0.05
        cell.robot.move_joints(q, speed=0.3)
        _, sent_q, speed, accel, asynchronous = next(e for e in arm.log if e[0] == "moveJ")
        np.testing.assert_allclose(sent_q, q)
        assert (speed, asynchronous) == (0.3, True) and accel < 1.4


def test_driver_caps_apply_even_if_safety_is_loosened(arm):
    assert MAX_TCP_SPEED < 0.25 and MAX_JOINT_SPEED < 1.05  # below ur_rtde's defaults
    with cell_for(arm) as cell:
        cell.robot.safety.max_speed, cell.robot.safety.max_joint_speed = 1.0, 3.0
        target = cell.robot.flange_pose()
        target[2, 3] += 0.01
        with pytest.raises(SafetyError, match="driver's cap"):
            cell.robot.move_to(target, speed=0.3)
        with pytest.raises(SafetyError, match="driver's cap"):
            cell.robot.move_joints(cell.robot.joint_positions() + 0.01, speed=1.0)
    assert not [e for e in arm.log if e[0] in ("moveL", "moveJ")]


def test_motion_timeout_stops_and_raises(arm):
    arm.stall_motion = True
    with cell_for(arm) as cell:
        target = cell.robot.flange_pose()
        target[2, 3] += 0.002
        t0 = time.monotonic()
        with pytest.raises(MotionTimeoutError, match="stopped"):
            cell.robot.move_to(target, speed=0.1)
        assert time.monotonic() - t0 < 5.0
        assert any(e[0] == "stopL" for e in arm.log)


def test_protective_stop_is_reported(arm):
    with cell_for(arm) as cell:
        target = cell.robot.flange_pose()
        target[0, 3] += 0.02
        arm.time_scale = 0.5
        arm.protective_stop = True
        with pytest.raises(RuntimeError, match="protective stop"):
            cell.robot.move_to(target, speed=0.05)


def test_safeguard_stop_mid_move_is_raised_within_a_second(arm):
    # A light curtain is crossed 40 % into a 0.4 s move: the controller pauses the arm in a
    # safeguard stop (safety mode 5, status bit 4), which is not a protective stop.
    with cell_for(arm) as cell:
        target = cell.robot.flange_pose()
        target[0, 3] += 0.02
        arm.time_scale = 1.0
        arm.safeguard_at_fraction = 0.4
        t0 = time.monotonic()
        with pytest.raises(RuntimeError, match="safeguard stop.*light curtain") as stopped:
            cell.robot.move_to(target, speed=0.05)
        assert time.monotonic() - t0 < 1.0
        from robots.drivers.ur import URSafeguardStopError

        assert isinstance(stopped.value, URSafeguardStopError)
        assert stopped.value.safety_mode == 5 and stopped.value.status_bits >> 4 & 1
        assert any(e[0] == "stopL" for e in arm.log)


def test_time_limit_follows_the_pendant_speed_slider(arm):
    # The slider at 10 %: a 0.4 s move takes 4 s, longer than its 3.8 s limit at full speed.
    # The limit counts motion time at the controller's speed scaling, so the move completes.
    with cell_for(arm) as cell:
        target = cell.robot.flange_pose()
        target[1, 3] += 0.04
        arm.time_scale, arm.speed_scaling = 1.0, 0.1
        cell.robot.move_to(target, speed=0.1)
        np.testing.assert_allclose(cell.robot.flange_pose()[:3, 3], target[:3, 3], atol=2e-4)


def test_dropped_connection_raises(arm):
    with cell_for(arm) as cell:
        arm.drop()
        with pytest.raises(RobotDisconnectedError, match="lost"):
            cell.robot.flange_pose()
        with pytest.raises(RobotDisconnectedError):
            cell.robot.move_joints(np.zeros(6), 0.1)
    assert cell.robot.closed


def test_failed_connect_disconnects_what_opened(arm):
    with pytest.raises(RobotDisconnectedError, match="RTDEIOInterface"):
        create_workcell("127.0.0.21", sdk=make_sdk(arm, refuse="RTDEIOInterface"))
    closed = [e[0] for e in arm.log if e[1:] == ("disconnect",)]
    assert sorted(closed) == ["RTDEControlInterface", "RTDEReceiveInterface"]


def test_suction_through_a_digital_output(arm):
    offset = make_pose(t=[0, 0, 0.12])
    with cell_for(arm, tool="suction", pin=3, flange_T_tcp=offset) as cell:
        cup = cell.robot.tool
        assert isinstance(cup, URSuctionCup)
        cup.settle_s = 0.0
        assert cup.grasp() and arm.digital_out[3] is True and cup.is_holding
        cup.release()
        assert arm.digital_out[3] is False and not cup.is_holding
        np.testing.assert_allclose(cell.robot.tcp_pose(), cell.robot.flange_pose() @ offset)
    with pytest.raises(ValueError, match="pin"):
        cell_for(FakeUR(), tool="gripper", pin=9)


def test_missing_sdk_names_the_install_command(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_rtde(name, *args, **kwargs):
        if name.startswith("rtde_"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rtde)
    from robots import BackendNotAvailableError

    with pytest.raises(BackendNotAvailableError, match="ur-rtde"):
        create_workcell("127.0.0.21")


# --------------------------------------------------------------------------- the real SDK

# Every ur_rtde call robots/drivers/ur.py makes: (module, class, method).
USED = [
    ("rtde_control", "RTDEControlInterface", m)
    for m in ("moveL", "moveJ", "stopL", "stopJ", "setTcp", "getTCPOffset", "isConnected",
              "isSteady", "disconnect")
] + [
    ("rtde_receive", "RTDEReceiveInterface", m)
    for m in ("getActualTCPPose", "getActualQ", "isProtectiveStopped", "isEmergencyStopped",
              "getSafetyStatusBits", "getSafetyMode", "getSpeedScaling", "isConnected",
              "disconnect")
] + [
    ("rtde_io", "RTDEIOInterface", m)
    for m in ("setStandardDigitalOut", "setToolDigitalOut", "disconnect")
]


def _real_overloads(method) -> list[list[tuple[str, str | None]]]:
    """Parameter (name, default) lists of each pybind11 overload, from the docstring."""
    out = []
    for line in (method.__doc__ or "").splitlines():
        m = re.match(rf"\s*(?:\d+\.\s*)?{method.__name__}\(self: [\w.]+(.*)\) -> ", line)
        if m:
            params = [p.strip() for p in re.split(r",\s*(?![^\[]*\])", m.group(1)) if p.strip()]
            out.append([(p.split(":")[0].strip(), p.split("=")[1].strip() if "=" in p else None)
                        for p in params])
    return out


@pytest.mark.parametrize("module, cls, method", USED, ids=lambda x: str(x))
def test_installed_ur_rtde_has_the_names_the_fake_mimics(module, cls, method):
    real_module = pytest.importorskip(
        module, reason=f"ur_rtde ({module}) cannot be imported here; install ur-rtde>=1.5,<2")
    real = getattr(getattr(real_module, cls), method, None)
    assert real is not None, f"installed {module}.{cls} has no {method}"
    fake = getattr(getattr(ur_rtde_fake, cls), method)
    fake_params = [(p.name, None if p.default is p.empty else repr(p.default))
                   for p in list(inspect.signature(fake).parameters.values())[1:]]
    overloads = _real_overloads(real)
    assert overloads, f"could not read the signature of {module}.{cls}.{method}"

    def same_default(real_default, fake_default):
        if real_default is None:  # no default in the real SDK: the fake may not rely on one
            return True
        if fake_default is None:
            return False
        try:
            return float(real_default) == float(fake_default)
        except ValueError:
            return real_default == fake_default  # True/False

    def matches(real_params):
        return len(real_params) == len(fake_params) and all(
            (re.fullmatch(r"arg\d+", rn) or rn == fn) and same_default(rd, fd)  # pybind: argN
            for (rn, rd), (fn, fd) in zip(real_params, fake_params)
        )

    assert any(matches(o) for o in overloads), (
        f"{cls}.{method}: fake parameters {fake_params} match no installed overload {overloads}"
    )


def test_installed_constructors_take_the_hostname_first():
    for module, cls in (("rtde_control", "RTDEControlInterface"),
                        ("rtde_receive", "RTDEReceiveInterface"), ("rtde_io", "RTDEIOInterface")):
        real_module = pytest.importorskip(module, reason="ur_rtde cannot be imported here")
        doc = getattr(real_module, cls).__init__.__doc__
        assert re.search(r"__init__\(self: [\w.]+, hostname: str", doc), doc


def test_a_camera_that_cannot_open_leaves_no_rtde_connection(arm):
    # connect("ur", camera="realsense", camera_options=...) as docs/robots/realsense.md shows;
    # a camera option that cannot be opened raises, and the arm is released, not left connected.
    with pytest.raises(ValueError, match="camera must be None, 'realsense' or a robots.Camera"):
        cell_for(arm, tool="none", camera="kinect")
    closed = sorted(e[0] for e in arm.log if e[1:] == ("disconnect",))
    assert closed == ["RTDEControlInterface", "RTDEIOInterface", "RTDEReceiveInterface"]
    with pytest.raises(ValueError, match="camera_options given but camera is not 'realsense'"):
        cell_for(arm, tool="none", camera_options={"serial": "0123"})
