"""The b-CAP client against the documented wire layout, byte by byte, and its failure paths.

Expected packets are built here from the layout table (robots/drivers/bcap.py docstring,
from DENSO's published b-CAP format) with explicit struct calls, independently of the
client's encoder; the loopback server (tests/fakes/bcap_server.py) records what the client
really sent over TCP.
"""

from __future__ import annotations

import struct
import time

import pytest
from fakes.bcap_server import H_CTRL, H_ROBOT, FakeCobottaServer

from robots.drivers._common import ConnectionTimeoutError
from robots.drivers.bcap import (
    BCAPClient,
    BCAPError,
    decode_packet,
    decode_variant,
    encode_packet,
    encode_variant,
)
from robots.interfaces import RobotDisconnectedError

# --------------------------------------------------------------------------- the spec table

SPEC_FUNCTION_IDS = {
    "Service_Start": 1, "Service_Stop": 2, "Controller_Connect": 3, "Controller_Disconnect": 4,
    "Controller_GetRobot": 7, "Controller_Execute": 17, "Robot_Execute": 64, "Robot_Change": 66,
    "Robot_Halt": 70, "Robot_Move": 72, "Robot_Release": 84,
}


def spec_bstr(text: str) -> bytes:  # VT_BSTR = 8, count 1, byte length, UTF-16LE
    data = text.encode("utf-16-le")
    return struct.pack("<H", 8) + struct.pack("<I", 1) + struct.pack("<I", len(data)) + data


def spec_i4(value: int) -> bytes:  # VT_I4 = 3
    return struct.pack("<H", 3) + struct.pack("<I", 1) + struct.pack("<i", value)


def spec_empty() -> bytes:  # VT_EMPTY = 0, count 1, no data
    return struct.pack("<H", 0) + struct.pack("<I", 1)


def spec_i4_array(values) -> bytes:  # VT_ARRAY | VT_I4
    return struct.pack("<H", 0x2000 | 3) + struct.pack("<I", len(values)) + b"".join(
        struct.pack("<i", v) for v in values)


def spec_r8_array(values) -> bytes:  # VT_ARRAY | VT_R8
    return struct.pack("<H", 0x2000 | 5) + struct.pack("<I", len(values)) + b"".join(
        struct.pack("<d", v) for v in values)


def spec_bool(value: bool) -> bytes:  # VT_BOOL = 11, -1 true / 0 false as int16
    return struct.pack("<H", 11) + struct.pack("<I", 1) + struct.pack("<h", -1 if value else 0)


def spec_packet(serial: int, function: str, variants: list[bytes]) -> bytes:
    args = b"".join(struct.pack("<I", len(v)) + v for v in variants)
    length = 1 + 4 + 2 + 2 + 4 + 2 + len(args) + 1
    return (bytes([0x01]) + struct.pack("<I", length) + struct.pack("<H", serial)
            + struct.pack("<H", 0) + struct.pack("<I", SPEC_FUNCTION_IDS[function])
            + struct.pack("<H", len(variants)) + args + bytes([0x04]))


def assert_same_bytes(sent: bytes, expected: bytes, what: str) -> None:
    if sent != expected:
        i = next((k for k, (a, b) in enumerate(zip(sent, expected)) if a != b),
                 min(len(sent), len(expected)))
        raise AssertionError(
            f"{what}: first difference at byte {i} (sent {len(sent)} bytes, spec "
            f"{len(expected)})\n sent: {sent[max(0, i - 8):i + 8].hex(' ')}\n spec: "
            f"{expected[max(0, i - 8):i + 8].hex(' ')}"
        )


@pytest.fixture
def server():
    srv = FakeCobottaServer().start()
    yield srv
    srv.stop()


# --------------------------------------------------------------------------- pure codec


def test_service_start_matches_hand_written_bytes():
    # 01 | length 30 | serial 1 | reserved 0 | func 1 | 1 arg | arg length 10 | BSTR "" | 04
    expected = bytes.fromhex(
        "01 1e000000 0100 0000 01000000 0100 0a000000 0800 01000000 00000000 04".replace(" ", "")
    )
    assert encode_packet(1, 1, [""]) == expected
    assert spec_packet(1, "Service_Start", [spec_bstr("")]) == expected


