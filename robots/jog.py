"""Jogging: small, deliberate moves of the arm by hand, in sim and on a real robot.

Three layers, each built on the one before:

* :func:`jog_target` / :func:`jog_step` compute where one jog step goes (pure pose math);
  :func:`jog` moves there through the ordinary ``Robot.move_to``, so every jog passes the
  same :class:`~robots.safety.Safety` checks as any other move. A refused move raises
  ``SafetyError`` (or ``UnreachableError``) and nothing moves.
* :func:`run_jog_console` is the terminal loop behind ``cobotlab robot check --jog``: it asks
  the operator to confirm EVERY move, whatever the Safety mode.
* :class:`JogPanel` (``jog_panel(cell)``) is the ipywidgets panel for notebooks: step sliders,
  base/tool frame toggle, +/- buttons per axis, a pose readout and a STOP button.

Frames and units
----------------
Axes are ``x, y, z`` (translation, metres) and ``rx, ry, rz`` (rotation, radians).
``frame="base"`` jogs along / about axes parallel to the robot base frame; ``frame="tool"``
along / about the axes of the TCP frame (the flange frame when no tool is mounted). Rotations
always turn about an axis through the TCP, so the tool tip stays put while it tilts: the way
teach pendants jog. Results are ``base_T_flange`` targets, since that is what ``move_to``
takes. The console and the panel speak mm and degrees; everything else is SI.

One jog step is limited to :data:`MAX_JOG_STEP_M` (20 mm) and :data:`MAX_JOG_STEP_RAD`
(10 deg): a jog is for nudging, and the cap catches millimetres typed as metres.
"""

from __future__ import annotations

import asyncio
import html
import math
import re
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from robots.geometry import (
    as_pose,
    invert,
    make_pose,
    pose_from_rotvec,
    rotation_error_deg,
    rpy_from_pose,
    translation_error,
)
from robots.interfaces import (
    Robot,
    RobotDisconnectedError,
    SafetyError,
    UnreachableError,
    Workcell,
)

__all__ = [
    "AXES",
    "FRAMES",
    "JOG_SPEED",
    "MAX_JOG_STEP_M",
    "MAX_JOG_STEP_RAD",
    "JogPanel",
    "RefreshTimer",
    "format_pose",
    "jog",
    "jog_panel",
    "jog_step",
    "jog_target",
    "in_panel_units",
    "run_jog_console",
]

AXES = ("x", "y", "z", "rx", "ry", "rz")
FRAMES = ("base", "tool")
MAX_JOG_STEP_M = 0.020
MAX_JOG_STEP_RAD = math.radians(10.0)
JOG_SPEED = 0.02  # m/s: a 5 mm jog takes a quarter of a second, slow enough to watch

_MAX_STEP_MM = MAX_JOG_STEP_M * 1000
_MAX_STEP_DEG = math.degrees(MAX_JOG_STEP_RAD)
_RPY_NOTE = "rpy: R = Rz(yaw) Ry(pitch) Rx(roll)"


# --------------------------------------------------------------------------- pose math


def _check_axis_frame(axis, frame) -> None:
    if axis not in AXES:
        raise ValueError(f"jog axis must be one of {AXES}, got {axis!r}")
    if frame not in FRAMES:
        raise ValueError(
            f"jog frame must be 'base' (axes of the robot base) or 'tool' (axes of the TCP), "
            f"got {frame!r}"
        )


def _check_step(axis: str, step) -> float:
    try:
        step = float(step)
    except (TypeError, ValueError):
        raise ValueError(f"jog step must be a number, got {step!r}") from None
    rotation = axis.startswith("r")
    unit = "rad" if rotation else "m"
    if not math.isfinite(step) or step == 0.0:
        raise ValueError(f"jog step along {axis} must be finite and non-zero, got {step} {unit}")
    limit = MAX_JOG_STEP_RAD if rotation else MAX_JOG_STEP_M
    if abs(step) > limit + 1e-12:
        hint = (
            "steps are in radians (2 deg = math.radians(2))"
            if rotation
            else "steps are in metres (5 mm = 0.005)"
        )
        raise ValueError(
            f"jog step {step:g} {unit} along {axis} is larger than the jog limit "
            f"{limit:.4g} {unit} ({_MAX_STEP_DEG:g} deg / {_MAX_STEP_MM:g} mm); {hint}; "
            "use move_to for longer moves"
        )
    return step


