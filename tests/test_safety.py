"""Safety limits: every violation is refused with a message naming the limit and the fix."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robots import Safety, SafetyError
from robots.geometry import make_pose, pose_from_rotvec

DOWN = np.diag([1.0, -1.0, -1.0])  # flange z pointing at the table


def at(x, y, z, R=DOWN):
    return make_pose(R, [x, y, z])


def test_defaults_are_conservative_and_allow_a_normal_move():
    s = Safety()
    assert s.max_speed <= 0.25 and s.max_step <= 0.5
    s.check_cartesian_move(at(0.4, 0.0, 0.4), at(0.45, 0.05, 0.35), 0.1)
    s.check_joint_move(np.zeros(6), np.full(6, 0.2), 0.5)


def test_below_floor_names_the_value_the_limit_and_the_fix():
    with pytest.raises(SafetyError) as info:
        Safety().check_cartesian_move(at(0.4, 0, 0.1), at(0.4, 0, -0.05), 0.1)
    msg = str(info.value)
    assert "z=-0.0500 m" in msg and "floor 0.0100 m" in msg
    assert "workspace_min" in msg and "raise the target" in msg


def test_the_tcp_must_stay_in_the_box_too():
    s = Safety()
    flange = at(0.4, 0.0, 0.08)
    s.check_cartesian_move(at(0.4, 0, 0.2), flange, 0.1)  # flange alone is fine
    tool = make_pose(t=[0, 0, 0.1])  # 10 cm tool along flange z, i.e. downwards
    with pytest.raises(SafetyError, match="TCP z=-0.0200 m"):
        s.check_cartesian_move(at(0.4, 0, 0.2), flange, 0.1, flange_T_tcp=tool)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_beyond_the_box_on_each_axis(axis):
    s = Safety()
    target = at(0.3, 0.0, 0.4)
    target[axis, 3] = s.workspace_max[axis] + 0.01
    current = target.copy()
    current[axis, 3] -= 0.05
    with pytest.raises(
        SafetyError, match=rf"{'xyz'[axis]}=.* beyond .*Safety.workspace_max\[{axis}\]"
    ):
        s.check_cartesian_move(current, target, 0.1)


def test_speed_cap():
    with pytest.raises(SafetyError, match=r"0\.500 m/s exceeds .*max_speed=0\.250"):
        Safety().check_cartesian_move(at(0.4, 0, 0.4), at(0.41, 0, 0.4), 0.5)
    with pytest.raises(SafetyError, match="max_joint_speed"):
        Safety().check_joint_move(np.zeros(6), np.full(6, 0.1), 2.0)


def test_step_limits_catch_a_millimetre_typo():
    # 400 "metres" instead of 0.4: clipped by the box first, so use a target 0.6 m away.
    with pytest.raises(SafetyError, match="max_step.*waypoints.*millimetres"):
        Safety().check_cartesian_move(at(-0.3, 0, 0.4), at(0.3, 0.0, 0.5), 0.1)
    turned = at(0.4, 0, 0.4) @ pose_from_rotvec([0, 0, np.radians(100)])
    with pytest.raises(SafetyError, match=r"100\.0 deg.*max_rotation_step=90\.0 deg"):
        Safety().check_cartesian_move(at(0.4, 0, 0.4), turned, 0.1)
    with pytest.raises(SafetyError, match=r"joint 2 would move 2\.000 rad"):
        Safety().check_joint_move(np.zeros(6), np.array([0, 0, 2.0, 0, 0, 0]), 0.5)


def test_joint_limits_tighter_of_safety_and_robot_wins():
    robot_limits = np.tile([-3.0, 3.0], (6, 1))
    s = Safety(joint_limits=np.tile([-1.0, 1.0], (6, 1)))
    s.check_joint_move(np.zeros(6), np.full(6, 0.9), 0.5, robot_limits=robot_limits)
    with pytest.raises(SafetyError, match=r"joint 4 target \+1\.2000 rad.*\[-1\.0000, \+1\.0000\]"):
        s.check_joint_move(
            np.zeros(6), np.array([0, 0, 0, 0, 1.2, 0]), 0.5, robot_limits=robot_limits
        )
    narrow_robot = robot_limits.copy()
    narrow_robot[1] = [-0.5, 0.5]
    with pytest.raises(SafetyError, match="joint 1"):
        s.check_joint_move(
            np.zeros(6), np.array([0, 0.7, 0, 0, 0, 0]), 0.5, robot_limits=narrow_robot
        )


def test_a_robot_outside_the_box_may_move_back_in():
    Safety().check_cartesian_move(at(0.4, 0, 0.005), at(0.4, 0, 0.05), 0.05)


def test_malformed_targets_are_value_errors_not_safety_errors():
    s = Safety()
    bad = at(0.4, 0, 0.4)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        s.check_cartesian_move(at(0.4, 0, 0.4), bad, 0.1)
    with pytest.raises(ValueError, match="reflection"):
        s.check_cartesian_move(at(0.4, 0, 0.4), at(0.4, 0, 0.4) @ np.diag([1, 1, -1, 1.0]), 0.1)
    with pytest.raises(ValueError, match="target q\\[3\\]"):
        s.check_joint_move(np.zeros(6), np.array([0, 0, 0, np.nan, 0, 0]), 0.5)
    with pytest.raises(ValueError, match="shape"):
        s.check_joint_move(np.zeros(6), np.zeros(5), 0.5)
    with pytest.raises(ValueError, match="positive"):
        s.check_cartesian_move(at(0.4, 0, 0.4), at(0.4, 0, 0.4), 0.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"workspace_min": [0, 0, 0.5], "workspace_max": [1, 1, 0.4]}, "empty along z"),
        ({"max_speed": -0.1}, "max_speed"),
        ({"max_step": np.nan}, "max_step"),
        ({"mode": "yolo"}, "mode"),
        ({"joint_limits": np.zeros((6, 3))}, r"\(n, 2\)"),
        ({"joint_limits": [[1.0, -1.0]]}, "lower"),
        ({"workspace_min": [0, 0]}, "3 finite numbers"),
    ],
)
def test_malformed_settings_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Safety(**kwargs)


def test_limits_edited_in_place_are_validated_at_the_next_check():
    s = Safety()
    s.max_speed = -1.0
    with pytest.raises(ValueError, match="max_speed"):
        s.check_cartesian_move(at(0.4, 0, 0.4), at(0.41, 0, 0.4), 0.1)
    s.max_speed = 0.05
    with pytest.raises(SafetyError, match="max_speed=0.050"):
        s.check_cartesian_move(at(0.4, 0, 0.4), at(0.41, 0, 0.4), 0.1)


def test_confirm_mode_shows_the_move_in_mm_and_degrees_and_obeys_the_answer():
    seen = []
    s = Safety(mode="confirm", confirm=lambda msg: seen.append(msg) or True)
    target = at(0.45, 0.0, 0.4) @ pose_from_rotvec([0, 0, np.radians(20)])
    s.check_cartesian_move(at(0.4, 0, 0.4), target, 0.1)
    assert "50.0 mm, 20.0 deg" in seen[0] and "100 mm/s" in seen[0]
    assert "x=400.0 y=0.0 z=400.0 mm" in seen[0] and "x=450.0" in seen[0]
    s.confirm = lambda msg: False
    with pytest.raises(SafetyError, match="refused by the operator"):
        s.check_cartesian_move(at(0.4, 0, 0.4), target, 0.1)
    with pytest.raises(SafetyError, match="refused"):
        s.check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)


def test_confirm_is_asked_only_after_the_checks_pass():
    asked = []
    s = Safety(mode="confirm", confirm=lambda msg: asked.append(msg) or True)
    with pytest.raises(SafetyError, match="floor"):
        s.check_cartesian_move(at(0.4, 0, 0.4), at(0.4, 0, -0.1), 0.1)
    assert asked == []


def test_default_confirmation_reads_the_terminal(monkeypatch):
    answers = iter(["yes", "n"])
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    s = Safety(mode="confirm")
    s.check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)
    with pytest.raises(SafetyError, match="refused"):
        s.check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)


coords = st.floats(-0.9, 0.9)


@settings(max_examples=60, deadline=None)
@given(x=coords, y=coords, z=st.floats(0.02, 1.2), dx=st.floats(-0.2, 0.2), dz=st.floats(-0.2, 0.2))
def test_targets_inside_pass_and_outside_fail(x, y, z, dx, dz):
    s = Safety()
    target = at(x, y, z)
    current = at(x - dx, y, z - dz)
    s.check_cartesian_move(current, target, 0.2)
    outside = at(x, y, s.workspace_min[2] - 0.001 - abs(dz))
    with pytest.raises(SafetyError, match="floor"):
        s.check_cartesian_move(at(x, y, 0.1), outside, 0.2)



def test_safety_and_interfaces_do_not_import_each_other():
    # robots.interfaces uses Safety; if robots.safety imported robots.interfaces back (it once
    # did, for SafetyError), the two modules would form an import circle that breaks as soon
    # as either moves an import to the top of the file.
    import robots.interfaces
    import robots.safety

    assert "robots.interfaces" not in _module_imports(robots.safety)
    assert "robots.safety" in _module_imports(robots.interfaces)
    assert robots.interfaces.SafetyError is robots.safety.SafetyError is SafetyError


def _module_imports(module) -> set[str]:
    """Every module name an ``import`` statement anywhere in ``module``'s source names."""
    import ast
    import inspect

    names = set()
    for node in ast.walk(ast.parse(inspect.getsource(module))):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return names
