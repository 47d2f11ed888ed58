"""The hardware-abstraction interfaces: what every robot, camera and tool looks like.

A lab talks only to these classes. The PyBullet world (``sim_backends``) and the real drivers
(``robots.drivers.*``) implement them, so code written against a simulated arm drives a real
one unchanged. Conventions (see DESIGN.md): poses are float64 (4, 4) arrays, ``a_T_b`` maps
b-coordinates to a-coordinates, SI units (metres, radians, seconds) everywhere.

How a backend implements a robot
--------------------------------
Subclass :class:`Robot` and implement ``flange_pose``, ``joint_positions``, ``joint_limits``,
``stop`` and the two motion hooks ``_move_to`` / ``_move_joints``. Students call the public
``move_to`` / ``move_joints``, which validate the input and run the :class:`~robots.safety.Safety`
checks *before* calling the hooks (a template method), so no backend can forget the checks and
a refused move never reaches the hardware. Release connections in ``_close``, not ``close``.
Read methods should start with ``self._require_open()``; ``tests/contract.py`` checks that.
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from robots.geometry import as_pose, invert
from robots.safety import Safety, SafetyError

__all__ = [
    "Intrinsics",
    "Frame",
    "SafetyError",
    "UnreachableError",
    "RobotDisconnectedError",
    "Tool",
    "Gripper",
    "SuctionCup",
    "Pointer",
    "Robot",
    "Camera",
    "Workcell",
]


# --------------------------------------------------------------------------- errors


class UnreachableError(RuntimeError):
    """No joint configuration reaches the requested pose (outside reach or joint limits)."""


class RobotDisconnectedError(RuntimeError):
    """The robot (or camera) was closed or lost its connection."""


# --------------------------------------------------------------------------- camera data


def _finite_float(value, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out}")
    return out


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """Pinhole camera intrinsics in pixels, OpenCV conventions.

    ``fx, fy`` are focal lengths and ``cx, cy`` the principal point, in pixels, with pixel
    centres at integer coordinates (OpenCV's convention: the top-left pixel's centre is
    (0, 0)). ``width, height`` are the image size in pixels. ``dist`` holds the distortion
    coefficients ``(k1, k2, p1, p2, k3)`` in OpenCV's order (a 4-vector gets ``k3 = 0``); it is
    stored as a read-only float64 array so it can be passed straight to ``cv2`` functions.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, _finite_float(getattr(self, name), name))
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(
                f"focal lengths must be positive pixels, got fx={self.fx}, fy={self.fy}; "
                "check the units (pixels, not millimetres) and the sign"
            )
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or int(value) != value or int(value) <= 0:
                raise ValueError(f"{name} must be a positive whole number of pixels, got {value!r}")
            object.__setattr__(self, name, int(value))
        dist = np.array(self.dist, dtype=float).reshape(-1)
        if dist.shape == (4,):
            dist = np.append(dist, 0.0)
        if dist.shape != (5,):
            raise ValueError(
                f"dist must hold 5 coefficients (k1, k2, p1, p2, k3), got {dist.size}; "
                "the rational and thin-prism models are not supported"
            )
        if not np.all(np.isfinite(dist)):
            raise ValueError(f"dist must be finite, got {dist}")
        dist.setflags(write=False)
        object.__setattr__(self, "dist", dist)

    @property
    def K(self) -> np.ndarray:
        """The (3, 3) camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (a fresh copy)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels, the order OpenCV's ``imageSize`` arguments use."""
        return (self.width, self.height)

    @classmethod
    def from_K(cls, K, width: int, height: int, dist=None) -> Intrinsics:
        """Build from a (3, 3) camera matrix (zero skew) and the image size in pixels."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise ValueError(f"K must have shape (3, 3), got {K.shape}")
        zeros = np.array([K[0, 1], K[1, 0], K[2, 0], K[2, 1], K[2, 2] - 1.0])
        if np.abs(zeros).max() > 1e-9:
            raise ValueError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got\n{K}")
        return cls(
            K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, np.zeros(5) if dist is None else dist
        )

    def scaled(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera with the image resized to ``width`` x ``height``.

        Uses the pixel-centre convention of ``cv2.resize``: a point at x maps to
        ``(x + 0.5) * s - 0.5``, so the principal point moves by half a pixel less than a
        plain ``cx * s``. Distortion coefficients act on normalised coordinates and do not change.
        """
        if int(width) <= 0 or int(height) <= 0:
            raise ValueError(f"scaled size must be positive, got {width}x{height}")
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            int(width),
            int(height),
            self.dist.copy(),
        )

    def to_dict(self) -> dict:
        """Plain-Python form (floats and lists) for YAML/JSON; ``from_dict`` inverts it exactly."""
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
            "dist": [float(d) for d in self.dist],
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> Intrinsics:
        missing = {"fx", "fy", "cx", "cy", "width", "height"} - set(d)
        if missing:
            raise ValueError(f"intrinsics are missing {sorted(missing)}")
        return cls(
            d["fx"], d["fy"], d["cx"], d["cy"], d["width"], d["height"], d.get("dist", np.zeros(5))
        )

    def __eq__(self, other) -> bool:
        if not isinstance(other, Intrinsics):
            return NotImplemented
        return (self.fx, self.fy, self.cx, self.cy, self.width, self.height) == (
            other.fx,
            other.fy,
            other.cx,
            other.cy,
            other.width,
            other.height,
        ) and bool(np.array_equal(self.dist, other.dist))

    def __hash__(self) -> int:
        return hash(
            (self.fx, self.fy, self.cx, self.cy, self.width, self.height, tuple(self.dist.tolist()))
        )


