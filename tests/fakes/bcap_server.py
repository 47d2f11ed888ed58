"""A b-CAP server on loopback that speaks the wire protocol and simulates a COBOTTA.

Used by tests/test_bcap.py and tests/test_driver_cobotta.py. Its packet codec is written
separately from ``robots.drivers.bcap`` (plain ``struct`` calls following the layout table in
that module's docstring), so a mistake in the client's encoder is not mirrored here.

What it simulates: the controller's handles and state (TakeArm, Motor, ExtSpeed, Tool0; like
the controller it refuses ``Robot_Change``, ``Motor`` and motion from a client that has not
taken the arm with TakeArm first, and GiveArm frees it), the
current position (mm, degrees, figure) and joints (degrees), moves that take time at the
commanded speed (``time_scale`` speeds the clock up for tests), ``MotionComplete``,
``Robot_Halt`` freezing the arm mid-move, and the electric hand. It does NOT model the
COBOTTA's kinematics: Cartesian moves change CurPos, joint moves change CurJnt; a real
controller couples the two. The backend contract checks each on its own.

Fault injection for tests: ``mute`` (read requests, never answer), ``drop()`` (close every
client socket), ``stall_motion`` (moves never finish), ``fail_next[command] = hresult``
(one failure reply), ``executing_notices`` (interim S_EXECUTING packets before each reply,
``executing_interval_s`` apart, so a call can outlast the client's timeout while the
controller keeps showing it is alive),
``hand_object`` (whether HandMoveH finds something to grip).
"""

from __future__ import annotations

import re
import socket
import struct
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

H_CTRL, H_ROBOT = 0x1111, 0x2222
S_OK, S_EXECUTING = 0, 0x900
E_FAIL = 0x80004005 - 2**32
E_HANDLE = 0x80070006 - 2**32
E_INVALIDARG = 0x80070057 - 2**32
E_MOTOR_OFF = 0x81501003 - 2**32
E_NOT_TAKEN = 0x83500130 - 2**32  # arm not taken (a stand-in code for "TakeArm first")
E_GRIP_NOT_DETECTED = 0x8350048F - 2**32

FULL_SPEED_MM_S = 1000.0  # what SPEED=100% at ExtSpeed=100% means in this fake
MAX_JOINT_SPEED_DEG_S = np.degrees(1.1093)

VT_EMPTY, VT_I4, VT_R8, VT_BSTR, VT_BOOL, VT_VARIANT, VT_ARRAY = 0, 3, 5, 8, 11, 12, 0x2000


# --------------------------------------------------------------------------- codec (independent)


def parse_variant(buf: bytes, i: int):
    vt, count = struct.unpack_from("<HI", buf, i)
    i += 6
    base = vt & ~VT_ARRAY
    if vt == VT_EMPTY:
        return None, i

    def one(i):
        if base == VT_I4:
            return struct.unpack_from("<i", buf, i)[0], i + 4
        if base == VT_R8:
            return struct.unpack_from("<d", buf, i)[0], i + 8
        if base == VT_BOOL:
            return struct.unpack_from("<h", buf, i)[0] != 0, i + 2
        if base == VT_BSTR:
            n = struct.unpack_from("<I", buf, i)[0]
            return buf[i + 4:i + 4 + n].decode("utf-16-le"), i + 4 + n
        if base == VT_VARIANT:
            return parse_variant(buf, i)
        raise ValueError(f"fake server: unsupported VARIANT type {vt}")

    if vt & VT_ARRAY:
        out = []
        for _ in range(count):
            v, i = one(i)
            out.append(v)
        return out, i
    assert count == 1, f"a scalar VARIANT must have count 1, got {count}"
    return one(i)


def parse_request(data: bytes):
    soh, length, serial, reserved, func, argc = struct.unpack_from("<BIHHIH", data, 0)
    assert soh == 1 and data[-1] == 4 and length == len(data), "malformed request framing"
    i, args = 15, []
    for _ in range(argc):
        n = struct.unpack_from("<I", data, i)[0]
        value, end = parse_variant(data, i + 4)
        assert end == i + 4 + n, "argument length prefix disagrees with its VARIANT"
        args.append(value)
        i = end
    assert i == len(data) - 1, "stray bytes before EOT"
    return serial, reserved, func, args


def variant_bytes(value) -> bytes:
    if value is None:
        return struct.pack("<HI", VT_EMPTY, 1)
    if isinstance(value, bool):
        return struct.pack("<HIh", VT_BOOL, 1, -1 if value else 0)
    if isinstance(value, int):
        return struct.pack("<HIi", VT_I4, 1, value)
    if isinstance(value, float):
        return struct.pack("<HId", VT_R8, 1, value)
    if isinstance(value, (list, tuple)):
        return struct.pack("<HI", VT_ARRAY | VT_R8, len(value)) + struct.pack(
            f"<{len(value)}d", *[float(v) for v in value])
    raise TypeError(value)


