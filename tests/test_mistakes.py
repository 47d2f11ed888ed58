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


# --------------------------------------------------------------------------- lab 5


@pytest.fixture(scope="module")
def lab5_specs():
    from autograder import checks

    return {s.name: s for s in checks.SPECS["lab5_depth"]}


def _lab5_hint(spec, value, trial):
    from autograder import checks

    return checks._mistake_hint(spec, value, trial)


def test_lab5_backproject_mistakes_are_named_with_holes_as_nan(lab5_specs):
    """The predictions carry NaN at the holes; an answer with NaN in the same places
    matches (mistakes.matches), so the depth scale, u/v and K mistakes are named."""
    spec = lab5_specs["backproject"]
    trial = spec.make_trial(np.random.default_rng(4), 1)
    raw, K, scale = trial.args
    for words, predicted in spec.mistakes(trial):
        assert _lab5_hint(spec, predicted, trial) == words
    assert _lab5_hint(spec, trial.truth, trial) is None or spec.measure(trial.truth, trial)
    names = [w for w, _ in spec.mistakes(trial)]
    assert any("depth_scale" in w for w in names) and any("swapped" in w for w in names)
    assert any("focal length" in w for w in names) and any("NaN" in w for w in names)


def test_lab5_nan_placement_must_agree():
    from autograder.mistakes import matches

    a = np.array([[1.0, np.nan], [2.0, 3.0]])
    assert matches(a, a.copy())
    assert not matches(np.nan_to_num(a), a)      # a hole filled in is not the prediction
    assert not matches(a, np.nan_to_num(a))
    assert not matches(np.array([1.0, np.inf]), np.array([1.0, np.inf]))


@pytest.mark.parametrize("name, words", [
    ("fit_plane_ransac", "all the points"),
    ("fit_plane_ransac", "away from the camera"),
    ("fit_flange_circle", "Kasa"),
    ("fit_flange_circle", "away from the camera"),
    ("base_T_cam_from_flanges", "cam_T_base"),
    ("base_T_cam_from_flanges", "R^T"),
    ("rectangle_pose", "width and height are swapped"),
])
def test_lab5_classic_mistakes_are_named(lab5_specs, name, words):
    spec = lab5_specs[name]
    rng = np.random.default_rng(11)
    for index in range(12):
        trial = spec.make_trial(rng, index)
        found = [(w, v) for w, v in spec.mistakes(trial) if words in w]
        if not found:
            continue  # e.g. a square mark: width and height are the same
        w, predicted = found[0]
        measured = spec.measure(predicted, trial)
        if all(measured[c.name] <= trial.tol[c.name] for c in spec.checks):
            continue  # this problem does not tell the mistake apart (the score is full)
        assert _lab5_hint(spec, predicted, trial) == w
        return
    pytest.fail(f"no problem of {name} where {words!r} loses credit and is named")


def test_lab5_a_right_answer_is_given_no_mistake_name(lab5_specs):
    spec = lab5_specs["base_T_cam_from_flanges"]
    trial = spec.make_trial(np.random.default_rng(2), 0)
    assert _lab5_hint(spec, trial.truth, trial) is None