@dataclass
class Frame:
    """One camera image.

    ``rgb`` is (H, W, 3) uint8 in RGB order (OpenCV functions that expect BGR need
    ``cv2.cvtColor``). ``depth`` is (H, W) float32 in metres, aligned pixel for pixel with
    ``rgb`` (NaN where there is no measurement), or None for a camera without depth.
    ``timestamp`` is in seconds (simulation time in sim, host clock on a real camera).
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    timestamp: float
    camera_name: str = "cam"

    def __post_init__(self):
        rgb = np.asarray(self.rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"Frame.rgb must have shape (H, W, 3), got {rgb.shape}")
        if rgb.dtype != np.uint8:
            raise ValueError(
                f"Frame.rgb must be uint8, got {rgb.dtype}; convert with "
                "np.clip(img * 255, 0, 255).astype(np.uint8) if it is a 0..1 float image"
            )
        self.rgb = rgb
        if self.depth is not None:
            depth = np.asarray(self.depth)
            if depth.shape != rgb.shape[:2]:
                raise ValueError(
                    f"Frame.depth must be aligned with rgb, shape {rgb.shape[:2]}, "
                    f"got {depth.shape}"
                )
            if not np.issubdtype(depth.dtype, np.floating):
                raise ValueError(
                    f"Frame.depth must be float metres, got {depth.dtype}; a uint16 depth image "
                    "in millimetres converts with depth.astype(np.float32) / 1000"
                )
            self.depth = depth.astype(np.float32, copy=False)
        self.timestamp = _finite_float(self.timestamp, "Frame.timestamp")

    @property
    def height(self) -> int:
        return self.rgb.shape[0]

    @property
    def width(self) -> int:
        return self.rgb.shape[1]


# --------------------------------------------------------------------------- tools


class Tool(ABC):
    """Something mounted on the flange. ``flange_T_tcp`` (4, 4) is the tool tip in the flange frame.

    Subclasses call ``super().__init__(name, flange_T_tcp)``.
    """

    def __init__(self, name: str, flange_T_tcp=None):
        self.name = str(name)
        self.flange_T_tcp = (
            np.eye(4) if flange_T_tcp is None else as_pose(flange_T_tcp, "flange_T_tcp")
        )

    @abstractmethod
    def grasp(self) -> bool:
        """Close / switch on; return True if something is now held."""

    @abstractmethod
    def release(self) -> None:
        """Open / switch off, dropping whatever is held."""

    @property
    @abstractmethod
    def is_holding(self) -> bool:
        """True while an object is held."""

    def __repr__(self) -> str:
        offset = self.flange_T_tcp[:3, 3].tolist()
        return f"{type(self).__name__}(name={self.name!r}, tcp_offset_m={offset})"


class Gripper(Tool):
    """A two-finger gripper. Backends may add ``opening()`` (metres) or ``close(force)``."""


class SuctionCup(Tool):
    """A suction cup: ``grasp`` switches the vacuum on and succeeds only on contact."""


class Pointer(Tool):
    """A rigid pointed tip for touching points (three-point measurement). It holds nothing."""

    def __init__(self, name: str = "pointer", flange_T_tcp=None):
        super().__init__(name, flange_T_tcp)

    def grasp(self) -> bool:
        raise RuntimeError(
            f"tool {self.name!r} is a pointer and cannot grasp; mount a Gripper or SuctionCup "
            "(e.g. connect(..., tool='suction')) to pick objects"
        )

    def release(self) -> None:
        """Nothing to release; present so code that always releases keeps working."""

    @property
    def is_holding(self) -> bool:
        return False


# --------------------------------------------------------------------------- robot


def _as_speed(speed, name: str) -> float:
    speed = _finite_float(speed, name)
    if speed <= 0:
        raise ValueError(f"{name} must be positive, got {speed}")
    return speed


class Robot(ABC):
    """A robot arm. Public motion methods validate and run the safety checks, then move.

    Attributes: ``name`` (e.g. "panda"), ``safety`` (a :class:`~robots.safety.Safety`, checked
    before every move), ``tool`` (the mounted :class:`Tool` or None), ``settle_time_s`` (how
    long to wait after a move before taking a picture; a simulator that stops dead sets 0),
    ``move_listeners`` (callables run with no argument after each finished move, e.g. a 3-D
    view redrawing; one that fails is reported as a warning and never fails the move).
    """

    settle_time_s: float = 0.5

    def __init__(self, name: str, safety=None, tool: Tool | None = None):
        self.name = str(name)
        self.safety = Safety() if safety is None else safety
        self.tool = tool
        self._closed = False
        self.move_listeners: list = []

    # ----- to implement in a backend

    @abstractmethod
    def flange_pose(self) -> np.ndarray:
        """Current ``base_T_flange`` (4, 4), as the controller reports it (metres)."""

    @abstractmethod
    def joint_positions(self) -> np.ndarray:
        """Current joint angles, (n,) radians, as the controller reports them."""

    @abstractmethod
    def joint_limits(self) -> np.ndarray:
        """(n, 2) lower and upper joint limits in radians."""

    @abstractmethod
    def stop(self) -> None:
        """Stop any motion now. Must be safe to call at any time, twice, and after ``close``."""

    @abstractmethod
    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        """Move the flange linearly to a validated, safety-checked target (blocking)."""

    @abstractmethod
    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        """Move to validated, safety-checked joint angles (blocking)."""

    def _close(self) -> None:
        """Release the connection; called once by ``close``. Override in a backend."""

    # ----- public API

    @property
    def closed(self) -> bool:
        return self._closed

    def _require_open(self) -> None:
        if self._closed:
            raise RobotDisconnectedError(
                f"robot {self.name!r} is closed (its workcell was exited or close() was called); "
                "open a new one with robots.connect(...)"
            )

    def move_to(self, base_T_flange, speed: float = 0.1) -> None:
        """Move the flange in a straight line to ``base_T_flange`` (4, 4), at ``speed`` m/s.

        Blocks until the move ends. Raises ValueError for a malformed target (NaN, not a
        rotation), SafetyError if the move breaks a limit in ``self.safety`` (before anything
        moves), UnreachableError if no joint configuration reaches it. If the move itself is
        interrupted (Ctrl-C or an error), the robot is stopped and the exception re-raised.
        """
        self._require_open()
        target = as_pose(base_T_flange, "base_T_flange target")
        speed = _as_speed(speed, "speed (m/s)")
        current = self.flange_pose()
        flange_T_tcp = None if self.tool is None else self.tool.flange_T_tcp
        self.safety.check_cartesian_move(current, target, speed, flange_T_tcp=flange_T_tcp)
        self._run_move(self._move_to, target, speed)

    def move_tcp_to(self, base_T_tcp, speed: float = 0.1) -> None:
        """Like ``move_to`` but for the tool tip: ``base_T_tcp`` becomes the TCP pose."""
        flange_T_tcp = np.eye(4) if self.tool is None else self.tool.flange_T_tcp
        self.move_to(as_pose(base_T_tcp, "base_T_tcp target") @ invert(flange_T_tcp), speed)

    def move_joints(self, q, speed: float = 0.5) -> None:
        """Move to joint angles ``q`` (n,) radians, the fastest joint at ``speed`` rad/s (blocking).

        The same checks and stop-on-interrupt behaviour as ``move_to``.
        """
        self._require_open()
        current = np.asarray(self.joint_positions(), dtype=float)
        target = np.asarray(q, dtype=float)
        if target.shape != current.shape:
            raise ValueError(
                f"q must have shape {current.shape} (one angle per joint of {self.name}), "
                f"got {target.shape}"
            )
        bad = np.flatnonzero(~np.isfinite(target))
        if bad.size:
            raise ValueError(
                f"q[{bad[0]}] is {target[bad[0]]}; joint targets must be finite radians"
            )
        speed = _as_speed(speed, "speed (rad/s)")
        self.safety.check_joint_move(current, target, speed, robot_limits=self.joint_limits())
        self._run_move(self._move_joints, target, speed)

    def _run_move(self, move, target, speed) -> None:
        try:
            move(target, speed)
        except BaseException:  # includes KeyboardInterrupt: a half-finished move must stop
            try:
                self.stop()
            except Exception as stop_error:  # keep the original error; still shout about this one
                warnings.warn(
                    f"stop() failed after an interrupted move: {stop_error!r}",
                    RuntimeWarning,
                    stacklevel=3,
                )
            raise
        for listener in list(getattr(self, "move_listeners", ())):
            try:
                listener()
            except Exception as error:  # the move happened; a display must not undo that
                warnings.warn(f"a move listener failed after the move: {error!r}",
                              RuntimeWarning, stacklevel=3)

    def tcp_pose(self) -> np.ndarray:
        """``base_T_tcp = base_T_flange @ tool.flange_T_tcp`` (the flange pose if no tool)."""
        base_T_flange = self.flange_pose()
        return base_T_flange if self.tool is None else base_T_flange @ self.tool.flange_T_tcp

    def close(self) -> None:
        """Stop and disconnect. Idempotent; afterwards every call raises RobotDisconnectedError."""
        if self._closed:
            return
        try:
            self.stop()
        finally:
            self._closed = True
            self._close()

    def __enter__(self) -> Robot:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"{type(self).__name__}(name={self.name!r}, tool={self.tool!r}, {state})"


# --------------------------------------------------------------------------- camera


class Camera(ABC):
    """A camera with known ``intrinsics``.

    Subclasses call ``super().__init__(name, intrinsics)`` and implement ``capture``.
    """

    def __init__(self, name: str, intrinsics: Intrinsics):
        if not isinstance(intrinsics, Intrinsics):
            raise ValueError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        self.name = str(name)
        self.intrinsics = intrinsics

    @abstractmethod
    def capture(self) -> Frame:
        """Take one picture now (blocking) and return it."""

    def close(self) -> None:
        """Release the device. Idempotent. The default has nothing to release."""

    def __repr__(self) -> str:
        i = self.intrinsics
        return f"{type(self).__name__}(name={self.name!r}, {i.width}x{i.height}, fx={i.fx:.1f})"


# --------------------------------------------------------------------------- workcell


class Workcell:
    """A robot with its cameras, as returned by ``robots.connect``.

    ``camera`` is the main camera (or None), ``cameras`` all of them by name (e.g. "left",
    "right" for a stereo pair), ``truth`` the simulator's ground truth (None on a real robot;
    instructors and tests only), ``kind`` the backend name ("sim", "ur", ...).

    Use it as a context manager: on leaving the block, even through an exception, the robot is
    stopped, then the cameras and the robot are closed. Backends that hold more (a physics
    client, a socket) override ``_close``, which runs last.
    """

    def __init__(
        self,
        robot: Robot,
        camera: Camera | None = None,
        cameras: Mapping[str, Camera] | None = None,
        truth=None,
        kind: str = "sim",
    ):
        if not isinstance(robot, Robot):
            raise ValueError(f"robot must be a robots.Robot, got {type(robot).__name__}")
        self.robot = robot
        self.cameras: dict[str, Camera] = dict(cameras or {})
        if camera is None and self.cameras:
            camera = next(iter(self.cameras.values()))
        if camera is not None and camera not in self.cameras.values():
            self.cameras[camera.name] = camera
        self.camera = camera
        self.truth = truth
        self.kind = str(kind)
        self._closed = False

    def _close(self) -> None:
        """Backend hook, called after the robot and cameras are closed."""

    def visual_scene(self):
        """What a 3-D view can draw of this cell, read-only: a ``robots.viewer.VisualScene``.

        It holds the cell's shapes (arm links, tool, table, targets, pieces) at their poses
        now and the true poses of its frames, all in the robot base frame (metres); each call
        reads them afresh. None (this default) when the backend has no model of the cell, as
        on a real robot: ``robots.viewer`` then draws the frames it can read from the robot.
        """
        return None

    def close(self) -> None:
        """Stop the robot, close cameras and robot, then the backend. Idempotent.

        Every step runs even if an earlier one fails; the first failure is re-raised at the end.
        """
        if self._closed:
            return
        self._closed = True
        steps = [
            self.robot.stop,
            *(c.close for c in self.cameras.values()),
            self.robot.close,
            self._close,
        ]
        first_error = None
        for step in steps:
            try:
                step()
            except Exception as error:
                first_error = first_error or error
        if first_error is not None:
            raise first_error

    def __enter__(self) -> Workcell:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.close()
        except Exception:
            if exc is None:
                raise
            # An error is already propagating; it is the one the user needs to see.
            warnings.warn(
                "closing the workcell also failed; see the original error",
                RuntimeWarning,
                stacklevel=2,
            )

    def __repr__(self) -> str:
        cams = ", ".join(self.cameras) or "no camera"
        return f"Workcell(kind={self.kind!r}, robot={self.robot.name!r}, cameras=[{cams}])"
