"""The message format between the grader and a student-code worker.

The worker runs untrusted student code, so everything it sends back is treated as hostile:
messages are length-prefixed JSON (never pickle, whose loading can run arbitrary code in the
grader that holds the secret), arrays travel as raw little-endian bytes with a whitelisted
dtype, and every size is capped before anything is allocated. Only numpy and the standard
library are used here, so the worker can import this module without pulling in the grader.
"""

from __future__ import annotations

import base64
import json
import os
import select
import struct
import time

import numpy as np

MAX_MESSAGE_BYTES = 64 * 1024 * 1024
MAX_ARRAY_ELEMENTS = 2_000_000
MAX_DEPTH = 8
# Every integer crossing the wire fits in 64 bits: JSON has no limit of its own, and a
# 400-digit number turned into a float on the trusted side (a score, a time) would raise
# OverflowError there instead of costing the student the problem.
INT_MIN, INT_MAX = -(2**63), 2**63 - 1
_DTYPES = {"f8": np.float64, "i8": np.int64, "b1": np.bool_}
_HEADER = struct.Struct("<Q")


class WireError(Exception):
    """A message that is malformed, too large, or arrives too late."""


class WireTimeout(WireError):
    """No (whole) message arrived before the deadline."""


class WireClosed(WireError):
    """The other end closed the connection (it exited or was killed)."""


class WireTooLarge(WireError):
    """A message or an array over its cap, refused before it was read or allocated."""


def _bounded_int(value: int) -> int:
    if not INT_MIN <= value <= INT_MAX:
        raise WireError(f"an integer of {value.bit_length()} bits does not fit in 64 bits "
                        "(return a float or an array instead)")
    return value


def encode(obj, depth: int = 0):
    """A JSON-ready form of ``obj``: arrays, numbers, strings, lists, tuples, str-keyed dicts."""
    if depth > MAX_DEPTH:
        raise WireError(f"value nested deeper than {MAX_DEPTH} levels")
    if obj is None or isinstance(obj, (bool, str, np.bool_)):
        return obj.item() if isinstance(obj, np.generic) else obj
    if isinstance(obj, (int, np.integer)):
        return _bounded_int(int(obj))
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        arr = np.asarray(obj)
        if arr.dtype.kind == "b":
            code = "b1"
        elif arr.dtype.kind == "u" and arr.size and int(arr.max()) > INT_MAX:
            code = "f8"   # as int64 these would wrap round to negative numbers
        elif arr.dtype.kind in "iu":
            code = "i8"
        elif arr.dtype.kind == "f":
            code = "f8"
        else:
            raise WireError(f"cannot send an array of dtype {arr.dtype}")
        if arr.size > MAX_ARRAY_ELEMENTS:
            raise WireTooLarge(f"array of {arr.size} elements is larger than "
                               f"{MAX_ARRAY_ELEMENTS}")
        data = np.ascontiguousarray(arr, dtype=np.dtype(_DTYPES[code]).newbyteorder("<"))
        return {"__nd__": base64.b64encode(data.tobytes()).decode("ascii"), "dtype": code,
                "shape": list(arr.shape)}
    if isinstance(obj, tuple):
        return {"__tuple__": [encode(x, depth + 1) for x in obj]}
    if isinstance(obj, list):
        return [encode(x, depth + 1) for x in obj]
    if isinstance(obj, dict) and all(isinstance(k, str) and not k.startswith("__") for k in obj):
        return {k: encode(v, depth + 1) for k, v in obj.items()}
    raise WireError(f"cannot send an object of type {type(obj).__name__}")


def decode(obj, depth: int = 0):
    """Inverse of :func:`encode`, validating everything (the input may be forged)."""
    if depth > MAX_DEPTH:
        raise WireError(f"value nested deeper than {MAX_DEPTH} levels")
    if obj is None or isinstance(obj, (bool, float, str)):
        return obj
    if isinstance(obj, int):
        return _bounded_int(obj)
    if isinstance(obj, list):
        return [decode(x, depth + 1) for x in obj]
    if not isinstance(obj, dict):
        raise WireError(f"unexpected JSON value of type {type(obj).__name__}")
    if "__tuple__" in obj:
        items = obj["__tuple__"]
        if not isinstance(items, list):
            raise WireError("malformed tuple")
        return tuple(decode(x, depth + 1) for x in items)
    if "__nd__" in obj:
        code, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("__nd__")
        if code not in _DTYPES or not isinstance(data, str) or not isinstance(shape, list):
            raise WireError("malformed array")
        if len(shape) > 6 or not all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n
                                     for n in shape):
            raise WireError(f"bad array shape {shape!r}")
        size = int(np.prod(shape, dtype=np.int64)) if shape else 1
        if size > MAX_ARRAY_ELEMENTS:
            raise WireTooLarge(f"array of {size} elements is larger than {MAX_ARRAY_ELEMENTS}")
        raw = base64.b64decode(data.encode("ascii"), validate=True)
        dtype = np.dtype(_DTYPES[code]).newbyteorder("<")
        if len(raw) != size * dtype.itemsize:
            raise WireError("array data does not match its shape")
        return np.frombuffer(raw, dtype=dtype).astype(_DTYPES[code]).reshape(shape)
    return {str(k): decode(v, depth + 1) for k, v in obj.items()}


def send(fd: int, message: dict) -> None:
    """Write one message (a dict, encoded) to file descriptor ``fd``."""
    body = json.dumps(encode(message)).encode("utf-8")
    if len(body) > MAX_MESSAGE_BYTES:
        raise WireTooLarge(f"message of {len(body)} bytes exceeds {MAX_MESSAGE_BYTES}")
    view = memoryview(_HEADER.pack(len(body)) + body)
    while view:
        written = os.write(fd, view)
        view = view[written:]


def _read_exactly(fd: int, n: int, deadline: float | None) -> bytes:
    chunks, remaining = [], n
    while remaining:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise WireTimeout("timed out waiting for the worker")
        chunk = os.read(fd, min(remaining, 1 << 20))
        if not chunk:
            raise WireClosed("the worker closed the connection (it exited or was killed)")
        chunks.append(chunk)
        remaining -= len(chunk)
    return b"".join(chunks)


def receive(fd: int, deadline: float | None = None, max_bytes: int = MAX_MESSAGE_BYTES) -> dict:
    """Read one message from ``fd``; ``deadline`` is a ``time.monotonic()`` value or None.

    A message longer than ``max_bytes`` is refused from its length header, before any of it
    is read or allocated, so the cost of a reply is bounded by the caller's cap.
    """
    (length,) = _HEADER.unpack(_read_exactly(fd, _HEADER.size, deadline))
    limit = min(int(max_bytes), MAX_MESSAGE_BYTES)
    if length > limit:
        raise WireTooLarge(f"message of {length} bytes exceeds {limit}")
    try:
        message = decode(json.loads(_read_exactly(fd, length, deadline).decode("utf-8")))
    except (ValueError, RecursionError, UnicodeDecodeError) as exc:
        raise WireError(f"malformed message: {type(exc).__name__}") from None
    if not isinstance(message, dict):
        raise WireError("a message must be a JSON object")
    return message
