"""A stand-in for ur_rtde exposing exactly the API surface robots/drivers/ur.py uses.

Class names, method names, parameter names, argument order, defaults and units follow
ur_rtde 1.6 (metres, radians, rotation vectors; ``asynchronous`` flags); tests/test_driver_ur.py
compares these signatures with the installed ur_rtde. Behind them, :class:`FakeUR` simulates a
UR5e: standard-DH forward kinematics, numerical IK for linear moves, moves that take time at
the commanded speed (``time_scale`` speeds the clock up), stopL/stopJ freezing the arm, a TCP
offset (non-zero at start, like a pendant configured for a gripper), digital outputs, and
faults (``drop()``, ``protective_stop``, ``stall_motion``).

Safety as the controller reports it: ``safety_mode`` (getSafetyMode: 1 normal, 3 protective
stop, 5 safeguard stop, 7 robot emergency stop, ...) and the matching ``safety_status_bits``
(bit 2 protective stopped, bit 4 safeguard stopped, bit 7 emergency stopped, ...). A stop
freezes the arm where it is and the motion stays pending, as on the real arm (a safeguard
stop pauses; the move does not finish by itself). ``safeguard_at_fraction`` makes the arm
enter a safeguard stop part-way through the next move, like a light curtain being crossed.
``speed_scaling`` (getSpeedScaling, the pendant's slider) slows every move down.
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, Slerp

# UR5e standard DH parameters (Universal Robots' published values).
DH_D = [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
DH_A = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]
DH_ALPHA = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]
HOME_Q = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]


def fk(q) -> np.ndarray:
    T = np.eye(4)
    for theta, d, a, alpha in zip(q, DH_D, DH_A, DH_ALPHA):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                          [0, sa, ca, d], [0, 0, 0, 1]])
    return T


def ik(T, seed) -> np.ndarray:
    def residual(q):
        E = fk(q)
        return np.concatenate([E[:3, 3] - T[:3, 3],
                               Rotation.from_matrix(T[:3, :3].T @ E[:3, :3]).as_rotvec()])

    sol = least_squares(residual, seed, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert np.abs(residual(sol.x)).max() < 1e-9, "fake UR: IK did not converge"
    return sol.x


def pose_vector(T) -> list[float]:
    return [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_rotvec()]


def pose_matrix(v) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(v[3:6]).as_matrix()
    T[:3, 3] = v[:3]
    return T


class FakeUR:
    """The simulated robot shared by the three interfaces."""

    def __init__(self, time_scale: float = 20.0):
        self.time_scale = time_scale
        self.lock = threading.RLock()
        self.q = np.array(HOME_Q)
        self.tcp_offset = [0.0, 0.0, 0.15, 0.0, 0.0, 0.0]  # as if the pendant set a gripper TCP
        self.connected = True
        self.safety_mode = 1  # NORMAL
        self.safeguard_at_fraction = None  # e.g. 0.4: safeguard stop 40 % into the next move
        self.speed_scaling = 1.0
        self.stall_motion = False
        self.digital_out = {}
        self.tool_digital_out = {}
        self.motion = None  # (kind, start_q or start_T, target, t0, duration)
        self.log: list[tuple] = []

    # protective_stop as a flag, kept for the tests written against it
    @property
    def protective_stop(self) -> bool:
        return self.safety_mode == 3

    @protective_stop.setter
    def protective_stop(self, on: bool) -> None:
        self.safety_mode = 3 if on else 1

    def safety_status_bits(self) -> int:
        bits = {1: 1 << 0, 2: 1 << 1, 3: 1 << 2 | 1 << 10, 4: 1 << 3, 5: 1 << 4 | 1 << 10,
                6: 1 << 5 | 1 << 7 | 1 << 10, 7: 1 << 6 | 1 << 7 | 1 << 10, 8: 1 << 8 | 1 << 10,
                9: 1 << 9 | 1 << 10}
        return bits.get(self.safety_mode, 1 << 10)

    def drop(self):
        self.connected = False

    def _advance(self):
        if self.motion is None or self.stall_motion or self.safety_mode != 1:
            return
        kind, start, target, t0, duration = self.motion
        s = min(1.0, (time.monotonic() - t0) / duration)
        if self.safeguard_at_fraction is not None and s >= self.safeguard_at_fraction:
            s, self.safety_mode, self.safeguard_at_fraction = self.safeguard_at_fraction, 5, None
        if kind == "J":
            self.q = (1 - s) * start + s * target
        else:
            slerp = Slerp([0, 1], Rotation.from_matrix([start[:3, :3], target[:3, :3]]))
            T = np.eye(4)
            T[:3, :3] = slerp(s).as_matrix()
            T[:3, 3] = (1 - s) * start[:3, 3] + s * target[:3, 3]
            self.q = ik(T, self.q)
        if s >= 1.0:
            self.motion = None

    def state(self):
        with self.lock:
            self._advance()
            return self.q.copy()

    def require(self):
        if not self.connected:
            raise RuntimeError("fake UR: not connected")


class _Interface:
    def __init__(self, robot: FakeUR):
        self._robot = robot
        self._open = True

    def isConnected(self) -> bool:
        return self._open and self._robot.connected

    def disconnect(self) -> None:
        self._robot.log.append((type(self).__name__, "disconnect"))
        self._open = False


class RTDEControlInterface(_Interface):
    def moveL(self, pose, speed=0.25, acceleration=1.2, asynchronous=False) -> bool:
        r = self._robot
        r.require()
        r.log.append(("moveL", list(pose), speed, acceleration, asynchronous))
        with r.lock:
            r._advance()
            target = np.asarray(pose_matrix(pose)) @ np.linalg.inv(pose_matrix(r.tcp_offset))
            duration = (np.linalg.norm(target[:3, 3] - fk(r.q)[:3, 3]) / speed / r.time_scale
                        / r.speed_scaling)
            r.motion = ("L", fk(r.q), target, time.monotonic(), max(duration, 1e-3))
        if not asynchronous:
            while r.motion is not None and not r.stall_motion:
                r.state()
        return True

    def moveJ(self, q, speed=1.05, acceleration=1.4, asynchronous=False) -> bool:
        r = self._robot
        r.require()
        r.log.append(("moveJ", list(q), speed, acceleration, asynchronous))
        with r.lock:
            r._advance()
            target = np.asarray(q, dtype=float)
            duration = np.abs(target - r.q).max() / speed / r.time_scale / r.speed_scaling
            r.motion = ("J", r.q.copy(), target, time.monotonic(), max(duration, 1e-3))
        if not asynchronous:
            while r.motion is not None and not r.stall_motion:
                r.state()
        return True

    def stopL(self, a=10.0, asynchronous=False) -> None:
        self._stop("stopL", a)

    def stopJ(self, a=2.0, asynchronous=False) -> None:
        self._stop("stopJ", a)

    def _stop(self, name, a):
        r = self._robot
        r.require()
        r.log.append((name, a))
        with r.lock:
            r._advance()
            r.motion = None

    def setTcp(self, tcp_offset) -> bool:
        self._robot.require()
        self._robot.tcp_offset = list(tcp_offset)
        return True

    def getTCPOffset(self) -> list:
        return list(self._robot.tcp_offset)

    def isSteady(self) -> bool:
        r = self._robot
        r.state()
        return r.motion is None


class RTDEReceiveInterface(_Interface):
    def getActualTCPPose(self) -> list:
        r = self._robot
        if not r.connected:
            return []  # what ur_rtde returns with no data
        return pose_vector(fk(r.state()) @ pose_matrix(r.tcp_offset))

    def getActualQ(self) -> list:
        r = self._robot
        return list(r.state()) if r.connected else []

    def isProtectiveStopped(self) -> bool:
        return bool(self._robot.safety_status_bits() >> 2 & 1)

    def isEmergencyStopped(self) -> bool:
        return bool(self._robot.safety_status_bits() >> 7 & 1)

    def getSafetyStatusBits(self) -> int:
        return self._robot.safety_status_bits()

    def getSafetyMode(self) -> int:
        return self._robot.safety_mode

    def getSpeedScaling(self) -> float:
        return self._robot.speed_scaling


class RTDEIOInterface(_Interface):
    def setStandardDigitalOut(self, output_id, signal_level) -> bool:
        self._robot.require()
        self._robot.digital_out[output_id] = bool(signal_level)
        return True

    def setToolDigitalOut(self, output_id, signal_level) -> bool:
        self._robot.require()
        self._robot.tool_digital_out[output_id] = bool(signal_level)
        return True


def make_sdk(robot: FakeUR, refuse: str | None = None) -> SimpleNamespace:
    """An ``sdk`` for ``robots.drivers.ur.create_workcell`` whose classes all drive ``robot``.

    ``refuse``: the name of a class whose constructor fails, as ur_rtde's do (RuntimeError).
    """

    def factory(cls):
        def make(hostname, *args, **kwargs):
            if cls.__name__ == refuse:
                raise RuntimeError(f"fake: {cls.__name__} could not connect to {hostname}")
            robot.log.append((cls.__name__, "connect", hostname))
            return cls(robot)

        make.__name__ = cls.__name__
        return make

    return SimpleNamespace(
        RTDEControlInterface=factory(RTDEControlInterface),
        RTDEReceiveInterface=factory(RTDEReceiveInterface),
        RTDEIOInterface=factory(RTDEIOInterface),
    )
