"""Trivial answers (issue 38, item 1): what a student who computes nothing hands in, built
from the shapes of a problem alone (autograder/trivial.py), and the gate that scores them
with the grader's own scoring (autograder/fairness.py TrivialGate).

Toy specs only, a few dozen draws: the built-in labs' numbers are verify's (tests/
test_labs_verify.py runs the gate end to end on the skeleton lab).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from autograder import fairness
from autograder.spec_types import Check, CodeMistake, FunctionSpec, OutputError, Trial
from autograder.trivial import trivial_answers
from robots import geometry as geo


def _spec(name, measure, checks, parameters, drive=None, mistakes=()):
    return FunctionSpec(name=name, points=2.0, n_trials=6, make_trial=None, measure=measure,
                        checks=checks, signature=f"{name}({parameters})",
                        parameters=parameters, drive=drive, code_mistakes=mistakes)


def _named(answers) -> dict:
    return {a.name: a for a in answers}


def _pose(rng):
    return geo.make_pose(geo.rotation_from_rotvec(rng.normal(size=3)), rng.uniform(-1, 1, 3))


# --------------------------------------------------------------------------- the candidates


def test_a_pose_truth_gets_zeros_the_identity_and_its_input_echoed():
    rng = np.random.default_rng(0)
    a_T_b = _pose(rng)
    spec = _spec("invert", lambda v, t: {}, (), "a_T_b")
    trial = Trial(args=(a_T_b,), truth=np.linalg.inv(a_T_b), tol={})
    other = Trial(args=(_pose(rng),), truth=_pose(rng), tol={})
    answers = _named(trivial_answers(spec, trial, [other]))
    assert set(answers) == {"a_T_b echoed back", "identity pose", "zeros",
                            "truth of another problem"}
    np.testing.assert_array_equal(answers["identity pose"].value, np.eye(4))
    np.testing.assert_array_equal(answers["a_T_b echoed back"].value, a_T_b)
    assert answers["a_T_b echoed back"].value is not a_T_b   # a copy: scoring may not write in
    np.testing.assert_array_equal(answers["truth of another problem"].value, other.truth)
    assert np.all(answers["zeros"].value == 0) and answers["zeros"].value.shape == (4, 4)


def test_a_point_and_normal_truth_gets_the_median_point_with_a_constant_normal():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(40, 3))
    spec = _spec("fit_plane", lambda v, t: {}, (), "points, inlier_m, iterations=500")
    trial = Trial(args=(points, 0.01, 500), truth=(np.zeros(3), np.array([0.0, 0.0, -1.0])),
                  tol={})
    answers = _named(trivial_answers(spec, trial))
    combined = answers["(median of points, (0, 0, -1))"].value
    np.testing.assert_array_equal(combined[0], np.median(points, axis=0))
    np.testing.assert_array_equal(combined[1], [0.0, 0.0, -1.0])
    assert "(mean of points, (0, 0, 1))" in answers and "(zeros, zeros)" in answers
    # each part alone too: an answer may be one part of what the truth keeps
    assert {"median of points", "(0, 0, 1)", "zeros"} <= set(answers)
    # the scalar inputs are no 3-vector: never echoed as one
    assert not [n for n in answers if "inlier_m" in n or "iterations" in n]
    assert len(answers) <= 2 * 36 + 10


def test_a_pose_and_points_truth_offers_a_pose_answer_and_problems_that_must_raise():
    """fit_rigid's truth is (pose, the points measure maps), its answer a pose; a problem
    whose right answer is an exception makes raising on every problem a trivial answer."""
    rng = np.random.default_rng(2)
    src, dst = rng.normal(size=(8, 3)), rng.normal(size=(8, 3))
    spec = _spec("fit_rigid", lambda v, t: {}, (), "src, dst")
    trial = Trial(args=(src, dst), truth=(_pose(rng), src), tol={})
    degenerate = Trial(args=(src[:2], dst[:2]), truth=(_pose(rng), src[:2]), tol={},
                       raises="ValueError")
    answers = _named(trivial_answers(spec, trial, [degenerate]))
    assert "identity pose" in answers and "(identity pose, src echoed back)" in answers
    assert answers["raises ValueError on every problem"].raises == "ValueError"
    # the degenerate problem's truth is no answer to copy
    assert "truth of another problem" not in answers


def test_a_closed_loop_gets_laws_shaped_like_its_mistakes_answers():
    def drive(call, trial):
        velocity = np.asarray(call(trial.truth["s"], 1.5), dtype=float)
        return {"error": float(np.linalg.norm(velocity - trial.truth["v"]))}

    spec = _spec("law", lambda v, t: v, (Check("error", "", 1.0, ((1.0, 1.0),)),), "s, gain",
                 drive=drive, mistakes=(CodeMistake("no gain", lambda s, gain: -s[:6]),))
    trial = Trial(args=(), truth={"s": np.arange(8.0), "v": -1.5 * np.arange(6.0)},
                  tol={"error": 1e-6})
    answers = _named(trivial_answers(spec, trial))
    assert set(answers) == {"a law returning zeros"}
    np.testing.assert_array_equal(answers["a law returning zeros"].value(np.ones(8), 2.0),
                                  np.zeros(6))
    # without a mistake to show the law's output there is nothing trivial to try
    assert trivial_answers(replace(spec, code_mistakes=()), trial) == []


# --------------------------------------------------------------------------- the gate


def _angle(a, b):
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b)))


def _measure_normal(value, trial):
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or abs(np.linalg.norm(v) - 1) > 1e-3:
        raise OutputError("expected a unit normal (3,)")
    return {"normal": _angle(v, trial.truth)}


NORMAL_SPEC = _spec("plane_normal", _measure_normal,
                    (Check("normal", "deg", 1.0, ((1.0, 1.0), (3.0, 0.5))),), "points")


def _plane_trial(rng, tilt_deg, tol_deg):
    """A plane facing the camera, its normal tilted by ``tilt_deg`` (low, high) from
    (0, 0, -1)."""
    tilt = math.radians(rng.uniform(*tilt_deg))
    azimuth = rng.uniform(0, 2 * math.pi)
    normal = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth),
                       -math.cos(tilt)])
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    points = np.array([0, 0, 0.5]) + rng.uniform(-0.1, 0.1, (30, 1)) * u \
        + rng.uniform(-0.1, 0.1, (30, 1)) * w
    return Trial(args=(points,), truth=normal, tol={"normal": tol_deg})


def _gate(tilt_deg, tol_deg, draws=40):
    def make_trial(rng, index):
        return _plane_trial(rng, tilt_deg, tol_deg)

    spec = replace(NORMAL_SPEC, make_trial=make_trial)
    # student000123 -> seed 123: the same problems in every run
    return fairness.trivial_gate(spec, range(draws),
                                 lambda student: np.random.default_rng(int(student[-6:])))


def test_a_check_that_credits_a_constant_normal_fails_the_gate():
    """Planes tilted at most 20 deg from the optical axis, scored within 30 deg: the normal
    (0, 0, -1) earns full credit on every problem without looking at a point."""
    gate = _gate(tilt_deg=(0, 20), tol_deg=30)
    failing = gate.failing()
    assert failing and failing[0].answer == "(0, 0, -1)", [(s.answer, s.mean) for s in failing]
    assert failing[0].mean == 1.0 and failing[0].check == "normal"
    low, high = failing[0].interval()
    assert 0.9 < low <= 1.0 == high
    assert failing[0].typical_error("normal") < 20


def test_a_check_whose_tolerance_comes_from_the_noise_passes_the_gate():
    """Planes tilted 20 to 80 deg (drawn where a constant normal is far off), scored within
    2 deg: no trivial answer earns anything."""
    gate = _gate(tilt_deg=(20, 80), tol_deg=2, draws=60)
    assert gate.failing() == []
    best = gate.ranked()[0]
    assert best.mean <= fairness.TRIVIAL_LIMIT
    assert gate.draws == 60 and all(s.draws == 60 for s in gate.scores.values())
    assert fairness.mean_interval(0.0, 60)[1] == pytest.approx(
        fairness.clopper_pearson(0, 60)[1])


def test_the_interval_of_a_mean_share_brackets_it():
    low, high = fairness.mean_interval(12.5, 50)
    assert low < 12.5 / 50 < high
    assert fairness.mean_interval(50.0, 50) == (pytest.approx(
        fairness.clopper_pearson(50, 50)[0]), 1.0)
