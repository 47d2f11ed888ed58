"""Small helpers shared by the real-robot drivers: timeout errors, waiting, unit conversions.

Every driver converts to the project's conventions at its boundary (DESIGN.md): metres,
radians, (4, 4) float64 poses. Controllers that speak millimetres and degrees (Denso, Aubo's
pendant, ...) convert with the functions here so the factor 1000 lives in one place.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from robots.geometry import as_pose, pose_from_rpy, rpy_from_pose
from robots.interfaces import RobotDisconnectedError

__all__ = [
    "ROTATION_LEVER_M",
    "ConnectionTimeoutError",
    "MotionTimeoutError",
    "as_reading",
    "mm_rpy_deg_from_pose",
    "motion_time_limit_s",
    "pose_from_mm_rpy_deg",
    "wait_for",
]


class MotionTimeoutError(RuntimeError):
    """A move did not finish within its time limit; the driver has already stopped the robot."""


class ConnectionTimeoutError(RobotDisconnectedError):
    """The controller stopped answering within the time limit; the link is treated as lost."""


# A move is given (path length / speed) * factor + margin seconds. The factor covers the
# acceleration and deceleration phases (a trapezoidal profile needs up to 2x the cruise time
# on a short move); the margin covers command latency and settling.
TIME_LIMIT_FACTOR = 2.0
TIME_LIMIT_MARGIN_S = 3.0

# How rotation is weighed against translation when a move is planned or timed: a turn of
# 1 rad counts as 0.1 m, the path of a point on the tool 10 cm from the flange axis. So
# ``speed / ROTATION_LEVER_M`` (rad/s) is the turn rate that matches a linear speed (m/s).
ROTATION_LEVER_M = 0.1
MIN_PACE = 0.05  # see wait_for: the slowest speed scaling a time limit stretches for


def motion_time_limit_s(
    distance: float, speed: float, factor: float = TIME_LIMIT_FACTOR,
    margin_s: float = TIME_LIMIT_MARGIN_S,
) -> float:
    """Seconds a move of ``distance`` (m or rad) at ``speed`` (m/s or rad/s) may take at most."""
    if not (np.isfinite(distance) and distance >= 0 and np.isfinite(speed) and speed > 0):
        raise ValueError(
            f"motion_time_limit_s needs distance >= 0 and speed > 0, got {distance}, {speed}"
        )
    return float(distance) / float(speed) * factor + margin_s


def wait_for(
    done: Callable[[], bool],
    timeout_s: float,
    stop: Callable[[], None],
    what: str,
    poll_s: float = 0.01,
    pace: Callable[[], float] | None = None,
) -> None:
    """Poll ``done()`` until it returns True; after ``timeout_s`` call ``stop()`` and raise.

    Waiting in Python (rather than inside a blocking SDK call) is what lets Ctrl-C reach the
    driver mid-move: ``KeyboardInterrupt`` arrives between polls and ``Robot.move_to`` stops
    the arm. Raises :class:`MotionTimeoutError` naming ``what`` and the limit.

    ``pace``: the controller's current speed scaling (1.0 = full programmed speed; the
    pendant's speed slider). The limit then counts motion time, not wall time: a second at
    40% scaling uses 0.4 s of it, so slowing the arm on the pendant stretches the limit to
    match. Scaling is floored at ``MIN_PACE`` so a slider at 0% still times out, 20x later.
    """
    used, last = 0.0, time.monotonic()
    while not done():
        now = time.monotonic()
        rate = 1.0 if pace is None else min(max(float(pace()), MIN_PACE), 1.0)
        used, last = used + (now - last) * rate, now
        if used > timeout_s:
            stop()
            scaled = "" if pace is None else " of motion at the pendant's speed scaling"
            raise MotionTimeoutError(
                f"{what} did not finish within {timeout_s:.1f} s{scaled}; the robot was stopped. "
                "Check the teach pendant for a protective stop or an error, that nothing "
                "blocks the arm, and that the speed override on the pendant is not near 0%"
            )
        time.sleep(poll_s)


def as_reading(values, n: int, what: str) -> np.ndarray:
    """A controller reading as a float array of length ``n``, or RobotDisconnectedError.

    SDKs report a lost link in odd ways (an empty list, zeros, NaN); a reading of the wrong
    length or with NaN is treated as a lost connection rather than returned as data.
    """
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        arr = np.array([])
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise RobotDisconnectedError(
            f"the controller returned an invalid {what} ({values!r}, expected {n} finite "
            "numbers); the connection is probably lost. Check the cable and the controller, "
            "then reconnect"
        )
    return arr


def pose_from_mm_rpy_deg(xyz_mm: Sequence[float], rpy_deg: Sequence[float]) -> np.ndarray:
    """Pose (metres) from a position in mm and angles (rx, ry, rz) in degrees.

    The rotation is ``Rz(rz) @ Ry(ry) @ Rx(rx)``: rotations about the fixed base axes X, then
    Y, then Z (the same matrix as intrinsic Z-Y'-X''); see ``robots.geometry.pose_from_rpy``.
    """
    xyz = np.asarray(xyz_mm, dtype=float).reshape(3) / 1000.0
    rx, ry, rz = np.asarray(rpy_deg, dtype=float).reshape(3)
    return pose_from_rpy(rx, ry, rz, t=xyz, degrees=True)


def mm_rpy_deg_from_pose(T) -> tuple[np.ndarray, np.ndarray]:
    """(position in mm, (rx, ry, rz) in degrees) of a pose; inverse of ``pose_from_mm_rpy_deg``."""
    T = as_pose(T)
    return T[:3, 3] * 1000.0, rpy_from_pose(T, degrees=True)
