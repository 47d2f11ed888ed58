"""Safety limits checked before every move, in simulation and on a real robot alike.

``Robot.move_to`` and ``Robot.move_joints`` call :meth:`Safety.check_cartesian_move` /
:meth:`Safety.check_joint_move` before anything moves; a violation raises
:class:`SafetyError` naming the limit, the requested value and the fix.
Students meet the same errors in sim as on the real arm, so a lab that runs clean in sim does
not surprise anyone in the lab room.

The checks look at the target and at the size of the step, not at the path in between: the
workspace box is convex, so a straight-line flange move between two points inside it stays
inside it. A TCP that rotates while moving can bulge out slightly; keep the floor margin.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from robots.geometry import as_pose, rotation_angle_deg, warn_caller

__all__ = ["ANGULAR_SPEED_MAX", "Safety", "SafetyError", "ask_on_terminal",
           "check_angular_speed"]

MODES = ("auto", "confirm")

#: rad/s. An angular speed (or speed limit) above one turn per second looks like deg/s: no
#: cobot joint or wrist turns that fast (UR e-Series: pi rad/s on the base joints, 2 pi on
#: the wrist; Panda: 2.6 rad/s), while 30 deg/s, typed as 30, is 4.8 turns a second.
ANGULAR_SPEED_MAX = 2.0 * math.pi


def check_angular_speed(value: float, name: str) -> float:
    """``value`` (an angular speed or limit, rad/s) unchanged; a warning naming ``name`` when
    it is finite and above ``ANGULAR_SPEED_MAX`` (a turn per second): it looks like deg/s.

    A warning, not an error: the number is legal, only implausible (inf means "no limit" and
    passes silently). Shared by the safety limits and the servo laws' saturation."""
    if value > ANGULAR_SPEED_MAX and math.isfinite(value):
        warn_caller(
            f"{name} = {value:g} rad/s is more than a turn per second ({math.degrees(value):.4g} "
            f"deg/s): it looks like deg/s. Angular speeds are rad/s: pass "
            f"np.radians({value:g}) = {math.radians(value):.4g}")
    return value


class SafetyError(RuntimeError):
    """A move was refused by the safety checks (or by the operator); nothing moved.

    Defined here, next to the checks that raise it, so that this module needs nothing from
    ``robots.interfaces`` (which re-exports it): the dependency runs one way only.
    """


def ask_on_terminal(message: str) -> bool:
    """Default confirmation: print the planned move and accept only 'y' or 'yes'."""
    answer = input(f"{message}\nMove? [y/N] ")
    return answer.strip().lower() in ("y", "yes")