def reply_bytes(serial: int, hresult: int, values=()) -> bytes:
    body = b"".join(struct.pack("<I", len(v)) + v for v in map(variant_bytes, values))
    head = struct.pack("<BIHHiH", 1, 15 + len(body) + 1, serial, 0, hresult, len(values))
    return head + body + b"\x04"


# --------------------------------------------------------------------------- the arm


class _Motion:
    def __init__(self, kind, start, target, duration):
        self.kind, self.start, self.target = kind, np.array(start), np.array(target)
        self.t0, self.duration = time.monotonic(), max(duration, 1e-6)
        if kind == "P":
            rots = Rotation.from_euler("xyz", [start[3:6], target[3:6]], degrees=True)
            self.slerp = Slerp([0.0, 1.0], rots)

    def fraction(self) -> float:
        return min(1.0, (time.monotonic() - self.t0) / self.duration)

    def state(self, s: float) -> np.ndarray:
        if s >= 1.0:
            return self.target.copy()
        out = (1 - s) * self.start + s * self.target
        if self.kind == "P":
            out[3:6] = self.slerp(s).as_euler("xyz", degrees=True)
        return out


class FakeCobottaServer:
    """Start with ``server = FakeCobottaServer(); server.start()``; ``server.port`` is ephemeral."""

    def __init__(self, time_scale: float = 20.0):
        self.time_scale = time_scale
        self.lock = threading.RLock()
        self.packets: list[bytes] = []  # every request, raw
        self.calls: list[tuple] = []  # (func_id, args) of every request
        self.mute = False
        self.stall_motion = False
        self.fail_next: dict[str, int] = {}
        self.executing_notices = 0
        self.executing_interval_s = 0.0
        self.mute_after_notices = False  # True: send the interim notices, never the final reply
        self.service_options: list[str] = []
        self.hand_object = True
        self.position = np.array([200.0, 0.0, 200.0, 180.0, 0.0, 180.0])  # mm, deg
        self.fig = 5
        self.joints = np.array([0.0, 20.0, 90.0, 0.0, 70.0, 0.0, 0.0, 0.0])  # deg, 6 + 2 extra
        self.motion: _Motion | None = None
        self.arm_taken = self.motor_on = False
        self.ext_speed = 100.0
        self.tool = None
        self.hand_width_mm = 30.0
        self.halts = 0
        self._clients: list[socket.socket] = []
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(4)
        self.port = self._listener.getsockname()[1]
        self._running = False

    # ----- lifecycle

    def start(self) -> FakeCobottaServer:
        self._running = True
        threading.Thread(target=self._accept_loop, daemon=True).start()
        return self

    def stop(self) -> None:
        self._running = False
        self._listener.close()
        self.drop()

    def drop(self) -> None:
        """Close every client connection abruptly, like a pulled cable or a controller reboot."""
        with self.lock:
            clients, self._clients = self._clients, []
        for c in clients:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()

    def _accept_loop(self):
        while self._running:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            with self.lock:
                self._clients.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket):
        buf = b""
        try:
            while True:
                while len(buf) < 5 or len(buf) < struct.unpack_from("<I", buf, 1)[0]:
                    chunk = conn.recv(65536)
                    if not chunk:
                        return
                    buf += chunk
                n = struct.unpack_from("<I", buf, 1)[0]
                data, buf = buf[:n], buf[n:]
                serial, _reserved, func, args = parse_request(data)
                with self.lock:
                    self.packets.append(data)
                    self.calls.append((func, args))
                    if self.mute:
                        continue
                    hresult, values = self._handle(func, args)
                for _ in range(self.executing_notices):
                    conn.sendall(reply_bytes(serial, S_EXECUTING))
                    time.sleep(self.executing_interval_s)
                if not self.mute_after_notices:
                    conn.sendall(reply_bytes(serial, hresult, values))
        except OSError:
            return

    # ----- the controller

    def current(self) -> tuple[np.ndarray, np.ndarray]:
        """(CurPos[:6], CurJnt) right now, advancing any motion in progress."""
        with self.lock:
            m = self.motion
            if m is not None and not self.stall_motion:
                s = m.fraction()
                if m.kind == "P":
                    self.position = m.state(s)
                else:
                    self.joints[:6] = m.state(s)
                if s >= 1.0:
                    self.motion = None
            return self.position.copy(), self.joints.copy()

    def _handle(self, func: int, args: list):
        if func == 1:  # Service_Start(option)
            self.service_options.append(args[0] if args else None)
            return S_OK, []
        if func == 2:  # Service_Stop
            return S_OK, []
        if func == 3:  # Controller_Connect(name, provider, machine, option)
            if len(args) != 4 or args[1] != "CaoProv.DENSO.VRC":
                return E_INVALIDARG, []
            return S_OK, [H_CTRL]
        if func in (4, 7, 17) and args[0] != H_CTRL:
            return E_HANDLE, []
        if func in (64, 66, 70, 72, 84) and args[0] != H_ROBOT:
            return E_HANDLE, []
        if func == 4:
            return S_OK, []
        if func == 7:  # Controller_GetRobot(ctrl, name, option)
            return (S_OK, [H_ROBOT]) if args[1] == "Arm" else (E_INVALIDARG, [])
        if func == 84:  # Robot_Release
            return S_OK, []
        if func == 66:  # Robot_Change(robot, "Tool0"): only for the client holding the arm
            if not self.arm_taken:
                return E_NOT_TAKEN, []
            self.tool = args[1]
            return S_OK, []
        if func == 17:
            return self._controller_execute(args[1], args[2])
        if func == 64:
            return self._robot_execute(args[1], args[2])
        if func == 70:  # Robot_Halt
            self.current()
            self.motion = None
            self.halts += 1
            return S_OK, []
        if func == 72:
            return self._move(args[1], args[2], args[3])
        return E_FAIL, []

    def _failure(self, name):
        return self.fail_next.pop(name, None)

    def _controller_execute(self, command: str, param):
        failure = self._failure(command)
        if failure is not None:
            return failure, [None]
        if command == "HandMoveA":
            width, _speed = param
            if not 0 <= width <= 30:
                return E_INVALIDARG, [None]
            self.hand_width_mm = width
            return S_OK, [None]
        if command == "HandMoveH":
            _force, _close = param
            if not self.hand_object:
                self.hand_width_mm = 0.0
                return E_GRIP_NOT_DETECTED, [None]
            self.hand_width_mm = 12.0
            return S_OK, [None]
        return E_FAIL, [None]

    def _robot_execute(self, command: str, param):
        failure = self._failure(command)
        if failure is not None:
            return failure, [None]
        if command == "TakeArm":
            self.arm_taken = True
            return S_OK, [None]
        if command == "GiveArm":
            self.arm_taken = False
            return S_OK, [None]
        if command == "Motor":
            if not self.arm_taken:
                return E_NOT_TAKEN, [None]
            self.motor_on = bool(param[0])
            return S_OK, [None]
        if command == "ExtSpeed":
            self.ext_speed = float(param[0])
            return S_OK, [None]
        if command == "CurPos":
            pos, _ = self.current()
            return S_OK, [list(pos) + [float(self.fig)]]
        if command == "CurJnt":
            _, joints = self.current()
            return S_OK, [list(joints)]
        if command == "MotionComplete":
            self.current()
            return S_OK, [self.motion is None]
        return E_FAIL, [None]

    def _move(self, comp: int, pose: str, option: str):
        failure = self._failure("Move")
        if failure is not None:
            return failure, []
        if not (self.arm_taken and self.motor_on):
            return (E_NOT_TAKEN if not self.arm_taken else E_MOTOR_OFF), []
        speed = re.search(r"SPEED=([0-9.]+)", option)
        pct = float(speed.group(1)) if speed else 100.0
        scale = self.ext_speed / 100 * pct / 100 * self.time_scale
        if "NEXT" not in option:
            # The driver always moves with NEXT and polls; a blocking move is not simulated.
            return E_INVALIDARG, []
        p = re.fullmatch(r"@E P\(([^)]*)\)", pose)
        j = re.fullmatch(r"@E J\(([^)]*)\)", pose)
        self.current()
        if p and comp in (1, 2):
            values = [float(v) for v in p.group(1).split(",")]
            if len(values) != 7 or int(values[6]) != self.fig:
                return E_INVALIDARG, []
            target = np.array(values[:6])
            duration = np.linalg.norm(target[:3] - self.position[:3]) / (FULL_SPEED_MM_S * scale)
            self.motion = _Motion("P", self.position, target, duration)
        elif j and comp == 1:
            values = np.array([float(v) for v in j.group(1).split(",")])
            if len(values) != 6:
                return E_INVALIDARG, []
            duration = np.abs(values - self.joints[:6]).max() / (MAX_JOINT_SPEED_DEG_S * scale)
            self.motion = _Motion("J", self.joints[:6], values, duration)
        else:
            return E_INVALIDARG, []
        return S_OK, []
