"""The OpenCV wrappers speak our conventions: exact recovery of X (and Y) at zero noise."""

import numpy as np
import pytest

from autograder.synthetic import make_hand_eye, make_opencv_scenario
from robots import geometry as geo
from solutions.opencv_baseline import (
    HAND_EYE_METHODS,
    ROBOT_WORLD_METHODS,
    opencv_hand_eye,
    opencv_robot_world,
)


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("method", sorted(HAND_EYE_METHODS))
def test_calibrate_hand_eye_recovers_x(mount, method):
    p = make_hand_eye(0, mount, n_poses=10)
    X = opencv_hand_eye(p.base_T_flange, p.cam_T_target, mount, method)
    assert geo.rotation_error_deg(X, p.X_true) < 1e-8
    assert geo.translation_error(X, p.X_true) < 1e-9


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("method", sorted(ROBOT_WORLD_METHODS))
def test_robot_world_recovers_x_and_y(mount, method):
    p = make_opencv_scenario(1, mount, noise=False)
    X, Y = opencv_robot_world(p.base_T_flange, p.cam_T_target, mount, method)
    assert geo.rotation_error_deg(X, p.X_true) < 1e-8
    assert geo.translation_error(Y, p.Y_true) < 1e-8


def test_wrong_mount_is_named():
    p = make_hand_eye(0)
    with pytest.raises(ValueError, match="mount"):
        opencv_hand_eye(p.base_T_flange, p.cam_T_target, "eye_on_base")


def test_swapping_the_convention_gives_a_different_answer():
    # The inversion in opencv_hand_eye is load-bearing: feeding the eye-in-hand data as if it
    # were eye-to-hand must not recover the truth.
    # OpenCV then answers a reflection (PARK) or a wrong pose; a reflection is refused by name.
    p = make_hand_eye(0, "eye_in_hand", n_poses=10)
    try:
        X = opencv_hand_eye(p.base_T_flange, p.cam_T_target, "eye_to_hand", "PARK")
    except ValueError as exc:
        assert "not a rotation" in str(exc) and "PARK" in str(exc), exc
        return
    assert geo.translation_error(X, p.X_true) > 0.01 or geo.rotation_error_deg(X, p.X_true) > 1
    assert np.isfinite(X).all()
