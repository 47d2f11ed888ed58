"""The classic-mistake detector names the mistake behind a wrong answer, and only that one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from autograder.mistakes import diagnose


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


TRUTH = _pose([0.3, -0.5, 0.9], [0.21, -0.12, 0.43])


def _mirrored(T):
    out = T.copy()
    out[:3, 2] *= -1
    return out


@pytest.mark.parametrize("wrong, words", [
    (np.linalg.inv(TRUTH), "inverse"),
    (np.block([[TRUTH[:3, :3].T, TRUTH[:3, 3:]], [np.zeros((1, 3)), np.ones((1, 1))]]),
     "transpose"),
    (np.block([[TRUTH[:3, :3], 1000 * TRUTH[:3, 3:]], [np.zeros((1, 3)), np.ones((1, 1))]]),
     "millimetres"),
    (_pose(np.array([0.3, -0.5, 0.9]) * math.pi / 180, TRUTH[:3, 3]), "180/pi"),
    (_mirrored(TRUTH), "determinant -1"),
])
def test_each_classic_pose_mistake_is_named(wrong, words):
    hint = diagnose(wrong, TRUTH)
    assert hint is not None and words in hint, hint


def test_arrays_units_and_signs():
    truth = np.array([0.12, -0.4, 0.05])
    assert "millimetres" in diagnose(truth * 1000, truth)
    assert "degrees" in diagnose(np.degrees(truth), truth)
    assert "opposite sign" in diagnose(-truth, truth)
    M = np.arange(9.0).reshape(3, 3)
    assert "transpose" in diagnose(M.T, M)


def test_no_name_for_a_right_or_an_unrelated_answer():
    rng = np.random.default_rng(0)
    assert diagnose(TRUTH, TRUTH) is None
    for _ in range(200):  # unrelated wrong poses and arrays are not given a wrong name
        wrong = _pose(rng.normal(size=3), rng.uniform(-0.5, 0.5, 3))
        assert diagnose(wrong, TRUTH) is None
        assert diagnose(rng.normal(size=5), rng.normal(size=5)) is None
    assert diagnose("not numbers", TRUTH) is None
    assert diagnose(np.full((4, 4), np.nan), TRUTH) is None
    assert diagnose(np.eye(3), TRUTH) is None   # wrong shape: the shape check says so already