def jog_target(base_T_flange, axis: str, step: float, frame: str = "base",
               flange_T_tcp=None) -> np.ndarray:
    """Where one jog step takes the flange: a new ``base_T_flange`` (4, 4). Pure pose math.

    ``base_T_flange`` is the current flange pose (metres), ``axis`` one of ``AXES``, ``step``
    metres for x/y/z or radians for rx/ry/rz (signed; at most ``MAX_JOG_STEP_M`` /
    ``MAX_JOG_STEP_RAD`` in size), ``flange_T_tcp`` the tool offset (None: TCP = flange).

    ``frame="base"`` translates the TCP along a base axis, or turns it about an axis parallel
    to a base axis through the TCP point. ``frame="tool"`` does the same along / about the TCP
    frame's own axes. Either way a rotation leaves the TCP position unchanged, and a
    translation leaves every orientation unchanged. Raises ValueError for a bad axis, frame or
    step.
    """
    _check_axis_frame(axis, frame)
    step = _check_step(axis, step)
    base_T_flange = as_pose(base_T_flange, "base_T_flange")
    flange_T_tcp = np.eye(4) if flange_T_tcp is None else as_pose(flange_T_tcp, "flange_T_tcp")
    unit = np.zeros(3)
    unit["xyz".index(axis[-1])] = 1.0
    delta = pose_from_rotvec(step * unit) if axis.startswith("r") else make_pose(t=step * unit)

    base_T_tcp = base_T_flange @ flange_T_tcp
    if frame == "tool":
        moved = base_T_tcp @ delta
    else:
        # Apply delta in a frame at the TCP point with base-parallel axes, so a rotation turns
        # about the tip rather than about the base origin (which would swing the arm around).
        at_tcp = make_pose(t=base_T_tcp[:3, 3])
        moved = at_tcp @ delta @ invert(at_tcp) @ base_T_tcp
    return moved @ invert(flange_T_tcp)


def _robot_of(cell) -> Robot:
    if isinstance(cell, Workcell):
        return cell.robot
    if isinstance(cell, Robot):
        return cell
    raise ValueError(
        f"expected a robots.Workcell (from robots.connect) or a Robot, got {type(cell).__name__}"
    )


def _tcp_offset(robot: Robot) -> np.ndarray | None:
    return None if robot.tool is None else robot.tool.flange_T_tcp


def jog_step(robot, axis: str, step: float, frame: str = "base") -> np.ndarray:
    """The ``base_T_flange`` target (4, 4) of one jog step from ``robot``'s current pose.

    Reads the flange pose and the mounted tool's TCP offset, then calls :func:`jog_target`
    (see there for axes, units and frames). Moves nothing. ``robot`` may be a Workcell.
    """
    robot = _robot_of(robot)
    return jog_target(robot.flange_pose(), axis, step, frame, _tcp_offset(robot))


def jog(robot, axis: str, step: float, frame: str = "base", speed: float = JOG_SPEED) -> np.ndarray:
    """Move one jog step (see :func:`jog_target`) at ``speed`` m/s; return the new flange pose.

    Goes through ``robot.move_to``, so the Safety checks (workspace, speed cap, step sizes and,
    in "confirm" mode, the operator) come first: a refused move raises SafetyError, an
    unreachable one UnreachableError, and in both cases nothing moves. Returns the
    ``base_T_flange`` (4, 4) the controller reports after the move.
    """
    robot = _robot_of(robot)
    robot.move_to(jog_step(robot, axis, step, frame), speed)
    return robot.flange_pose()


