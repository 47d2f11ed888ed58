"""Connecting to a UR: a host that accepts TCP on port 30004 but never speaks RTDE.

The real ur_rtde constructors block (holding the interpreter lock) for minutes on such a
host, so the driver first sends RTDE's protocol-version request itself with a timeout. The
end-to-end tests run the real ur_rtde in a subprocess against a silent listener on loopback,
each bounded by a 20 s timeout so a regression fails instead of hanging the suite.
"""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fakes.rtde_listener import RTDEVersionServer, SilentListener
from fakes.ur_rtde_fake import FakeUR, make_sdk

from robots import RobotDisconnectedError
from robots.drivers import ur

REPO = Path(__file__).resolve().parent.parent


def test_probe_refuses_a_silent_host_in_time_and_names_it():
    with SilentListener() as silent:
        t0 = time.monotonic()
        with pytest.raises(RobotDisconnectedError, match=r"127\.0\.0\.1.*does not speak RTDE"):
            ur.probe_rtde("127.0.0.1", silent.port, timeout_s=0.5)
        assert time.monotonic() - t0 < 2.0
        time.sleep(0.05)
        # What it sent is RTDE_REQUEST_PROTOCOL_VERSION for version 2, byte for byte.
        assert b"".join(silent.received) == struct.pack(">HBH", 5, 86, 2)


def test_probe_accepts_a_host_that_answers_the_handshake():
    with RTDEVersionServer() as server:
        assert ur.probe_rtde("127.0.0.1", server.port, timeout_s=2.0) == 1


def test_probe_reports_nothing_listening():
    free = socket.socket()
    free.bind(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()
    with pytest.raises(RobotDisconnectedError, match=r"cannot reach the UR at 127\.0\.0\.1"):
        ur.probe_rtde("127.0.0.1", port, timeout_s=0.5)


def test_connect_probes_before_opening_any_interface(monkeypatch):
    arm = FakeUR()
    with SilentListener() as silent:
        monkeypatch.setattr(ur, "RTDE_PORT", silent.port)
        with pytest.raises(RobotDisconnectedError, match="does not speak RTDE"):
            ur.create_workcell("127.0.0.1", sdk=make_sdk(arm), probe=True, probe_timeout_s=0.5)
    assert not [e for e in arm.log if e[1:2] == ("connect",)]


SILENT_HOST = "127.0.0.77"  # a loopback address of its own, so port 30004 is free on it
RTDE_PORT = 30004  # fixed in ur_rtde


@pytest.fixture(scope="module")
def silent_ur_port():
    pytest.importorskip("rtde_receive", reason="the real ur_rtde is needed for this check")
    try:
        listener = SilentListener(SILENT_HOST, RTDE_PORT)
    except OSError as error:
        pytest.skip(f"cannot listen on {SILENT_HOST}:{RTDE_PORT} here ({error})")
    with listener:
        yield listener


def _run_bounded(code: str) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.monotonic()
    try:
        done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                              text=True, timeout=20)
    except subprocess.TimeoutExpired:
        pytest.fail("connecting to a host that never speaks RTDE hung for more than 20 s")
    return time.monotonic() - t0, done


def test_connect_with_the_real_ur_rtde_fails_within_15_s(silent_ur_port):
    elapsed, done = _run_bounded(f"from robots import connect; connect('ur', host='{SILENT_HOST}')")
    assert done.returncode != 0 and elapsed < 15.0
    assert SILENT_HOST in done.stderr and "does not speak RTDE" in done.stderr


def test_robot_check_cli_fails_within_15_s_naming_the_host(silent_ur_port):
    elapsed, done = _run_bounded(
        "import sys; from cobotlab.cli import main; "
        f"sys.exit(main(['robot', 'check', '--kind', 'ur', '--host', '{SILENT_HOST}']))")
    assert done.returncode != 0 and elapsed < 15.0
    message = done.stdout + done.stderr
    assert SILENT_HOST in message and "RTDE" in message
    assert "Traceback" not in message  # one clear line, not a stack trace
