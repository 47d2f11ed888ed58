"""A named mistake is the mistake that was made, and no trivial answer earns credit (issue 38).

* each mistake added for labs 1 and 3 is named with exactly its label on a hidden problem
  where it loses credit; a correct answer, a trivial answer and an answer between two
  mistakes' answers are named with nothing (autograder.mistakes.nearest);
* a check that ``requires`` another is worth nothing without it, and an edge case counts only
  when an ordinary problem is right, so a trivial answer earns nothing;
* a check within its tolerance but voided by another says so, never "outside the tolerance".
"""

from __future__ import annotations

import numpy as np
import pytest

from autograder import checks, feedback, mistakes
from autograder.outcomes import raised
from autograder.spec_types import MistakeName
from autograder.specs import lab1_flange as lab1
from autograder.specs import lab3_servoing as lab3

NEW_MISTAKES = [
    ("lab1_flange", "fit_rigid", lab1._fit_uncentred),
    ("lab3_servoing", "interaction_matrix", lab3._interaction_z_for_inverse),
    ("lab3_servoing", "ibvs_velocity", lab3._ibvs_error_stacked),
    ("lab3_servoing", "ibvs_velocity", lab3._ibvs_degrees),
    ("lab3_servoing", "ibvs_velocity", lab3._ibvs_w_first),
    ("lab3_servoing", "ibvs_velocity", lab3._ibvs_desired_l),
    ("lab3_servoing", "piece_position", lab3._piece_ray_length),
    ("lab3_servoing", "piece_position", lab3._piece_rows_columns),
    ("lab3_servoing", "piece_position", lab3._piece_window_mean),
]


def _answer(spec, func, trial):
    return spec.drive(func, trial) if spec.drive is not None else func(*trial.args)


def _ordinary_trials(spec, seed: int, n: int):
    rng = np.random.default_rng(seed)
    trials = [spec.make_trial(rng, i) for i in range(n)]
    return [t for t in trials if t.raises is None and not t.all_or_nothing]


@pytest.mark.parametrize("lab, name, func", NEW_MISTAKES,
                         ids=[f"{n}-{f.__name__}" for _, n, f in NEW_MISTAKES])
def test_each_new_mistake_is_named_with_exactly_its_label(lab, name, func):
    spec = checks.spec_for(name, lab)
    label = next(m.label for m in spec.code_mistakes if m.func is func)
    trial = _ordinary_trials(spec, 3, 6)[0]
    value = _answer(spec, func, trial)
    result = checks.score_function(spec, [trial], [checks.TrialOutcome(value=value)])
    assert result.fraction < 1.0, f"{func.__name__} kept full credit"
    assert checks._mistake_hint(spec, value, trial) == MistakeName(None, label)
    named = [e for e in result.errors if "classic mistake" in e]
    assert len(named) == 1 and label in named[0], result.errors



def test_without_hints_the_score_is_the_same_and_no_mistake_is_named():
    """``labs verify`` scores its draws with hints=False: the same points, checks and errors
    but for the classic-mistake line, which then is never computed."""
    spec = checks.spec_for("fit_rigid", "lab1_flange")
    trials = _ordinary_trials(spec, 3, 6)
    outcomes = [checks.TrialOutcome(value=lab1._fit_uncentred(*t.args)) for t in trials]
    named = checks.score_function(spec, trials, outcomes)
    plain = checks.score_function(spec, trials, outcomes, hints=False)
    assert any("classic mistake" in e for e in named.errors)
    assert not any("classic mistake" in e for e in plain.errors)
    assert (plain.points, plain.n_failed, plain.checks) == (named.points, named.n_failed,
                                                            named.checks)
    assert [e for e in named.errors if "classic mistake" not in e] == plain.errors

def test_a_diverging_servo_law_is_not_told_to_check_the_gain():
    """The issue's case: a stacked error vector, deg/s or (w, v) all failed with only "check
    the sign of the gain"; the describe words are neutral and the feedback names each."""
    spec = checks.spec_for("ibvs_velocity", "lab3_servoing")
    assert not any("sign of the gain" in c.describe for c in spec.checks)
    trial = _ordinary_trials(spec, 5, 2)[0]
    for func in (lab3._ibvs_error_stacked, lab3._ibvs_degrees, lab3._ibvs_w_first):
        hint = checks._mistake_hint(spec, _answer(spec, func, trial), trial)
        assert hint is not None and "gain" not in hint.words, (func.__name__, hint)


@pytest.mark.parametrize("lab, name", [("lab1_flange", "fit_rigid"),
                                       ("lab3_servoing", "interaction_matrix"),
                                       ("lab3_servoing", "piece_position"),
                                       ("lab2_handeye", "tsai_lenz")])
def test_a_correct_or_trivial_answer_is_named_with_nothing(lab, name):
    spec = checks.spec_for(name, lab)
    trial = _ordinary_trials(spec, 1, 6)[0]
    truth = checks._answer_truth(trial, None)
    trivial = np.eye(4) if np.shape(truth) == (4, 4) else np.zeros(np.shape(truth))
    assert checks._mistake_hint(spec, truth, trial) is None
    assert checks._mistake_hint(spec, trivial, trial) is None