def _vec3(value, name: str) -> np.ndarray:
    v = np.array(value, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(
            f"Safety.{name} must be 3 finite numbers (x, y, z) in metres, got {value!r}"
        )
    return v


def _positive(value, name: str, unit: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"Safety.{name} must be a positive number of {unit}, got {value!r}")
    return v


@dataclass
class Safety:
    """Limits every move must respect. Units: metres, m/s, radians, rad/s.

    * ``workspace_min`` / ``workspace_max``: an axis-aligned box in the robot base frame that
      the flange and the TCP must end inside. The default floor (z = 0.01 m) assumes the robot
      stands on the table top; raise it for a thick fixture, lower it only with care.
    * ``max_speed``: Cartesian speed cap for ``move_to`` (0.25 m/s is the usual collaborative
      limit for a person within reach).
    * ``max_joint_speed``: joint speed cap for ``move_joints``.
    * ``max_step`` / ``max_rotation_step``: the largest translation (m) and rotation (rad) a
      single ``move_to`` may make; ``max_joint_step``: the largest change of any one joint (rad)
      in a single ``move_joints``. Longer moves must be split into waypoints, which stops a
      typo (metres for millimetres) from sending the arm across the room.
    * ``joint_limits``: (n, 2) radians, or None to use only the robot's own limits; when both
      are given the tighter one wins.
    * ``mode``: "auto" moves once the checks pass; "confirm" also prints the planned move and
      asks ``confirm(message) -> bool`` (default: a y/N prompt on the terminal) first.
    """

    workspace_min: np.ndarray = field(default_factory=lambda: np.array([-1.0, -1.0, 0.01]))
    workspace_max: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0, 1.3]))
    max_speed: float = 0.25
    max_joint_speed: float = 1.0
    max_step: float = 0.5
    max_rotation_step: float = np.pi / 2
    max_joint_step: float = np.pi / 2
    joint_limits: np.ndarray | None = None
    mode: str = "auto"
    confirm: Callable[[str], bool] | None = None

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Normalise the fields and raise ValueError if any is malformed.

        Runs at construction and again before every check, so a limit edited in place
        (``robot.safety.max_speed = 0.1``) is validated too.
        """
        self.workspace_min = _vec3(self.workspace_min, "workspace_min")
        self.workspace_max = _vec3(self.workspace_max, "workspace_max")
        bad = np.flatnonzero(self.workspace_min >= self.workspace_max)
        if bad.size:
            axis = "xyz"[bad[0]]
            raise ValueError(
                f"Safety workspace is empty along {axis}: workspace_min.{axis}="
                f"{self.workspace_min[bad[0]]} m >= workspace_max.{axis}="
                f"{self.workspace_max[bad[0]]} m"
            )
        self.max_speed = _positive(self.max_speed, "max_speed", "m/s")
        self.max_joint_speed = _positive(self.max_joint_speed, "max_joint_speed", "rad/s")
        self.max_step = _positive(self.max_step, "max_step", "metres")
        self.max_rotation_step = _positive(self.max_rotation_step, "max_rotation_step", "radians")
        self._warn_degrees()
        self.max_joint_step = _positive(self.max_joint_step, "max_joint_step", "radians")
        if self.joint_limits is not None:
            self.joint_limits = _as_limits(self.joint_limits, "Safety.joint_limits")
        if self.mode not in MODES:
            raise ValueError(f"Safety.mode must be one of {MODES}, got {self.mode!r}")
        if self.confirm is not None and not callable(self.confirm):
            raise ValueError(
                "Safety.confirm must be a callable taking the message and returning bool"
            )

    def _warn_degrees(self) -> None:
        """Warn once per value (validate runs before every move) about an angular limit that
        looks like degrees: a joint speed cap above a turn per second, a rotation step above
        a full turn."""
        seen = self.__dict__.setdefault("_warned_values", {})
        speed, step = self.max_joint_speed, self.max_rotation_step
        if seen.get("max_joint_speed") != speed:
            seen["max_joint_speed"] = speed
            check_angular_speed(speed, "Safety.max_joint_speed")
        if seen.get("max_rotation_step") != step:
            seen["max_rotation_step"] = step
            if step > 2.0 * math.pi:
                warn_caller(
                    f"Safety.max_rotation_step = {step:g} rad is more than a full turn "
                    f"({math.degrees(step):.4g} deg): it looks like degrees. Angles are "
                    f"radians: pass np.radians({step:g}) = {math.radians(step):.4g}")

    # ----------------------------------------------------------------------- Cartesian

    def check_cartesian_move(
        self, current_base_T_flange, target_base_T_flange, speed: float, flange_T_tcp=None
    ) -> None:
        """Raise SafetyError if a linear move of the flange from current to target is unsafe.

        Checks, in order: speed cap, that the flange (and the TCP, if ``flange_T_tcp`` is given)
        ends inside the workspace box, the translation step and the rotation step. Only the
        target must lie in the box, so a robot that starts outside may move back in. In
        "confirm" mode the operator is asked last. Malformed poses raise ValueError.
        """
        self.validate()
        current = as_pose(current_base_T_flange, "current base_T_flange")
        target = as_pose(target_base_T_flange, "target base_T_flange")
        speed = float(speed)
        if not np.isfinite(speed) or speed <= 0:
            raise ValueError(f"speed must be a positive number of m/s, got {speed}")
        if speed > self.max_speed:
            raise SafetyError(
                f"speed {speed:.3f} m/s exceeds the Cartesian speed cap Safety.max_speed="
                f"{self.max_speed:.3f} m/s; move slower (speed <= {self.max_speed:g})"
            )
        self._check_in_box(target[:3, 3], "flange")
        if flange_T_tcp is not None:
            tcp = target @ as_pose(flange_T_tcp, "flange_T_tcp")
            self._check_in_box(tcp[:3, 3], "TCP")
        step = float(np.linalg.norm(target[:3, 3] - current[:3, 3]))
        if step > self.max_step:
            raise SafetyError(
                f"a single move of {step:.3f} m exceeds Safety.max_step={self.max_step:.3f} m; "
                "split it into waypoints, or check the units (metres, not millimetres)"
            )
        angle = np.radians(rotation_angle_deg(current[:3, :3].T @ target[:3, :3]))
        if angle > self.max_rotation_step:
            raise SafetyError(
                f"a single move rotates the flange by {np.degrees(angle):.1f} deg, more than "
                f"Safety.max_rotation_step={np.degrees(self.max_rotation_step):.1f} deg; split it "
                "into smaller rotations, or check for a flipped axis or degrees passed as radians"
            )
        if self.mode == "confirm":
            self._ask(_describe_cartesian(current, target, speed))

    def _check_in_box(self, p: np.ndarray, what: str) -> None:
        lo, hi = self.workspace_min, self.workspace_max
        for i, axis in enumerate("xyz"):
            if p[i] < lo[i]:
                hint = (
                    "raise the target or lower Safety.workspace_min[2] if the table is lower"
                    if axis == "z"
                    else f"move the target towards +{axis} or widen Safety.workspace_min[{i}]"
                )
                side = "below the workspace floor" if axis == "z" else "below the workspace limit"
                raise SafetyError(
                    f"target {what} {axis}={p[i]:.4f} m is {side} {lo[i]:.4f} m "
                    f"(Safety.workspace_min); {hint}"
                )
            if p[i] > hi[i]:
                raise SafetyError(
                    f"target {what} {axis}={p[i]:.4f} m is beyond the workspace limit "
                    f"{hi[i]:.4f} m (Safety.workspace_max); bring the target closer or widen "
                    f"Safety.workspace_max[{i}] if the cell really is larger"
                )

    # ----------------------------------------------------------------------- joints

    def check_joint_move(self, current_q, target_q, speed: float, robot_limits=None) -> None:
        """Raise SafetyError if moving the joints from ``current_q`` to ``target_q`` is unsafe.

        Checks the joint speed cap, the joint limits (``self.joint_limits`` and the robot's
        own ``robot_limits``, the tighter wins) and the largest single-joint step. Radians and
        rad/s. Malformed inputs raise ValueError.
        """
        self.validate()
        current = np.asarray(current_q, dtype=float).reshape(-1)
        target = np.asarray(target_q, dtype=float)
        if target.shape != current.shape:
            raise ValueError(f"target q must have shape {current.shape}, got {target.shape}")
        for name, q in (("current q", current), ("target q", target)):
            bad = np.flatnonzero(~np.isfinite(q))
            if bad.size:
                raise ValueError(f"{name}[{bad[0]}] is {q[bad[0]]}; joint angles must be finite")
        speed = float(speed)
        if not np.isfinite(speed) or speed <= 0:
            raise ValueError(f"speed must be a positive number of rad/s, got {speed}")
        if speed > self.max_joint_speed:
            degrees = (f"; {speed:g} rad/s is more than a turn per second: if you meant "
                       f"{speed:g} deg/s, pass np.radians({speed:g}) = {math.radians(speed):.4g}"
                       if speed > ANGULAR_SPEED_MAX else "")
            raise SafetyError(
                f"joint speed {speed:.3f} rad/s exceeds Safety.max_joint_speed="
                f"{self.max_joint_speed:.3f} rad/s; move slower (speed <= {self.max_joint_speed:g})"
                f"{degrees}"
            )
        limits = self._effective_limits(len(target), robot_limits)
        if limits is not None:
            for j, (q, (lo, hi)) in enumerate(zip(target, limits)):
                if not lo <= q <= hi:
                    raise SafetyError(
                        f"joint {j} target {q:+.4f} rad ({np.degrees(q):+.1f} deg) is outside its "
                        f"limits [{lo:+.4f}, {hi:+.4f}] rad ([{np.degrees(lo):+.1f}, "
                        f"{np.degrees(hi):+.1f}] deg); choose a target within the limits "
                        "(for a pose, try another IK solution)"
                    )
        steps = np.abs(target - current)
        j = int(np.argmax(steps))
        if steps[j] > self.max_joint_step:
            raise SafetyError(
                f"joint {j} would move {steps[j]:.3f} rad ({np.degrees(steps[j]):.1f} deg) in one "
                f"step, more than Safety.max_joint_step={self.max_joint_step:.3f} rad "
                f"({np.degrees(self.max_joint_step):.1f} deg); split the move into waypoints, "
                "or check for degrees passed as radians"
            )
        if self.mode == "confirm":
            self._ask(_describe_joints(current, target, speed))

    def _effective_limits(self, n: int, robot_limits) -> np.ndarray | None:
        limits = None
        for name, lim in (
            ("Safety.joint_limits", self.joint_limits),
            ("robot joint limits", robot_limits),
        ):
            if lim is None:
                continue
            lim = _as_limits(lim, name)
            if len(lim) != n:
                raise ValueError(f"{name} has {len(lim)} rows but the robot has {n} joints")
            limits = (
                lim
                if limits is None
                else np.column_stack(
                    [np.maximum(limits[:, 0], lim[:, 0]), np.minimum(limits[:, 1], lim[:, 1])]
                )
            )
        return limits

    # ----------------------------------------------------------------------- confirm

    def _ask(self, message: str) -> None:
        ask = self.confirm or ask_on_terminal
        if not ask(message):
            raise SafetyError("move refused by the operator (Safety.mode='confirm'); nothing moved")


def _as_limits(value, name: str) -> np.ndarray:
    lim = np.array(value, dtype=float)
    if lim.ndim != 2 or lim.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) (lower, upper radians), got {lim.shape}")
    if not np.all(np.isfinite(lim)):
        raise ValueError(f"{name} must be finite; use a large bound such as 2*pi for a free joint")
    bad = np.flatnonzero(lim[:, 0] >= lim[:, 1])
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] has lower {lim[bad[0], 0]} >= upper {lim[bad[0], 1]}")
    return lim


def _describe_cartesian(current: np.ndarray, target: np.ndarray, speed: float) -> str:
    from robots.geometry import rpy_from_pose

    def fmt(T):
        x, y, z = T[:3, 3] * 1000
        r, p, yw = rpy_from_pose(T, degrees=True)
        return f"x={x:.1f} y={y:.1f} z={z:.1f} mm, rpy=({r:.1f}, {p:.1f}, {yw:.1f}) deg"

    dist = np.linalg.norm(target[:3, 3] - current[:3, 3]) * 1000
    angle = rotation_angle_deg(current[:3, :3].T @ target[:3, :3])
    return (
        f"Planned linear move of the flange ({dist:.1f} mm, {angle:.1f} deg) at "
        f"{speed * 1000:.0f} mm/s\n  from {fmt(current)}\n  to   {fmt(target)}"
    )


def _describe_joints(current: np.ndarray, target: np.ndarray, speed: float) -> str:
    def fmt(q):
        return "[" + ", ".join(f"{v:.1f}" for v in np.degrees(q)) + "] deg"

    return (
        f"Planned joint move at {np.degrees(speed):.1f} deg/s\n  from {fmt(current)}\n"
        f"  to   {fmt(target)}"
    )