@pytest.mark.parametrize(
    "value, spec",
    [
        (None, spec_empty()),
        (7, spec_i4(7)),
        (-2, spec_i4(-2)),
        (True, spec_bool(True)),
        (False, spec_bool(False)),
        ("Arm", spec_bstr("Arm")),
        ("", spec_bstr("")),
        ([0, 0], spec_i4_array([0, 0])),
        ([50.0, 25.0, 25.0], spec_r8_array([50.0, 25.0, 25.0])),
        ([10, 2.5], spec_r8_array([10.0, 2.5])),  # ints mixed with floats travel as R8
        (b"\x01\x02", struct.pack("<HI", 0x2000 | 17, 2) + b"\x01\x02"),
    ],
)
def test_variant_encoding_matches_the_spec(value, spec):
    assert encode_variant(value) == spec
    decoded, end = decode_variant(spec)
    assert end == len(spec)
    assert decoded == ([float(v) for v in value] if value == [10, 2.5] else value)


def test_variant_array_of_variants_has_no_inner_length_prefix():
    value = [1.5, "P", True]
    spec = (struct.pack("<HI", 0x2000 | 12, 3) + struct.pack("<HId", 5, 1, 1.5)
            + spec_bstr("P") + spec_bool(True))
    assert encode_variant(value) == spec
    assert decode_variant(spec) == (value, len(spec))


def test_packet_round_trip_and_malformed_packets():
    data = encode_packet(513, 64, [H_ROBOT, "CurPos", None])
    assert data == spec_packet(513, "Robot_Execute",
                               [spec_i4(H_ROBOT), spec_bstr("CurPos"), spec_empty()])
    packet = decode_packet(data)
    assert (packet.serial, packet.code, packet.args) == (513, 64, [H_ROBOT, "CurPos", None])
    for bad, why in [
        (b"\x02" + data[1:], "SOH"),
        (data[:-1] + b"\x05", "EOT"),
        (data[:-3] + data[-1:], "length"),
    ]:
        with pytest.raises(ValueError):
            decode_packet(bad)
    with pytest.raises(ValueError, match="cannot send"):
        encode_variant({"a": 1})


# --------------------------------------------------------------------------- over TCP


def test_connect_sequence_bytes_match_the_spec(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    client.service_start("")
    h_ctrl = client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
    h_robot = client.controller_get_robot(h_ctrl, "Arm", "")
    client.robot_execute(h_robot, "TakeArm", [0, 0])
    client.robot_change(h_robot, "Tool0")
    client.robot_execute(h_robot, "Motor", [1, 0])
    client.robot_execute(h_robot, "ExtSpeed", [50.0, 50.0, 50.0])
    client.robot_move(h_robot, 2, "@E P(200.0, 0.0, 150.0, 180.0, 0.0, 180.0, 5)",
                      "SPEED=5.0, NEXT")
    client.robot_halt(h_robot, "")
    client.controller_execute(h_ctrl, "HandMoveA", [30.0, 50.0])
    client.controller_execute(h_ctrl, "HandMoveH", [10.0, True])
    client.robot_release(h_robot)
    client.controller_disconnect(h_ctrl)
    client.service_stop()
    client.close()
    assert (h_ctrl, h_robot) == (H_CTRL, H_ROBOT)

    pose = "@E P(200.0, 0.0, 150.0, 180.0, 0.0, 180.0, 5)"
    expected = [
        ("Service_Start", [spec_bstr("")]),
        ("Controller_Connect", [spec_bstr(""), spec_bstr("CaoProv.DENSO.VRC"),
                                spec_bstr("localhost"), spec_bstr("")]),
        ("Controller_GetRobot", [spec_i4(H_CTRL), spec_bstr("Arm"), spec_bstr("")]),
        ("Robot_Execute", [spec_i4(H_ROBOT), spec_bstr("TakeArm"), spec_i4_array([0, 0])]),
        ("Robot_Change", [spec_i4(H_ROBOT), spec_bstr("Tool0")]),
        ("Robot_Execute", [spec_i4(H_ROBOT), spec_bstr("Motor"), spec_i4_array([1, 0])]),
        ("Robot_Execute", [spec_i4(H_ROBOT), spec_bstr("ExtSpeed"),
                           spec_r8_array([50.0, 50.0, 50.0])]),
        ("Robot_Move", [spec_i4(H_ROBOT), spec_i4(2), spec_bstr(pose),
                        spec_bstr("SPEED=5.0, NEXT")]),
        ("Robot_Halt", [spec_i4(H_ROBOT), spec_bstr("")]),
        ("Controller_Execute", [spec_i4(H_CTRL), spec_bstr("HandMoveA"),
                                spec_r8_array([30.0, 50.0])]),
        ("Controller_Execute", [spec_i4(H_CTRL), spec_bstr("HandMoveH"),
                                struct.pack("<HI", 0x2000 | 12, 2) + struct.pack("<HId", 5, 1, 10.0)
                                + spec_bool(True)]),
        ("Robot_Release", [spec_i4(H_ROBOT)]),
        ("Controller_Disconnect", [spec_i4(H_CTRL)]),
        ("Service_Stop", []),
    ]
    assert len(server.packets) == len(expected)
    for k, ((function, variants), sent) in enumerate(zip(expected, server.packets)):
        assert_same_bytes(sent, spec_packet(k + 1, function, variants), f"packet {k + 1} {function}")


def test_replies_decode_values_and_serials_wrap(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    h_ctrl = client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
    h_robot = client.controller_get_robot(h_ctrl, "Arm", "")
    assert client.robot_execute(h_robot, "CurPos") == [200.0, 0.0, 200.0, 180.0, 0.0, 180.0, 5.0]
    client._serial = 0xFFFF
    client.robot_execute(h_robot, "CurJnt")
    client.robot_execute(h_robot, "CurJnt")
    serials = [struct.unpack_from("<H", p, 5)[0] for p in server.packets[-2:]]
    assert serials == [0xFFFF, 1]
    client.close()


def test_interim_executing_replies_are_skipped(server):
    server.executing_notices = 3
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    assert client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "") == H_CTRL
    client.close()


def test_interim_executing_replies_extend_the_deadline(server):
    # A long call answered by S_EXECUTING every 0.2 s for 0.8 s, with a 0.3 s reply limit: the
    # controller is alive and working, so the call must wait for the final reply.
    server.executing_notices, server.executing_interval_s = 4, 0.2
    client = BCAPClient("127.0.0.1", server.port, timeout_s=0.3)
    t0 = time.monotonic()
    assert client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "") == H_CTRL
    assert time.monotonic() - t0 >= 0.75
    assert client.connected
    client.close()