def format_pose(robot) -> str:
    """The robot's flange (and TCP, if a tool is mounted) pose as text in mm and degrees.

    Positions are in the base frame; angles are roll, pitch, yaw with
    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (fixed axes x, y, z), as ``rpy_from_pose`` gives.
    """
    robot = _robot_of(robot)
    poses = [("flange", robot.flange_pose())]
    if robot.tool is not None:
        poses.append(("tcp", robot.tcp_pose()))
    lines = []
    for label, T in poses:
        x, y, z = T[:3, 3] * 1000
        roll, pitch, yaw = rpy_from_pose(T, degrees=True)
        lines.append(
            f"{label:<6} x {x:8.1f}  y {y:8.1f}  z {z:8.1f} mm   "
            f"roll {roll:7.2f}  pitch {pitch:7.2f}  yaw {yaw:7.2f} deg"
        )
    return "\n".join(lines)


def _describe(axis: str, step: float, frame: str) -> str:
    amount = f"{math.degrees(step):+g} deg" if axis.startswith("r") else f"{step * 1000:+g} mm"
    return f"jog {axis} {amount} in the {frame} frame"


# A length in metres, a speed in m/s or an angle in radians inside an error message ("z=0.4010 m",
# "0.300 m/s", "+3.1000 rad"), unless the text already gives the angle in degrees beside it.
_SI_QUANTITY = re.compile(
    r"(?<![\w.])([+-]?\d+(?:\.\d+)?(?:e[+-]?\d+)?) (m/s|m|rad/s|rad)\b(?!\s*\(\s*[+-]?[\d.]+ deg)")


def in_panel_units(message: str) -> str:
    """``message`` with its metres and radians rewritten as mm and degrees, as the panel speaks.

    Safety, IK and driver errors speak SI units (DESIGN.md), but a student who set the step to
    5 mm should read "z=401.0 mm is beyond the workspace limit 400.0 mm", not "0.4010 m". Only
    the numbers with a unit change; a radian value that already has its degrees beside it in
    brackets, as Safety's joint messages do, stays as it is. Setting names such as
    ``Safety.max_step`` keep their meaning (they are set in metres, which the text then says).
    """
    def convert(match: re.Match) -> str:
        value, unit = float(match.group(1)), match.group(2)
        if unit in ("m", "m/s"):
            return f"{value * 1000:.1f} mm" + ("/s" if unit == "m/s" else "")
        return f"{math.degrees(value):.2f} deg" + ("/s" if unit == "rad/s" else "")

    converted = _SI_QUANTITY.sub(convert, message)
    if converted != message and "Safety." in converted:
        converted += " (Safety's limits themselves are set in metres and radians)"
    return converted


def _step_value(axis: str, sign: int, step_mm: float, step_deg: float) -> float:
    """Signed step in SI units (m or rad) for ``axis`` from the mm / deg settings."""
    size = math.radians(step_deg) if axis.startswith("r") else step_mm / 1000
    return size if sign > 0 else -size


@contextmanager
def _confirm_each_move(safety, ask: Callable[[str], bool]):
    """Run moves in Safety "confirm" mode with ``ask`` as the question, then restore the mode.

    Reusing Safety's own confirm step means the operator is asked only after every limit
    check has passed, and is shown Safety's from/to description of the move.
    """
    saved = (safety.mode, safety.confirm)
    safety.mode, safety.confirm = "confirm", ask
    try:
        yield
    finally:
        safety.mode, safety.confirm = saved


# --------------------------------------------------------------------------- console

_CONSOLE_HELP = f"""\
commands:
  x+ x- y+ y- z+ z-        move the TCP one step along an axis
  rx+ rx- ry+ ry- rz+ rz-  turn the TCP one step about an axis (through the tip)
  step MM                  translation step in mm (0 < MM <= {_MAX_STEP_MM:g})
  rstep DEG                rotation step in degrees (0 < DEG <= {_MAX_STEP_DEG:g})
  frame base | frame tool  jog along the base axes or the tool (TCP) axes
  p                        print the pose        h   this help
  q                        stop the robot and quit (Ctrl-C or Ctrl-D also stop and quit)
Every move is shown and needs a 'y' before the robot moves."""


