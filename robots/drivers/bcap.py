"""A b-CAP client: DENSO's binary request/reply protocol over TCP (port 5007).

Written for this project from the published packet format; no vendor code is used.

Wire format (facts cross-checked in two public sources: DENSO WAVE's open-source b-CAP
client libraries, github.com/DENSORobot/orin_bcap (Java ``BCAPPacketConverter``, Python
``bcapclient.py``, C# ``bCAPDefine.cs``), and DENSO's older 2009 C library as shipped in
github.com/shadow-robot/sr-ros-interface ``denso_arm/src/b-Cap.cpp``). All integers are
little-endian::

    offset size  field
    0      1     SOH = 0x01
    1      4     total packet length in bytes, SOH and EOT included (uint32)
    5      2     serial number (uint16); the reply repeats it. Starts at 1, wraps 0xFFFF -> 1
    7      2     reserved / version (uint16), 0 in requests
    9      4     function ID in a request; HRESULT (int32, < 0 = failure) in a reply
    13     2     number of arguments (uint16)
    15     ...   arguments, each: length of what follows (uint32), then one VARIANT
    end    1     EOT = 0x04

A VARIANT is: type (uint16, COM VARTYPE: EMPTY 0, I2 2, I4 3, R4 4, R8 5, BSTR 8, BOOL 11,
VARIANT 12, UI1 17 ... with 0x2000 added for an array), element count (uint32; 1 for a
scalar, also for EMPTY), then the data. A BSTR is its byte length (uint32) followed by UTF-16LE
text; a BOOL is int16 (-1 true, 0 false); an array of VARIANTs holds its elements back to back
*without* the per-argument length prefix. A reply with HRESULT S_EXECUTING (0x00000900) is an
interim "still working" notice; the final reply with the same serial follows. The controller
sends these while a long call (a blocking move, a hand motion) is in progress.

Function IDs used here: Service_Start 1, Service_Stop 2, Controller_Connect 3,
Controller_Disconnect 4, Controller_GetRobot 7, Controller_Execute 17, Robot_Execute 64,
Robot_Change 66, Robot_Halt 70, Robot_Move 72, Robot_Release 84 (same numbers in both sources).

Timeouts: every call has a deadline, and each interim S_EXECUTING reply to that call restarts
it (the controller has shown it is alive and working on the request), so a long call is given
as long as it keeps reporting progress. A controller that does not answer in time raises
:class:`~robots.drivers._common.ConnectionTimeoutError` and the socket is closed, because a
late reply would otherwise be mistaken for the answer to the next request. A closed or reset
connection raises :class:`~robots.interfaces.RobotDisconnectedError`.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass

from robots.drivers._common import ConnectionTimeoutError
from robots.interfaces import RobotDisconnectedError

__all__ = [
    "DEFAULT_PORT",
    "FUNC",
    "S_EXECUTING",
    "S_OK",
    "VT",
    "BCAPClient",
    "BCAPError",
    "Packet",
    "decode_packet",
    "decode_variant",
    "encode_packet",
    "encode_variant",
]

DEFAULT_PORT = 5007
SOH, EOT = 0x01, 0x04
HEADER_SIZE = 15  # SOH .. argument count
MAX_PACKET_SIZE = 16 * 1024 * 1024  # a sanity bound: anything larger is a corrupted length

FUNC = {
    "Service_Start": 1,
    "Service_Stop": 2,
    "Controller_Connect": 3,
    "Controller_Disconnect": 4,
    "Controller_GetRobot": 7,
    "Controller_Execute": 17,
    "Robot_Execute": 64,
    "Robot_Change": 66,
    "Robot_Halt": 70,
    "Robot_Move": 72,
    "Robot_Release": 84,
}

S_OK = 0
S_EXECUTING = 0x00000900


class VT:
    """COM VARTYPE codes used on the wire."""

    EMPTY, NULL, I2, I4, R4, R8, BSTR, ERROR, BOOL, VARIANT = 0, 1, 2, 3, 4, 5, 8, 10, 11, 12
    UI1, UI2, UI4, I8, UI8 = 17, 18, 19, 20, 21
    ARRAY = 0x2000


# Fixed-size element formats (struct codes) for scalars and plain arrays.
_FIXED = {
    VT.I2: "h", VT.I4: "i", VT.R4: "f", VT.R8: "d", VT.ERROR: "i", VT.BOOL: "h",
    VT.UI1: "B", VT.UI2: "H", VT.UI4: "I", VT.I8: "q", VT.UI8: "Q",
}


class BCAPError(RuntimeError):
    """The controller answered a request with a failure HRESULT."""

    def __init__(self, hresult: int, function: str, detail: str = ""):
        self.hresult = hresult
        self.function = function
        code = f"0x{hresult & 0xFFFFFFFF:08X}"
        hint = (
            " Read the error on the teach pendant (or in the controller's error log) under "
            "this code; clear it there, then reconnect."
        )
        super().__init__(f"{function} failed with HRESULT {code}{detail}.{hint}")


@dataclass
class Packet:
    """A decoded packet. ``code`` is the function ID (request) or the HRESULT (reply)."""

    serial: int
    reserved: int
    code: int
    args: list


# --------------------------------------------------------------------------- VARIANT codec


def _bstr(text: str) -> bytes:
    data = text.encode("utf-16-le")
    return struct.pack("<I", len(data)) + data


def _vt_of_scalar(value) -> int:
    if isinstance(value, bool):
        return VT.BOOL
    if isinstance(value, int):
        if not -(2**31) <= value < 2**31:
            raise ValueError(f"integer {value} does not fit a b-CAP I4 (32-bit) argument")
        return VT.I4
    if isinstance(value, float):
        return VT.R8
    if isinstance(value, str):
        return VT.BSTR
    raise ValueError(
        f"cannot send {type(value).__name__} {value!r} over b-CAP; use None, bool, int, float, "
        "str, bytes or a list of those"
    )


def _scalar_data(vt: int, value) -> bytes:
    if vt == VT.BSTR:
        return _bstr(value)
    if vt == VT.BOOL:
        return struct.pack("<h", -1 if value else 0)
    return struct.pack("<" + _FIXED[vt], value)


def encode_variant(value) -> bytes:
    """One VARIANT (type, count, data) for a Python value.

    None -> EMPTY; bool -> BOOL; int -> I4; float -> R8; str -> BSTR; bytes -> UI1 array;
    a list/tuple of one scalar type -> an array of that type (ints mixed with floats become
    R8); any other list -> an array of VARIANTs. An empty list is sent as EMPTY.
    """
    if value is None:
        return struct.pack("<HI", VT.EMPTY, 1)
    if isinstance(value, (bytes, bytearray)):
        return struct.pack("<HI", VT.ARRAY | VT.UI1, len(value)) + bytes(value)
    if isinstance(value, (list, tuple)):
        if not value:
            return struct.pack("<HI", VT.EMPTY, 1)
        kinds = {_vt_of_scalar(v) if not isinstance(v, (list, tuple, bytes, bytearray))
                 and v is not None else VT.VARIANT for v in value}
        if kinds == {VT.I4, VT.R8}:
            kinds, value = {VT.R8}, [float(v) for v in value]
        if len(kinds) == 1 and VT.VARIANT not in kinds:
            vt = kinds.pop()
            body = b"".join(_scalar_data(vt, v) for v in value)
            return struct.pack("<HI", VT.ARRAY | vt, len(value)) + body
        body = b"".join(encode_variant(v) for v in value)
        return struct.pack("<HI", VT.ARRAY | VT.VARIANT, len(value)) + body
    vt = _vt_of_scalar(value)
    return struct.pack("<HI", vt, 1) + _scalar_data(vt, value)


def _read(buf: bytes, offset: int, size: int) -> bytes:
    if offset + size > len(buf):
        raise ValueError(
            f"b-CAP packet truncated: needed {size} bytes at offset {offset}, have {len(buf)}"
        )
    return buf[offset:offset + size]


def _decode_scalar(buf: bytes, offset: int, vt: int):
    if vt == VT.BSTR:
        (n,) = struct.unpack("<I", _read(buf, offset, 4))
        text = _read(buf, offset + 4, n).decode("utf-16-le")
        return text, offset + 4 + n
    if vt not in _FIXED:
        raise ValueError(f"unsupported b-CAP VARIANT type {vt} at offset {offset}")
    fmt = "<" + _FIXED[vt]
    size = struct.calcsize(fmt)
    (v,) = struct.unpack(fmt, _read(buf, offset, size))
    return (v != 0 if vt == VT.BOOL else v), offset + size


def decode_variant(buf: bytes, offset: int = 0):
    """Decode one VARIANT at ``offset``; return (value, offset after it). Arrays become lists."""
    vt, count = struct.unpack("<HI", _read(buf, offset, 6))
    offset += 6
    if vt & VT.ARRAY:
        base = vt & ~VT.ARRAY
        if base == VT.UI1:
            return bytes(_read(buf, offset, count)), offset + count
        out = []
        for _ in range(count):
            if base == VT.VARIANT:
                v, offset = decode_variant(buf, offset)
            else:
                v, offset = _decode_scalar(buf, offset, base)
            out.append(v)
        return out, offset
    if vt in (VT.EMPTY, VT.NULL):
        return None, offset
    return _decode_scalar(buf, offset, vt)


# --------------------------------------------------------------------------- packets


def encode_packet(serial: int, code: int, args=(), reserved: int = 0) -> bytes:
    """A complete packet: header, each argument as (length, VARIANT), EOT."""
    body = b""
    for arg in args:
        v = encode_variant(arg)
        body += struct.pack("<I", len(v)) + v
    length = HEADER_SIZE + len(body) + 1
    header = struct.pack("<BIHHiH", SOH, length, serial, reserved, code, len(args))
    return header + body + bytes([EOT])


def decode_packet(data: bytes) -> Packet:
    """Parse one complete packet; ValueError if it is malformed."""
    if len(data) < HEADER_SIZE + 1:
        raise ValueError(f"b-CAP packet too short ({len(data)} bytes)")
    soh, length, serial, reserved, code, argc = struct.unpack("<BIHHiH", data[:HEADER_SIZE])
    if soh != SOH or length != len(data) or data[-1] != EOT:
        raise ValueError(
            f"malformed b-CAP packet (SOH={soh:#x}, length field {length}, got {len(data)} "
            f"bytes, last byte {data[-1]:#x})"
        )
    offset, args = HEADER_SIZE, []
    for _ in range(argc):
        (n,) = struct.unpack("<I", _read(data, offset, 4))
        value, end = decode_variant(data, offset + 4)
        if end != offset + 4 + n:
            raise ValueError(f"b-CAP argument length {n} disagrees with its content")
        args.append(value)
        offset = end
    if offset != len(data) - 1:
        raise ValueError(f"{len(data) - 1 - offset} stray bytes before the b-CAP EOT")
    return Packet(serial, reserved, code, args)


# --------------------------------------------------------------------------- client


class BCAPClient:
    """One TCP connection to a b-CAP server, one request at a time.

    ``timeout_s`` bounds connecting and every reply (override per call with ``timeout_s=``).
    Thread-safe: a lock serialises requests, so a ``Robot_Halt`` from another thread waits for
    the current request to finish (requests used during motion are short: the driver moves with
    the ``NEXT`` option and polls).
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout_s: float = 3.0):
        if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        self.host, self.port, self.timeout_s = str(host), int(port), float(timeout_s)
        self._serial = 1
        self._lock = threading.Lock()
        self._buffer = b""
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except TimeoutError:
            raise ConnectionTimeoutError(
                f"no b-CAP answer from {self.host}:{self.port} within {self.timeout_s:.1f} s; "
                "check the address, the cable and that the controller is switched on"
            ) from None
        except OSError as error:
            raise RobotDisconnectedError(
                f"cannot connect to b-CAP at {self.host}:{self.port}: {error}. Check the "
                "address, that this computer is on the robot's subnet, and that b-CAP "
                "(port 5007) is enabled on the controller"
            ) from error
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def close(self) -> None:
        """Close the socket (idempotent). Does not send anything."""
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    # ----- the request/reply exchange

    def call(self, function: str, args=(), timeout_s: float | None = None) -> list:
        """Send ``function`` with ``args`` and return the reply's values (a list, often empty).

        Raises BCAPError for a failure HRESULT, ConnectionTimeoutError if no reply comes within
        ``timeout_s`` (default ``self.timeout_s``) of the request or of the last interim
        S_EXECUTING reply, RobotDisconnectedError if the link is closed or drops.
        """
        func_id = FUNC[function]
        limit = self.timeout_s if timeout_s is None else float(timeout_s)
        with self._lock:
            if self._sock is None:
                raise RobotDisconnectedError(
                    f"b-CAP connection to {self.host}:{self.port} is closed; reconnect "
                    "with robots.connect(...)"
                )
            serial = self._serial
            self._serial = 1 if serial >= 0xFFFF else serial + 1
            self._send(encode_packet(serial, func_id, args), function)
            deadline = time.monotonic() + limit
            while True:
                reply = self._receive(deadline, function, limit)
                if reply.serial != serial:
                    continue  # a stale reply to an earlier request; not ours
                if reply.code != S_EXECUTING:
                    break
                deadline = time.monotonic() + limit  # alive and still working: wait again
        if reply.code < 0:
            raise BCAPError(reply.code, function)
        return reply.args

    def _send(self, data: bytes, function: str) -> None:
        try:
            self._sock.sendall(data)
        except OSError as error:
            self.close()
            raise RobotDisconnectedError(
                f"b-CAP connection to {self.host}:{self.port} lost while sending {function}: "
                f"{error}"
            ) from error

    def _receive(self, deadline: float, function: str, limit: float) -> Packet:
        while True:
            if len(self._buffer) >= 5:
                if self._buffer[0] != SOH:
                    self.close()
                    raise RobotDisconnectedError(
                        f"b-CAP stream out of step (byte {self._buffer[0]:#x} where a packet "
                        "should start); the connection was closed, reconnect"
                    )
                (length,) = struct.unpack("<I", self._buffer[1:5])
                if not HEADER_SIZE + 1 <= length <= MAX_PACKET_SIZE:
                    self.close()
                    raise RobotDisconnectedError(f"b-CAP packet length {length} is impossible")
                if len(self._buffer) >= length:
                    data, self._buffer = self._buffer[:length], self._buffer[length:]
                    try:
                        return decode_packet(data)
                    except ValueError as error:
                        self.close()
                        raise RobotDisconnectedError(f"bad b-CAP reply to {function}: {error}")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._timed_out(function, limit)
            try:
                self._sock.settimeout(remaining)
                chunk = self._sock.recv(65536)
            except TimeoutError:
                self._timed_out(function, limit)
            except OSError as error:
                self.close()
                raise RobotDisconnectedError(
                    f"b-CAP connection to {self.host}:{self.port} lost during {function}: "
                    f"{error}. Check the cable and the controller"
                ) from error
            if not chunk:
                self.close()
                raise RobotDisconnectedError(
                    f"the controller at {self.host}:{self.port} closed the b-CAP connection "
                    f"during {function}; check the pendant for an error, then reconnect"
                )
            self._buffer += chunk

    def _timed_out(self, function: str, limit: float):
        self.close()
        raise ConnectionTimeoutError(
            f"no reply to {function} from {self.host}:{self.port} within {limit:.1f} s; the "
            "connection was closed. If the arm may still be moving, press the emergency stop; "
            "then check the cable and the controller and reconnect"
        )

    # ----- the functions the Cobotta driver uses (argument order as in the b-CAP spec)

    def service_start(self, option: str = "") -> None:
        """Start the b-CAP service. ``option``: e.g. ``"WDT=400"``, a watchdog in ms (see
        docs/robots/cobotta.md); "" for none."""
        self.call("Service_Start", [option])

    def service_stop(self) -> None:
        self.call("Service_Stop", [])

    def controller_connect(self, name: str, provider: str, machine: str, option: str) -> int:
        return self.call("Controller_Connect", [name, provider, machine, option])[0]

    def controller_disconnect(self, h_ctrl: int) -> None:
        self.call("Controller_Disconnect", [h_ctrl])

    def controller_get_robot(self, h_ctrl: int, name: str, option: str = "") -> int:
        return self.call("Controller_GetRobot", [h_ctrl, name, option])[0]

    def controller_execute(self, h_ctrl: int, command: str, param=None, timeout_s=None):
        out = self.call("Controller_Execute", [h_ctrl, command, param], timeout_s)
        return out[0] if out else None

    def robot_execute(self, h_robot: int, command: str, param=None, timeout_s=None):
        out = self.call("Robot_Execute", [h_robot, command, param], timeout_s)
        return out[0] if out else None

    def robot_change(self, h_robot: int, name: str) -> None:
        self.call("Robot_Change", [h_robot, name])

    def robot_move(self, h_robot: int, comp: int, pose, option: str = "") -> None:
        self.call("Robot_Move", [h_robot, comp, pose, option])

    def robot_halt(self, h_robot: int, option: str = "") -> None:
        self.call("Robot_Halt", [h_robot, option])

    def robot_release(self, h_robot: int) -> None:
        self.call("Robot_Release", [h_robot])

    def __repr__(self) -> str:
        state = "open" if self.connected else "closed"
        return f"BCAPClient({self.host}:{self.port}, {state})"