def test_interim_replies_that_stop_still_time_out(server):
    # Interim replies, then silence: the deadline restarts at the last one and then expires.
    server.executing_notices, server.executing_interval_s = 2, 0.1
    client = BCAPClient("127.0.0.1", server.port, timeout_s=0.3)
    server.mute_after_notices = True
    t0 = time.monotonic()
    with pytest.raises(ConnectionTimeoutError, match="within 0.3 s"):
        client.service_start("")
    assert 0.4 < time.monotonic() - t0 < 2.0
    assert not client.connected


def test_robot_change_before_take_arm_is_refused_like_the_controller(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    h_ctrl = client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
    h_robot = client.controller_get_robot(h_ctrl, "Arm", "")
    with pytest.raises(BCAPError, match="0x83500130"):
        client.robot_change(h_robot, "Tool0")
    client.robot_execute(h_robot, "TakeArm", [0, 0])
    client.robot_change(h_robot, "Tool0")
    assert server.tool == "Tool0"
    client.close()


def test_failure_hresult_raises_with_the_code(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    with pytest.raises(BCAPError, match="0x80070057") as info:
        client.controller_connect("", "NoSuchProvider", "localhost", "")
    assert info.value.hresult == 0x80070057 - 2**32
    assert client.connected  # a refused request leaves the link usable
    assert client.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "") == H_CTRL
    client.close()


def test_dropped_connection_raises_disconnected(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=1.0)
    client.service_start("")
    server.drop()
    with pytest.raises(RobotDisconnectedError, match="closed|lost"):
        client.service_start("")
    assert not client.connected
    with pytest.raises(RobotDisconnectedError, match="closed"):
        client.service_start("")


def test_silent_controller_times_out_and_closes_the_link(server):
    client = BCAPClient("127.0.0.1", server.port, timeout_s=0.3)
    server.mute = True
    t0 = time.monotonic()
    with pytest.raises(ConnectionTimeoutError, match="within 0.3 s"):
        client.service_start("")
    assert 0.25 < time.monotonic() - t0 < 2.0
    assert not client.connected


def test_nothing_listening_raises_disconnected():
    srv = FakeCobottaServer()  # bound but never started: close it to free the port
    port = srv.port
    srv.stop()
    with pytest.raises(RobotDisconnectedError, match="cannot connect"):
        BCAPClient("127.0.0.1", port, timeout_s=0.5)
