"""Jogging (robots/jog.py) on the real PyBullet UR5e: pose math, console loop and notebook panel."""

import asyncio
import importlib.util
import math
import re

import numpy as np
import pytest

from robots import SafetyError, connect
from robots.geometry import make_pose, pose_from_rotvec, pose_from_rpy, rotation_error_deg
from robots.jog import (
    MAX_JOG_STEP_M,
    MAX_JOG_STEP_RAD,
    JogPanel,
    in_panel_units,
    jog,
    jog_panel,
    jog_step,
    jog_target,
    run_jog_console,
)

POS_TOL_M = 0.5e-3
ROT_TOL_DEG = 0.1
STEP_M = 0.005
STEP_RAD = math.radians(2.0)


@pytest.fixture
def cell():
    with connect("sim", arm="ur5e", seed=0, width=160, height=120) as c:
        yield c


@pytest.fixture
def pointer_cell():
    with connect("sim", arm="ur5e", seed=0, width=160, height=120, tool="pointer") as c:
        yield c


def spy_on_stop(monkeypatch, robot) -> list:
    """Record calls to robot.stop() and still run the real one."""
    calls = []
    real_stop = robot.stop

    def stop():
        calls.append(True)
        real_stop()

    monkeypatch.setattr(robot, "stop", stop)
    return calls


def unit(i):
    e = np.zeros(3)
    e[i] = 1.0
    return e


# --------------------------------------------------------------------------- pose math


