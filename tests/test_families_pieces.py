"""Units and the inverse named where the answer failed a validity check first (issue 52,
Required 2): a 4x4 whose last row is no pose's, a rotation block that is no rotation or
holds NaN beside a translation in millimetres, a circle's centre in millimetres beside a
normal that is not a unit vector. Each is named on what of it can be compared
(``autograder.families.pieces``), through the path check() uses, and the grader's scoring
names it too; what is not nearest stays unnamed.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_families_poses import RELATIVE, _trials

from autograder import checks
from autograder.families import inverse, pieces, units_length
from autograder.specs import lab0_frames as lab0
from autograder.specs import lab5_depth as lab5
from robots import geometry as geo


def _hint(spec, func, seed=3, n=3):
    return [checks._mistake_hint(spec, func(*t.args), t) for t in _trials(spec, seed, n)]


def whole_transposed(a_T_b):
    return np.asarray(a_T_b, float).T                 # "the inverse is the transpose"


def compose_whole_mm(poses):
    return 1000.0 * geo.compose(*poses)                # every entry, not the translation


def rotvec_unnormalised_mm(rvec, t):
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    K = geo.skew(rvec)                                 # the axis never divided by theta
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
    T[:3, 3] = 1000.0 * np.asarray(t, float)           # and the translation in mm
    return T


def relative_nan_rotation_mm(a_T_b, a_T_c):
    T = geo.invert(a_T_b) @ a_T_c
    T[:3, :3] = np.nan                                 # a failed arccos, say
    T[:3, 3] *= 1000.0
    return T


def circle_mm_normal_unnormalised(*args):
    centre, normal = lab5._refined_circle(*args)
    return 1000.0 * np.asarray(centre, float), 2.0 * np.asarray(normal, float)


def relative_whole_transposed(a_T_b, a_T_c):
    return (geo.invert(a_T_b) @ a_T_c).T               # the answer transposed on its way out


# (lab or None for the instructor's relative_pose, function, student function, the names
# allowed: (family, the words' start); a lab's own code mistake for it has family None)
MM = ("units m/mm", "its translation is 1000 times too large")
CASES = [
    # a_T_b.T is [R^T | 0] above a last row [t 1]: the transpose where the inverse belongs
    ("lab0_frames", "invert_pose", whole_transposed,
     [("inverse/transpose", inverse.TRANSPOSED_FOR_INVERSE)]),
    (None, "relative_pose", relative_whole_transposed,
     [("inverse/transpose", inverse.WHOLE_TRANSPOSED)]),
    ("lab0_frames", "compose_chain", compose_whole_mm, [("units m/mm", units_length.WHOLE_MM)]),
    ("lab0_frames", "pose_from_rotvec", rotvec_unnormalised_mm,
     [MM, (None, "its translation is in millimetres")]),
    (None, "relative_pose", relative_nan_rotation_mm, [MM]),
    ("lab5_depth", "fit_flange_circle", circle_mm_normal_unnormalised,
     [("units m/mm", "the first item of the answer is 1000 times too large"),
      ("units m/mm", "one input's lengths were taken in millimetres")]),
]


def _spec(lab, name):
    return RELATIVE if lab is None else checks.spec_for(name, lab)


@pytest.mark.parametrize("lab, name, func, allowed", CASES, ids=[c[2].__name__ for c in CASES])
def test_a_mistake_behind_a_failed_validity_check_is_named(lab, name, func, allowed):
    spec = _spec(lab, name)
    found = []
    for t in _trials(spec, 3, 4):
        value = func(*t.args)
        if checks._measurable(spec, value, t):
            continue        # a small rotation vector's unnormalised axis is still a rotation
        n = checks._mistake_hint(spec, value, t)
        found.append(n)
        assert n is None or any(n.family == f and n.words.startswith(w[:40])
                                for f, w in allowed), n
    assert len(found) >= 3 and sum(n is not None for n in found) >= len(found) - 1, found


def test_the_grader_names_an_answer_it_cannot_measure_and_scores_it_as_before():
    """score_function names the mistake on an answer whose last row is no pose's; the
    score is the one it had without the name (zero on every problem)."""
    spec = lab0.INVERT_POSE
    trials = _trials(spec, 4, 4)
    # a_T_b.T: [R^T | 0] above a last row [t 1] (the inverse's rotation, no translation)
    outcomes = [checks._call_in_process(whole_transposed, t, spec) for t in trials]
    named = checks.score_function(spec, trials, outcomes)
    bare = checks.score_function(spec, trials, outcomes, hints=False)
    assert named.points == bare.points == 0.0
    assert [m.words for m in named.mistakes] == [inverse.TRANSPOSED_FOR_INVERSE]
    assert not bare.mistakes


def test_two_different_mistakes_in_two_pieces_get_no_name():
    """A rotation transposed and a translation in millimetres, behind a last row that is no
    pose's: each piece names another mistake, and two names are never given at once."""
    spec = RELATIVE
    for t in _trials(spec, 5, 2):
        T = spec.reference(*t.args)
        wrong = np.array(T)
        wrong[:3, :3] = T[:3, :3].T
        wrong[:3, 3] *= 1000.0
        wrong[3] = [1.0, 0.0, 0.0, 1.0]
        assert checks._mistake_hint(spec, wrong, t) is None


def test_an_unmeasurable_answer_with_no_mistake_in_its_pieces_is_not_named():
    """Garbage in the last row and a right pose above it: no piece holds a mistake; random
    numbers in a 4x4: no mistake's answer is near (its block is no rotation, as the answer
    itself says)."""
    spec = RELATIVE
    rng = np.random.default_rng(0)
    for t in _trials(spec, 6, 3):
        right = np.array(spec.reference(*t.args))
        right[3] = [0.2, 0.0, 0.0, 1.0]
        assert checks._mistake_hint(spec, right, t) is None
        noise = checks._mistake_hint(spec, rng.normal(size=(4, 4)), t)
        assert noise is None or noise.family == "not a rotation", noise


def test_a_rotation_that_is_no_rotation_beside_a_right_translation_gets_no_name():
    """Its nearest rotation is wrong too (the axis was never normalised): no cause is known,
    and the right translation beside it is no piece's mistake either."""
    spec = checks.spec_for("pose_from_rotvec", "lab0_frames")

    def unnormalised(rvec, t):
        T = rotvec_unnormalised_mm(rvec, t)
        T[:3, 3] = t
        return T
    names = _hint(spec, unnormalised, n=4)
    assert names == [None] * 4, names


def test_pieces_splice_one_piece_of_the_answer_into_the_truth():
    truth = geo.make_pose(np.eye(3), [0.1, 0.2, 0.3])
    value = np.full((4, 4), np.nan)
    value[:3, 3] = [1.0, 2.0, 3.0]
    (only,) = pieces.spliced(value, truth)       # the rotation holds NaN: no piece of it
    assert np.allclose(only[:3, :3], np.eye(3)) and np.allclose(only[:3, 3], [1, 2, 3])
    parts = pieces.spliced((np.ones(3), np.zeros(2)), (np.zeros(3), np.ones(3)))
    assert len(parts) == 1 and np.allclose(parts[0][0], 1.0)
    assert pieces.spliced("a pose", truth) == [] and pieces.spliced(np.ones(3), truth) == []
