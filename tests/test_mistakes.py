"""The classic-mistake detector names the mistake behind a wrong answer, and only that one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from autograder.mistakes import diagnose
from autograder.spec_types import mistake_answers


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

    hint = checks._mistake_hint(spec, value, trial)
    return None if hint is None else hint.words


def test_lab5_backproject_mistakes_are_named_with_holes_as_nan(lab5_specs):
    """The predictions carry NaN at the holes; an answer with NaN in the same places
    matches (mistakes.matches), so the depth scale, u/v and K mistakes are named."""
    spec = lab5_specs["backproject"]
    trial = spec.make_trial(np.random.default_rng(4), 1)
    raw, K, scale = trial.args
    for words, predicted in mistake_answers(spec, trial):
        assert _lab5_hint(spec, predicted, trial) == words
    assert _lab5_hint(spec, trial.truth, trial) is None or spec.measure(trial.truth, trial)
    names = [w for w, _ in mistake_answers(spec, trial)]
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
        found = [(w, v) for w, v in mistake_answers(spec, trial) if words in w]
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


# --------------------------------------------------------------------------- code mistakes


def _code_mistake_cases():
    from autograder import checks

    return [pytest.param(lab, spec.name, i, id=f"{spec.name}[{i}]")
            for lab, specs in checks.SPECS.items() for spec in specs
            for i in range(len(spec.code_mistakes))]


@pytest.mark.parametrize("lab, name, index", _code_mistake_cases())
def test_each_code_mistake_is_named_where_it_loses_credit(lab, name, index):
    """A student's answer equal to a spec's code mistake is named by the words of that
    mistake or of an earlier one giving the same answer there (src and dst swapped is, to
    the noise, the inverse fit). A closed loop's answer is the loop's measured errors."""
    from autograder import checks

    spec = checks.spec_for(name, lab)
    mistake = spec.code_mistakes[index]
    rng = np.random.default_rng(0)
    np.seterr(all="ignore")
    lost_elsewhere = False  # credit lost where nothing is compared: NaN out, no ValueError
    for i in range(3 * spec.n_trials):
        trial = spec.make_trial(rng, i)
        try:
            value = mistake.func(*trial.args) if spec.drive is None else \
                spec.drive(mistake.func, trial)
        except Exception:  # noqa: BLE001 - the call's error is the feedback there
            lost_elsewhere |= trial.raises is None
            continue
        if trial.raises is not None:
            lost_elsewhere = True  # "expected ValueError": the message says it all
            continue
        try:
            measured = spec.measure(value, trial)
        except checks.OutputError:
            lost_elsewhere = True  # NaN, a mirror image: the output check says why
            continue
        if all(measured[c.name] <= trial.tol[c.name] for c in spec.checks):
            continue
        labels = [m.label for m in spec.code_mistakes[:index + 1]]
        assert getattr(checks._mistake_hint(spec, value, trial), "words", None) in labels
        return
    assert lost_elsewhere, f"{lab}.{name}: no problem where {mistake.label!r} loses credit"


def _mm_fit_rigid(src, dst):
    """A student's Kabsch fit, right but for a translation in millimetres."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    if len(src) < 3 or np.linalg.matrix_rank(src - src.mean(axis=0), tol=1e-9) < 2:
        raise ValueError("degenerate point set")
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, 1000.0 * (dst.mean(axis=0) - R @ src.mean(axis=0))
    return T


def test_check_names_a_fit_rigid_in_millimetres_on_practice_data(tmp_path, monkeypatch):
    """Before the spec held code mistakes, check() said only "worst error 1.36e+06 mm"."""
    from autograder import checks, practice

    practice.write_practice("lab1_flange", tmp_path)
    monkeypatch.setenv(practice.ENV_DIR, str(tmp_path))
    assert practice.load_practice("lab1_flange").source.startswith(str(tmp_path))
    result = checks.evaluate(_mm_fit_rigid, "fit_rigid", assignment="lab1_flange")
    assert result.points < result.max_points
    named = [e for e in result.errors if "classic mistake" in e]
    assert named and "millimetres" in named[0], result.errors