def _check_speed(speed) -> float:
    speed = float(speed)
    if not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"jog speed must be a positive number of m/s, got {speed}")
    return speed


def _parse_size(text: str, limit: float, unit: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{name} needs a number of {unit}, got {text!r}") from None
    if not (math.isfinite(value) and 0 < value <= limit):
        raise ValueError(
            f"{name} must be more than 0 and at most {limit:g} {unit} (the jog limit), got "
            f"{text}; for longer moves use move_to in code"
        )
    return value


def run_jog_console(cell, read: Callable[[str], str] | None = None,
                    write: Callable[[str], None] | None = None,
                    step_mm: float = 5.0, step_deg: float = 2.0, frame: str = "base",
                    speed: float = JOG_SPEED) -> int:
    """Jog the robot from a terminal; every move is confirmed. Returns the number of moves made.

    ``cell`` is a Workcell (or a Robot). ``read(prompt) -> str`` and ``write(text)`` talk to the
    operator (``input`` / ``print`` by default; tests pass scripted ones). ``step_mm`` (mm,
    at most 20) and ``step_deg`` (degrees, at most 10) are the starting step sizes, ``frame``
    "base" or "tool" (see :func:`jog_target`), ``speed`` the jog speed in m/s.

    Each move runs through ``robot.move_to`` with the Safety checks; the operator is then shown
    the planned move (from/to, mm and degrees) and must answer y, whatever
    ``robot.safety.mode`` is (the mode and confirm callable are restored after each move).
    A refused or unreachable move is reported and the loop goes on. ``q``, end of input
    (Ctrl-D) or Ctrl-C stop the robot and return; other errors stop the robot and propagate.
    The caller keeps ownership of the cell (this does not close it).
    """
    # Looked up at call time, so a redirected input()/print() (a notebook, a test) is honoured.
    read = input if read is None else read
    write = print if write is None else write
    robot = _robot_of(cell)
    if frame not in FRAMES:
        raise ValueError(f"frame must be 'base' or 'tool', got {frame!r}")
    step_mm = _parse_size(str(step_mm), _MAX_STEP_MM, "mm", "step_mm")
    step_deg = _parse_size(str(step_deg), _MAX_STEP_DEG, "deg", "step_deg")
    speed = _check_speed(speed)
    moves = 0

    write(f"jogging {robot.name}; positions in the base frame, {_RPY_NOTE}")
    write(_CONSOLE_HELP)
    write(format_pose(robot))
    try:
        while True:
            line = read(f"jog [{frame}, {step_mm:g} mm, {step_deg:g} deg]> ")
            words = line.strip().lower().split()
            if not words:
                continue
            command, args = words[0], words[1:]
            planned = None  # (axis, signed step in m or rad)
            try:
                if command in ("q", "quit", "exit"):
                    break
                elif command in ("h", "help", "?"):
                    write(_CONSOLE_HELP)
                elif command in ("p", "pose"):
                    write(format_pose(robot))
                elif command == "step" and len(args) == 1:
                    step_mm = _parse_size(args[0], _MAX_STEP_MM, "mm", "step")
                    write(f"translation step: {step_mm:g} mm")
                elif command == "rstep" and len(args) == 1:
                    step_deg = _parse_size(args[0], _MAX_STEP_DEG, "deg", "rstep")
                    write(f"rotation step: {step_deg:g} deg")
                elif command == "frame" and len(args) == 1 and args[0] in FRAMES:
                    frame = args[0]
                    write(f"jogging in the {frame} frame")
                elif len(command) >= 2 and command[:-1] in AXES and command[-1] in "+-" \
                        and not args:
                    axis = command[:-1]
                    sign = 1 if command[-1] == "+" else -1
                    planned = axis, _step_value(axis, sign, step_mm, step_deg)
                else:
                    write(f"unknown command {line.strip()!r}; type h for help")
            except ValueError as error:
                write(f"not understood: {error}")
            if planned is not None:
                moves += _console_move(robot, *planned, frame, speed, read, write)
    except (EOFError, KeyboardInterrupt):
        write("")  # the prompt line is still open
    finally:
        try:
            robot.stop()
            write(f"robot stopped; {moves} jog move(s) made.")
        except Exception as error:  # keep any error already propagating
            write(f"warning: robot.stop() failed ({error}); use the emergency stop if it moves")
    return moves


def _console_move(robot, axis, step, frame, speed, read, write) -> int:
    """One confirmed jog move; 1 if the robot moved, 0 if it was refused."""
    description = _describe(axis, step, frame)
    declined = []

    def ask(message: str) -> bool:
        write(f"{description}\n{message}")
        yes = read("Move? [y/N] ").strip().lower() in ("y", "yes")
        if not yes:
            declined.append(True)
        return yes

    try:
        with _confirm_each_move(robot.safety, ask):
            jog(robot, axis, step, frame, speed)
    except SafetyError as error:
        write("not moved: you answered no." if declined
              else f"not moved (refused): {in_panel_units(str(error))}")
        return 0
    except UnreachableError as error:
        write(f"not moved (unreachable): {in_panel_units(str(error))}")
        return 0
    write("moved.")
    write(format_pose(robot))
    return 1


# --------------------------------------------------------------------------- notebook panel


class RefreshTimer:
    """Calls ``refresh()`` every few seconds on the running event loop until it returns False.

    In Jupyter the kernel's loop runs between cells, so the callback never interrupts a move;
    outside a running loop (a plain script) :meth:`start` does nothing and returns False.
    Shared by the jog panel and the 3-D view (``robots.viewer``).
    """

    def __init__(self, refresh: Callable[[], bool]):
        self._refresh = refresh
        self._task: asyncio.Task | None = None

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def start(self, period_s: float) -> bool:
        """(Re)start with a period of ``period_s`` seconds; False when no loop is running."""
        period_s = float(period_s)
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be a positive number of seconds, got {period_s}")
        self.stop()
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return False
        self._task = loop.create_task(self._every(period_s))
        return True

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None

    async def _every(self, period_s: float) -> None:
        while True:
            await asyncio.sleep(period_s)
            if not self._refresh():
                return



def _ipywidgets():
    try:
        import ipywidgets
    except ModuleNotFoundError:
        raise ImportError(
            "the jog panel needs ipywidgets; install it with `pip install 'cobotlab[course]'` "
            "(or `pip install 'ipywidgets>=8.1,<9'`), or use `cobotlab robot check --jog`"
        ) from None
    return ipywidgets


@dataclass
class _PlannedJog:
    description: str
    start: np.ndarray  # base_T_flange when the jog was planned
    target: np.ndarray  # base_T_flange to move to


class JogPanel:
    """An ipywidgets jog panel over a Workcell (sim or real). Display it as a cell's last line.

    Widgets (attributes, so tests and notebooks can reach them): ``step_mm`` and ``step_deg``
    sliders (at most 20 mm / 10 deg), ``frame`` toggle ("base" / "tool", see
    :func:`jog_target`), ``axis_buttons[(axis, sign)]`` (sign +1 / -1), ``readout`` (the
    flange and TCP pose, mm and deg), ``stop_button``, ``confirm_button`` / ``cancel_button``
    and ``output`` (plain-words messages; never a traceback). ``widget`` is the whole panel.

    The buttons call the methods :meth:`jog`, :meth:`stop`, :meth:`confirm` and
    :meth:`cancel`, which can also be called directly. Each jog goes through
    ``robot.move_to`` and the Safety checks. In confirm mode a jog button only plans the move
    and shows it; the Confirm button then moves, provided the robot has not moved since.
    ``confirm_moves=None`` (the default) follows ``robot.safety.mode`` at every click, so
    switching Safety to "confirm" after the panel is built takes effect at the next click;
    True or False fixes it. Planning in the panel replaces Safety's terminal prompt, which a
    widget callback cannot show: the kernel has no terminal to read (``input()`` there raises
    EOFError or StdinNotImplementedError). With ``confirm_moves=False`` and a Safety in
    "confirm" mode, Safety's own ``confirm`` callable asks, so give it one that works
    without a terminal. Messages give lengths in mm and angles in degrees, as the sliders do
    (see :func:`in_panel_units`).

    STOP calls ``robot.stop()`` and drops a planned move. Moves block the notebook kernel, so
    a STOP click during a jog is handled when that (short) jog ends; the jog buttons are
    disabled while a move runs so no clicks queue up. STOP is no substitute for the
    emergency stop on a real arm.

    ``speed`` is the jog speed (m/s). ``refresh_s`` (seconds; None turns it off) re-reads the
    pose on a timer on the notebook's event loop, between moves, never during one; outside a
    running event loop (a plain script) call :meth:`refresh` instead.
    """

    def __init__(self, cell, step_mm: float = 5.0, step_deg: float = 2.0, frame: str = "base",
                 speed: float = JOG_SPEED, confirm_moves: bool | None = None,
                 refresh_s: float | None = 0.5):
        widgets = _ipywidgets()
        self.robot = _robot_of(cell)
        if frame not in FRAMES:
            raise ValueError(f"frame must be 'base' or 'tool', got {frame!r}")
        step_mm = _parse_size(str(step_mm), _MAX_STEP_MM, "mm", "step_mm")
        step_deg = _parse_size(str(step_deg), _MAX_STEP_DEG, "deg", "step_deg")
        self.speed = _check_speed(speed)
        self._confirm_moves = None if confirm_moves is None else bool(confirm_moves)
        self.messages: list[str] = []
        self.pose_text = ""
        self._planned: _PlannedJog | None = None
        self._timer = RefreshTimer(self.refresh)

        self.step_mm = widgets.FloatSlider(
            value=step_mm, min=0.1, max=_MAX_STEP_MM, step=0.1, description="step (mm)",
            readout_format=".1f")
        self.step_deg = widgets.FloatSlider(
            value=step_deg, min=0.1, max=_MAX_STEP_DEG, step=0.1, description="step (deg)",
            readout_format=".1f")
        self.frame = widgets.ToggleButtons(
            options=list(FRAMES), value=frame, description="frame",
            tooltips=["axes of the robot base", "axes of the tool (TCP)"])
        self.axis_buttons = {}
        for axis in AXES:
            for sign, mark in ((-1, "\u2212"), (+1, "+")):
                button = widgets.Button(
                    description=f"{axis} {mark}", layout=widgets.Layout(width="70px"),
                    tooltip=f"{'turn' if axis.startswith('r') else 'move'} one step "
                            f"{'+' if sign > 0 else '-'}{axis[-1]}")
                button.on_click(lambda _button, a=axis, s=sign: self.jog(a, s))
                self.axis_buttons[(axis, sign)] = button
        self.stop_button = widgets.Button(
            description="STOP", button_style="danger", tooltip="robot.stop() now",
            layout=widgets.Layout(width="140px", height="70px"))
        self.stop_button.style.font_weight = "bold"
        self.stop_button.on_click(lambda _button: self.stop())
        self.confirm_button = widgets.Button(
            description="Confirm move", button_style="warning", disabled=True)
        self.confirm_button.on_click(lambda _button: self.confirm())
        self.cancel_button = widgets.Button(description="Cancel", disabled=True)
        self.cancel_button.on_click(lambda _button: self.cancel())
        self.readout = widgets.HTML()
        self.output = widgets.HTML()

        # Translation in the left pair of columns, rotation in the right pair.
        grid = widgets.GridBox(
            [self.axis_buttons[(a, s)] for row in (("x", "rx"), ("y", "ry"), ("z", "rz"))
             for a in row for s in (-1, 1)],
            layout=widgets.Layout(grid_template_columns="repeat(4, 75px)"))
        self.widget = widgets.VBox([
            widgets.HBox([self.step_mm, self.step_deg]),
            self.frame,
            widgets.HBox([grid, widgets.VBox(
                [self.stop_button, self.confirm_button, self.cancel_button])]),
            self.readout,
            self.output,
        ])
        self._show_confirm_controls()
        self.refresh()
        if refresh_s is not None:
            self.start_auto_refresh(refresh_s)

    @property
    def confirm_moves(self) -> bool:
        """Whether a jog button plans a move for Confirm (True) or moves at once (False)."""
        if self._confirm_moves is not None:
            return self._confirm_moves
        return self.robot.safety.mode == "confirm"

    @confirm_moves.setter
    def confirm_moves(self, value: bool | None) -> None:
        self._confirm_moves = None if value is None else bool(value)
        self._show_confirm_controls()

    def _show_confirm_controls(self) -> None:
        display = None if self.confirm_moves else "none"
        for button in (self.confirm_button, self.cancel_button):
            button.layout.display = display

    # ----- display

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)

    def _say(self, text: str, kind: str = "info") -> None:
        self.messages.append(text)
        colour = {"info": "inherit", "ok": "#1a7f37", "error": "#b42318"}[kind]
        recent = self.messages[-4:]
        rows = [f'<div style="color:{colour if i == len(recent) - 1 else "#666"}">'
                f"{html.escape(m)}</div>" for i, m in enumerate(recent)]
        self.output.value = "".join(rows)

    def _report(self, error: Exception) -> None:
        """Show an error from a move in plain words; stop the robot if it was unexpected."""
        text = in_panel_units(str(error))
        if isinstance(error, SafetyError):
            self._say(f"Refused, nothing moved: {text}", "error")
        elif isinstance(error, UnreachableError):
            self._say(f"Cannot reach that pose, nothing moved: {text}", "error")
        elif isinstance(error, RobotDisconnectedError):
            self._say(f"Robot disconnected: {text}", "error")
        elif isinstance(error, ValueError):
            self._say(f"Bad jog request: {text}", "error")
        else:
            self._stop_quietly()
            self._say(f"{type(error).__name__}: {text} (robot.stop() was called)", "error")

    def _stop_quietly(self) -> str | None:
        try:
            self.robot.stop()
        except Exception as error:  # report it in the panel; a widget callback cannot raise
            return str(error)
        return None

    def _set_busy(self, busy: bool) -> None:
        for button in self.axis_buttons.values():
            button.disabled = busy
        self.confirm_button.disabled = busy or self._planned is None
        self.cancel_button.disabled = busy or self._planned is None

    def refresh(self) -> bool:
        """Re-read the pose into the readout. Returns False once the robot is disconnected."""
        try:
            self.pose_text = format_pose(self.robot)
        except RobotDisconnectedError:
            self.pose_text = "robot disconnected"
            self.readout.value = f"<b>{self.pose_text}</b>"
            return False
        except Exception as error:  # a flaky read should not kill the panel
            self.readout.value = f"<i>pose read failed: {html.escape(str(error))}</i>"
            return True
        self.readout.value = (
            f"<pre style='margin:0'>{html.escape(self.pose_text)}</pre>"
            f"<small>base frame, {_RPY_NOTE}</small>")
        return True

    # ----- button actions

    def jog(self, axis: str, sign: int) -> None:
        """Jog ``axis`` (one of ``AXES``) by one step of the slider size; ``sign`` is +1 or -1.

        Moves at once, or in ``confirm_moves`` mode plans the move for :meth:`confirm`. Errors
        are shown in ``output``, never raised.
        """
        self._planned = None  # a new click replaces any planned jog
        self._set_busy(False)
        try:
            if sign not in (1, -1):
                raise ValueError(f"sign must be +1 or -1, got {sign!r}")
            frame = self.frame.value
            step = _step_value(axis, sign, self.step_mm.value, self.step_deg.value)
            description = _describe(axis, step, frame)
            start = self.robot.flange_pose()
            target = jog_target(start, axis, step, frame, _tcp_offset(self.robot))
            confirming = self.confirm_moves  # read now: Safety's mode may have changed
            self._show_confirm_controls()
            if confirming:
                # Check the limits now, so the operator is never asked about a refused move.
                auto = replace(self.robot.safety, mode="auto", confirm=None)
                auto.check_cartesian_move(start, target, self.speed, _tcp_offset(self.robot))
                self._planned = _PlannedJog(description, start, target)
                self._set_busy(False)  # enables Confirm / Cancel
                self._say(f"Planned: {description}. Click 'Confirm move' to move, or Cancel.")
                return
            self._move(target, description)
        except Exception as error:  # shown in plain words; a widget callback's error is lost
            self._report(error)

    def confirm(self) -> None:
        """Carry out the planned jog, if the robot is still where it was when it was planned."""
        planned, self._planned = self._planned, None
        self._set_busy(False)
        if planned is None:
            self._say("Nothing to confirm: click an axis button first.")
            return
        try:
            now = self.robot.flange_pose()
            if (translation_error(now, planned.start) > 1e-4
                    or rotation_error_deg(now, planned.start) > 0.01):
                self._say("Not moved: the robot moved since this jog was planned; "
                          "click the axis button again.", "error")
                return
            # The operator has just confirmed this exact move in the panel.
            with _confirm_each_move(self.robot.safety, lambda _message: True):
                self._move(planned.target, planned.description)
        except Exception as error:
            self._report(error)

    def cancel(self) -> None:
        """Drop the planned jog; nothing moves."""
        had_plan = self._planned is not None
        self._planned = None
        self._set_busy(False)
        self._say("Planned jog cancelled; nothing moved." if had_plan else "Nothing to cancel.")

    def stop(self) -> None:
        """STOP: call ``robot.stop()`` and drop any planned jog."""
        self._planned = None
        self._set_busy(False)
        failure = self._stop_quietly()
        if failure is None:
            self._say("STOP: robot.stop() sent.", "error")
        else:
            self._say(f"STOP FAILED ({failure}): use the emergency stop button.", "error")
        self.refresh()

    def _move(self, target: np.ndarray, description: str) -> None:
        self._set_busy(True)
        try:
            self.robot.move_to(target, self.speed)
        finally:
            self._set_busy(False)
            self.refresh()
        self._say(f"Moved: {description}.", "ok")

    # ----- timer

    @property
    def auto_refresh_running(self) -> bool:
        return self._timer.running

    def start_auto_refresh(self, period_s: float = 0.5) -> bool:
        """Re-read the pose every ``period_s`` seconds on the running event loop.

        Returns False (and does nothing) when no event loop is running, as in a plain script;
        in Jupyter the kernel's loop is running. The timer stops by itself once the robot is
        disconnected.
        """
        return self._timer.start(period_s)

    def stop_auto_refresh(self) -> None:
        self._timer.stop()

    def close(self) -> None:
        """Stop the timer and close the widgets (the robot stays connected)."""
        self.stop_auto_refresh()
        for widget in self._all_widgets():
            widget.close()

    def _all_widgets(self) -> list:
        boxes = [self.widget]
        found = []
        while boxes:
            widget = boxes.pop()
            found.append(widget)
            boxes.extend(getattr(widget, "children", ()))
        return found


def jog_panel(cell, **options) -> JogPanel:
    """Build a :class:`JogPanel` for ``cell``; put ``jog_panel(cell)`` last in a cell to show it.

    ``options`` are JogPanel's: ``step_mm``, ``step_deg``, ``frame``, ``speed`` (m/s),
    ``confirm_moves``, ``refresh_s``.
    """
    return JogPanel(cell, **options)