def test_an_answer_between_two_mistakes_is_named_with_nothing():
    spec = checks.spec_for("interaction_matrix", "lab3_servoing")
    trial = _ordinary_trials(spec, 2, 6)[0]
    a = lab3._interaction_no_depth(*trial.args)
    b = lab3._interaction_z_for_inverse(*trial.args)
    assert checks._mistake_hint(spec, a, trial) != checks._mistake_hint(spec, b, trial)
    assert checks._mistake_hint(spec, (a + b) / 2, trial) is None
    # ... and one near one of them, within the noise (1e-4 of the entries' scale: the
    # tolerance times the widest band), is given its name
    labels = {m.func: m.label for m in spec.code_mistakes}
    near_b = b + 1e-6 * (a - b)
    assert checks._mistake_hint(spec, near_b, trial) == \
        MistakeName(None, labels[lab3._interaction_z_for_inverse])


def test_nearest_names_one_candidate_only_when_clearly_nearest():
    def distance(a, b):
        return abs(a - b)

    listed = [(None, 0.0), ("two", 2.0), ("three", 3.0)]
    assert mistakes.nearest(2.05, listed, distance, within=0.2) == "two"
    assert mistakes.nearest(2.5, listed, distance, within=1.0) is None   # between two
    assert mistakes.nearest(2.6, listed, distance, within=0.2) is None   # within no noise
    assert mistakes.nearest(0.01, listed, distance, within=0.2) is None  # the truth
    # the same answer listed twice is one candidate: the first label speaks for it
    assert mistakes.nearest(2.0, [(None, 0.0), ("a", 2.0), ("b", 2.0)], distance) == "a"


# --------------------------------------------------------------------------- trivial answers


def _pose(t=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, 3] = t
    return T


def _mean_fraction(spec, answer, seeds=range(3)):
    fractions = []
    for seed in seeds:
        trials = checks.make_trials(spec, np.random.default_rng(100 + seed))
        outcomes = [checks.TrialOutcome(value=answer(t)) if not isinstance(answer(t), Exception)
                    else checks.TrialOutcome(error=f"{type(answer(t)).__name__}: trivial",
                                             failure=raised(type(answer(t)).__name__))
                    for t in trials]
        fractions.append(checks.score_function(spec, trials, outcomes).fraction)
    return float(np.mean(fractions))


@pytest.mark.parametrize("lab, name, answer", [
    ("lab2_handeye", "tsai_lenz", lambda t: np.eye(4)),
    ("lab2_handeye", "axes_ls", lambda t: np.eye(4)),
    ("lab0_frames", "compose_chain", lambda t: np.asarray(t.args[0][0], dtype=float)),
    ("lab0_frames", "pose_from_rotvec", lambda t: _pose(t.args[1])),
    ("lab4_stereo", "frame_from_three_points", lambda t: _pose(t.args[0])),
    ("lab1_flange", "fit_rigid", lambda t: ValueError()),
], ids=["tsai-identity", "axes-identity", "chain-first-pose", "rotvec-identity-t",
        "frame-identity-origin", "fit-always-raises"])
def test_trivial_answers_earn_at_most_five_percent(lab, name, answer):
    """Before: 0.185, 0.185, 0.22, 0.31, 0.10 and 0.17 of the points."""
    spec = checks.spec_for(name, lab)
    assert _mean_fraction(spec, answer) <= 0.05


def test_a_translation_without_its_rotation_is_voided_and_the_feedback_says_why():
    spec = checks.spec_for("frame_from_three_points", "lab4_stereo")
    trials = _ordinary_trials(spec, 0, 6)
    result = checks.score_function(spec, trials,
                                   [checks.TrialOutcome(value=_pose(t.args[0])) for t in trials])
    translation = next(c for c in result.checks if c.name == "translation")
    assert result.points == 0 and translation.n_voided == len(trials)
    sentence = feedback._check_sentence(translation)
    assert "within the tolerance on every problem" in sentence
    assert "another check failed there" in sentence and "outside the tolerance" not in sentence


def test_the_all_or_nothing_sentence_says_the_check_passed_and_why_it_counts_as_failed():
    spec = checks.spec_for("pose_from_rotvec", "lab0_frames")
    rng = np.random.default_rng(0)
    trials = [spec.make_trial(rng, i) for i in range(8)]

    def wrong_translation(trial):
        T = np.array(trial.truth, dtype=float)
        if trial.all_or_nothing:
            T[:3, 3] += 0.5
        return checks.TrialOutcome(value=T)

    result = checks.score_function(spec, trials, [wrong_translation(t) for t in trials])
    rotation = next(c for c in result.checks if c.name == "rotation")
    assert rotation.n_voided == sum(t.all_or_nothing for t in trials) > 0
    assert rotation.worst_error < 1e-9
    sentence = feedback._check_sentence(rotation)
    assert "outside the tolerance" not in sentence
    assert "within the tolerance on every problem" in sentence
    assert "counted as failed: another check failed there" in sentence
    assert "outside the tolerance" not in result.summary().split("rotation:", 1)[1].split("\n")[0]


def test_an_edge_case_counts_once_the_method_is_right():
    """The gate takes nothing from a right method: the reference keeps full credit, and a
    method right on ordinary problems keeps its right answers to the edge cases."""
    spec = checks.spec_for("fit_rigid", "lab1_flange")
    trials = checks.make_trials(spec, np.random.default_rng(9))

    def reference(trial):
        try:
            return checks.TrialOutcome(value=lab1._kabsch(*trial.args))
        except ValueError as exc:
            return checks.TrialOutcome(error=f"ValueError: {exc}", failure=raised("ValueError"))

    assert checks.score_function(spec, trials, [reference(t) for t in trials]).fraction == 1.0