def test_jog_target_base_and_tool_frames_by_hand():
    # Flange turned 90 deg about base z: its x axis is base +y, its y axis is base -x.
    T = make_pose(pose_from_rpy(0, 0, math.pi / 2)[:3, :3], [0.4, 0.1, 0.3])
    np.testing.assert_allclose(jog_target(T, "x", 0.01, "base")[:3, 3], [0.41, 0.1, 0.3])
    np.testing.assert_allclose(jog_target(T, "x", 0.01, "tool")[:3, 3], [0.4, 0.11, 0.3])
    np.testing.assert_allclose(jog_target(T, "y", -0.01, "tool")[:3, 3], [0.41, 0.1, 0.3])
    # Rotation about base z keeps the point, and composes on the left.
    Rz = pose_from_rotvec([0, 0, 0.1])
    out = jog_target(T, "rz", 0.1, "base")
    np.testing.assert_allclose(out[:3, 3], T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(out[:3, :3], Rz[:3, :3] @ T[:3, :3], atol=1e-12)
    # About tool x: composes on the right.
    out = jog_target(T, "rx", 0.1, "tool")
    np.testing.assert_allclose(out[:3, :3], T[:3, :3] @ pose_from_rotvec([0.1, 0, 0])[:3, :3],
                               atol=1e-12)


def test_jog_target_rotation_turns_about_the_tcp_not_the_flange():
    T = pose_from_rpy(math.pi, 0, 0, t=[0.5, 0.0, 0.4])  # flange pointing down
    flange_T_tcp = make_pose(t=[0, 0, 0.15])
    tip = (T @ flange_T_tcp)[:3, 3]
    for frame in ("base", "tool"):
        for axis in ("rx", "ry", "rz"):
            out = jog_target(T, axis, 0.1, frame, flange_T_tcp)
            np.testing.assert_allclose((out @ flange_T_tcp)[:3, 3], tip, atol=1e-12)
            assert rotation_error_deg(out, T) == pytest.approx(math.degrees(0.1))
    # The flange swings: 0.15 m * 2 sin(0.05) about the tip.
    moved = jog_target(T, "rx", 0.1, "base", flange_T_tcp)
    assert np.linalg.norm(moved[:3, 3] - T[:3, 3]) == pytest.approx(0.3 * math.sin(0.05))


@pytest.mark.parametrize("axis, step, frame, match", [
    ("w", 0.001, "base", "axis"),
    ("x", 0.001, "world", "frame"),
    ("x", float("nan"), "base", "finite"),
    ("x", 0.0, "base", "non-zero"),
    ("x", "five", "base", "number"),
    ("z", 5.0, "base", "metres"),  # 5 "mm" typed as metres
    ("z", MAX_JOG_STEP_M * 1.01, "tool", "jog limit"),
    ("rz", 2.0, "base", "radians"),  # 2 "deg" typed as radians
    ("ry", -MAX_JOG_STEP_RAD * 1.01, "tool", "jog limit"),
])
def test_jog_target_rejects_bad_input(axis, step, frame, match):
    with pytest.raises(ValueError, match=match):
        jog_target(np.eye(4), axis, step, frame)


def test_jog_target_rejects_bad_pose():
    bad = np.eye(4)
    bad[0, 0] = -1.0  # a reflection
    with pytest.raises(ValueError):
        jog_target(bad, "x", 0.001)


# --------------------------------------------------------------------------- moving the sim arm


@pytest.mark.parametrize("frame", ["base", "tool"])
def test_translation_jog_moves_exactly_one_step(cell, frame):
    robot = cell.robot
    for i, axis in enumerate("xyz"):
        for sign in (1, -1):
            before = robot.flange_pose()
            target = jog_step(robot, axis, sign * STEP_M, frame)
            after = jog(robot, axis, sign * STEP_M, frame)
            direction = unit(i) if frame == "base" else before[:3, :3] @ unit(i)
            expected = before[:3, 3] + sign * STEP_M * direction
            assert np.linalg.norm(after[:3, 3] - expected) < POS_TOL_M
            assert rotation_error_deg(after, before) < ROT_TOL_DEG
            np.testing.assert_allclose(after, robot.flange_pose())
            assert np.linalg.norm(target[:3, 3] - expected) < 1e-9


@pytest.mark.parametrize("frame", ["base", "tool"])
def test_rotation_jog_turns_exactly_one_step(cell, frame):
    robot = cell.robot
    for i, axis in enumerate(("rx", "ry", "rz")):
        for sign in (1, -1):
            before = robot.flange_pose()
            after = jog(robot, axis, sign * STEP_RAD, frame)
            turn = pose_from_rotvec(sign * STEP_RAD * unit(i))[:3, :3]
            expected = turn @ before[:3, :3] if frame == "base" else before[:3, :3] @ turn
            assert rotation_error_deg(after[:3, :3], expected) < ROT_TOL_DEG
            assert np.linalg.norm(after[:3, 3] - before[:3, 3]) < POS_TOL_M  # no tool: TCP = flange


def test_tool_frame_rotation_keeps_the_pointer_tip_still(pointer_cell):
    robot = pointer_cell.robot
    tip_before, flange_before = robot.tcp_pose(), robot.flange_pose()
    jog(robot, "rx", STEP_RAD, "tool")
    tip_after = robot.tcp_pose()
    assert np.linalg.norm(tip_after[:3, 3] - tip_before[:3, 3]) < POS_TOL_M
    assert rotation_error_deg(tip_after, tip_before) == pytest.approx(2.0, abs=ROT_TOL_DEG)
    # The flange, 150 mm up the pointer, swings by about 150 mm * 2 deg.
    swing = np.linalg.norm(robot.flange_pose()[:3, 3] - flange_before[:3, 3])
    assert swing == pytest.approx(0.150 * STEP_RAD, rel=0.01)


def test_jog_out_of_the_workspace_is_refused_and_nothing_moves(cell):
    robot = cell.robot
    before = robot.flange_pose()
    robot.safety.workspace_max = np.array([1.0, 1.0, before[2, 3] + 0.002])
    with pytest.raises(SafetyError, match="workspace"):
        jog(robot, "z", STEP_M)
    np.testing.assert_array_equal(robot.flange_pose(), before)
    jog(robot, "z", -STEP_M)  # away from the limit is fine
    assert robot.flange_pose()[2, 3] == pytest.approx(before[2, 3] - STEP_M, abs=POS_TOL_M)


def test_jog_respects_the_speed_cap(cell):
    before = cell.robot.flange_pose()
    with pytest.raises(SafetyError, match="speed"):
        jog(cell, "x", STEP_M, speed=1.0)
    np.testing.assert_array_equal(cell.robot.flange_pose(), before)


# --------------------------------------------------------------------------- console


class Script:
    """Scripted operator: answers prompts in order, then raises EOFError (Ctrl-D)."""

    def __init__(self, *answers):
        self.answers = list(answers)
        self.prompts = []
        self.lines = []

    def read(self, prompt):
        self.prompts.append(prompt)
        if not self.answers:
            raise EOFError
        answer = self.answers.pop(0)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    def write(self, text):
        self.lines.append(str(text))

    @property
    def text(self):
        return "\n".join(self.lines)


def test_console_confirms_every_move_even_in_auto_mode(cell):
    robot = cell.robot
    assert robot.safety.mode == "auto"
    before = robot.flange_pose()
    script = Script("x+", "y", "x+", "n", "q")
    moves = run_jog_console(cell, read=script.read, write=script.write)
    assert moves == 1
    after = robot.flange_pose()
    assert np.linalg.norm(after[:3, 3] - (before[:3, 3] + [STEP_M, 0, 0])) < POS_TOL_M
    assert script.prompts.count("Move? [y/N] ") == 2
    assert "from x=" in script.text and "to   x=" in script.text
    assert "you answered no" in script.text
    assert robot.safety.mode == "auto" and robot.safety.confirm is None


def test_console_step_size_is_capped_and_changeable(cell):
    robot = cell.robot
    before = robot.flange_pose()
    script = Script("step 50", "rstep 45", "step 2", "z-", "y", "frame tool", "rstep 3",
                    "rz+", "yes", "q")
    assert run_jog_console(cell, read=script.read, write=script.write) == 2
    assert "at most 20 mm" in script.text and "at most 10 deg" in script.text
    after = robot.flange_pose()
    assert after[2, 3] == pytest.approx(before[2, 3] - 0.002, abs=POS_TOL_M)
    turn = pose_from_rotvec([0, 0, math.radians(3)])[:3, :3]
    assert rotation_error_deg(after[:3, :3], before[:3, :3] @ turn) < ROT_TOL_DEG
    with pytest.raises(ValueError, match="at most 20 mm"):
        run_jog_console(cell, read=script.read, write=script.write, step_mm=25)


def test_console_reports_a_refused_move_without_asking(cell):
    robot = cell.robot
    before = robot.flange_pose()
    robot.safety.workspace_min = np.array([-1.0, -1.0, before[2, 3] - 0.001])
    script = Script("z-", "q")  # no answer scripted: a prompt would read "q" and refuse
    assert run_jog_console(cell, read=script.read, write=script.write) == 0
    assert "refused" in script.text and "workspace floor" in script.text
    assert "Move? [y/N] " not in script.prompts
    np.testing.assert_array_equal(robot.flange_pose(), before)


def test_console_uses_its_own_prompt_in_confirm_mode_and_restores_safety(cell):
    robot = cell.robot

    def never(message):
        raise AssertionError("the console must ask through read(), not Safety.confirm")

    robot.safety.mode, robot.safety.confirm = "confirm", never
    script = Script("y+", "y", "q")
    assert run_jog_console(cell, read=script.read, write=script.write) == 1
    assert robot.safety.mode == "confirm" and robot.safety.confirm is never


@pytest.mark.parametrize("ending", [EOFError(), KeyboardInterrupt()], ids=["eof", "ctrl-c"])
def test_console_end_of_input_and_ctrl_c_stop_and_exit(cell, monkeypatch, ending):
    stops = spy_on_stop(monkeypatch, cell.robot)
    before = cell.robot.flange_pose()
    script = Script("p", ending)
    assert run_jog_console(cell, read=script.read, write=script.write) == 0
    assert stops == [True]
    assert "robot stopped" in script.lines[-1]
    np.testing.assert_array_equal(cell.robot.flange_pose(), before)


def test_console_eof_at_the_confirmation_prompt_moves_nothing(cell, monkeypatch):
    stops = spy_on_stop(monkeypatch, cell.robot)
    before = cell.robot.flange_pose()
    script = Script("x+")  # then EOF while asked "Move? [y/N]"
    assert run_jog_console(cell, read=script.read, write=script.write) == 0
    assert script.prompts[-1] == "Move? [y/N] "
    assert stops == [True]
    np.testing.assert_array_equal(cell.robot.flange_pose(), before)
    assert cell.robot.safety.mode == "auto"


# --------------------------------------------------------------------------- notebook panel

# robots.jog imports ipywidgets only when a panel is built; the panel tests need it.
needs_ipywidgets = pytest.mark.skipif(
    importlib.util.find_spec("ipywidgets") is None,
    reason="the jog panel needs ipywidgets (the course/dev extra)")


@needs_ipywidgets
def test_panel_buttons_move_and_update_the_readout(cell):
    robot = cell.robot
    panel = jog_panel(cell, refresh_s=None)
    assert not panel.confirm_moves
    before = robot.flange_pose()
    assert f"{before[0, 3] * 1000:8.1f}" in panel.readout.value

    panel.axis_buttons[("x", 1)].click()
    after = robot.flange_pose()
    assert np.linalg.norm(after[:3, 3] - (before[:3, 3] + [STEP_M, 0, 0])) < POS_TOL_M
    assert f"x {after[0, 3] * 1000:8.1f}" in panel.readout.value
    assert "Moved: jog x +5 mm in the base frame" in panel.output.value

    panel.frame.value = "tool"
    panel.step_mm.value = 2.0
    panel.jog("y", -1)
    expected = after[:3, 3] - 0.002 * after[:3, :3] @ unit(1)
    assert np.linalg.norm(robot.flange_pose()[:3, 3] - expected) < POS_TOL_M

    panel.step_deg.value = 3.0
    start = robot.flange_pose()
    panel.axis_buttons[("rz", -1)].click()
    turn = pose_from_rotvec([0, 0, -math.radians(3)])[:3, :3]
    assert rotation_error_deg(robot.flange_pose()[:3, :3], start[:3, :3] @ turn) < ROT_TOL_DEG
    assert panel.step_mm.max == 20 and panel.step_deg.max == 10  # sliders cannot exceed the cap


@needs_ipywidgets
def test_panel_shows_a_refused_move_in_plain_words(cell):
    robot = cell.robot
    panel = JogPanel(cell, refresh_s=None)
    before = robot.flange_pose()
    robot.safety.workspace_max = np.array([1.0, 1.0, before[2, 3] + 0.001])
    panel.jog("z", +1)  # must not raise
    np.testing.assert_array_equal(robot.flange_pose(), before)
    assert "Refused, nothing moved" in panel.output.value
    assert "workspace" in panel.output.value and "Traceback" not in panel.output.value
    assert not any(b.disabled for b in panel.axis_buttons.values())


@needs_ipywidgets
def test_panel_disables_jog_buttons_while_a_move_runs(cell, monkeypatch):
    robot = cell.robot
    panel = JogPanel(cell, refresh_s=None)
    seen = []
    real_move = robot._move_to

    def watching_move(target, speed):
        seen.append(all(b.disabled for b in panel.axis_buttons.values()))
        real_move(target, speed)

    monkeypatch.setattr(robot, "_move_to", watching_move)
    panel.jog("x", -1)
    assert seen == [True]
    assert not any(b.disabled for b in panel.axis_buttons.values())


@needs_ipywidgets
def test_panel_stop_button_calls_stop(cell, monkeypatch):
    stops = spy_on_stop(monkeypatch, cell.robot)
    panel = JogPanel(cell, refresh_s=None)
    panel.stop_button.click()
    assert stops == [True]
    assert "STOP" in panel.output.value


@needs_ipywidgets
def test_panel_in_confirm_mode_plans_then_moves_on_confirm(cell):
    robot = cell.robot

    def refuse(message):  # the panel must confirm through its own buttons, not this
        return False

    robot.safety.mode, robot.safety.confirm = "confirm", refuse
    panel = JogPanel(cell, refresh_s=None)
    assert panel.confirm_moves and panel.confirm_button.disabled
    before = robot.flange_pose()

    panel.axis_buttons[("y", 1)].click()
    np.testing.assert_array_equal(robot.flange_pose(), before)
    assert "Planned: jog y +5 mm" in panel.output.value and not panel.confirm_button.disabled
    panel.confirm_button.click()
    moved = robot.flange_pose()
    assert np.linalg.norm(moved[:3, 3] - (before[:3, 3] + [0, STEP_M, 0])) < POS_TOL_M
    assert robot.safety.mode == "confirm" and robot.safety.confirm is refuse
    assert panel.confirm_button.disabled

    panel.jog("y", 1)
    panel.cancel_button.click()
    panel.confirm()
    assert "Nothing to confirm" in panel.output.value
    np.testing.assert_array_equal(robot.flange_pose(), moved)

    # A plan made before the robot moved elsewhere is stale.
    panel.jog("y", 1)
    robot.safety.confirm = lambda message: True
    robot.move_to(jog_step(robot, "z", -STEP_M), 0.05)
    moved_elsewhere = robot.flange_pose()
    panel.confirm()
    assert "moved since this jog was planned" in panel.output.value
    np.testing.assert_array_equal(robot.flange_pose(), moved_elsewhere)

    # A refused move is reported at planning time, before anyone is asked.
    robot.safety.workspace_max = np.array([1.0, moved_elsewhere[1, 3] + 0.001, 1.3])
    panel.jog("y", 1)
    assert "Refused, nothing moved" in panel.output.value and panel.confirm_button.disabled


@needs_ipywidgets
def test_panel_reports_a_disconnected_robot(cell):
    panel = JogPanel(cell, refresh_s=None)
    cell.close()
    assert panel.refresh() is False
    assert "disconnected" in panel.readout.value
    panel.jog("x", 1)
    assert "Robot disconnected" in panel.output.value


@needs_ipywidgets
def test_panel_timer_refreshes_the_readout_on_the_event_loop(cell):
    robot = cell.robot
    no_loop = JogPanel(cell, refresh_s=0.5)  # plain script: no loop, no timer, no error
    assert not no_loop.auto_refresh_running

    async def scenario():
        panel = JogPanel(cell, refresh_s=0.02)
        assert panel.auto_refresh_running
        robot.move_to(jog_step(robot, "x", -0.01), 0.05)  # moved behind the panel's back
        new_x = f"x {robot.flange_pose()[0, 3] * 1000:8.1f}"
        assert new_x not in panel.readout.value
        for _ in range(50):
            await asyncio.sleep(0.02)
            if new_x in panel.readout.value:
                break
        assert new_x in panel.readout.value
        panel.close()
        assert not panel.auto_refresh_running

    asyncio.run(scenario())


@needs_ipywidgets
def test_panel_follows_safety_switched_to_confirm_after_it_was_built(cell, monkeypatch):
    """Issue 15: a widget callback has no terminal, so Safety's y/N prompt raised EOFError."""
    import io
    import sys

    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # a kernel's stdin: input() hits EOF
    robot = cell.robot
    panel = JogPanel(cell, refresh_s=None)
    assert not panel.confirm_moves and panel.confirm_button.layout.display == "none"
    robot.safety.mode = "confirm"  # Safety's own confirm is the terminal prompt (None)
    before = robot.flange_pose()

    panel.axis_buttons[("x", -1)].click()
    assert "EOFError" not in panel.output.value
    np.testing.assert_array_equal(robot.flange_pose(), before)
    assert "Planned: jog x -5 mm" in panel.output.value
    assert panel.confirm_button.layout.display != "none" and not panel.confirm_button.disabled
    panel.confirm_button.click()
    moved = robot.flange_pose()
    assert np.linalg.norm(moved[:3, 3] - (before[:3, 3] - [STEP_M, 0, 0])) < POS_TOL_M
    assert robot.safety.mode == "confirm" and robot.safety.confirm is None

    panel.jog("x", -1)
    panel.cancel_button.click()
    np.testing.assert_array_equal(robot.flange_pose(), moved)
    assert "cancelled; nothing moved" in panel.output.value

    robot.safety.mode = "auto"  # and back: the next click moves at once again
    panel.jog("x", 1)
    assert "Moved: jog x +5 mm" in panel.output.value
    assert panel.confirm_button.layout.display == "none"


@needs_ipywidgets
def test_panel_refusals_speak_mm_and_degrees(cell):
    robot = cell.robot
    panel = JogPanel(cell, refresh_s=None)
    z = robot.flange_pose()[2, 3]
    robot.safety.workspace_max = np.array([1.0, 1.0, z + 0.001])
    panel.jog("z", +1)
    message = panel.output.value
    assert f"z={(z + STEP_M) * 1000:.1f} mm" in message, message
    assert f"workspace limit {(z + 0.001) * 1000:.1f} mm" in message, message
    assert not re.search(r"\d m\b", message), message
    assert "set in metres" in message  # the setting's own unit, for whoever widens it

    robot.safety.workspace_max = np.array([1.0, 1.0, 1.3])
    robot.safety.max_step = 0.004
    panel.jog("y", 1)
    assert "a single move of 5.0 mm exceeds Safety.max_step=4.0 mm" in panel.output.value


def test_in_panel_units_converts_only_quantities_with_si_units():
    assert in_panel_units("target flange x=0.4010 m is beyond 0.4000 m") == (
        "target flange x=401.0 mm is beyond 400.0 mm")
    assert in_panel_units("speed 0.300 m/s is too fast").startswith("speed 300.0 mm/s")
    assert in_panel_units("turn 0.5 rad") == "turn 28.65 deg"
    joint = "joint 0 target +3.1000 rad (+177.6 deg) is outside its limits"
    assert in_panel_units(joint) == joint  # degrees already given beside it
    assert in_panel_units("no units here: 5 mm, 2 deg, tool0") == "no units here: 5 mm, 2 deg, tool0"
