"""A chain of frames gone wrong at one input (issue 52): a factor left out, one input used
twice (``autograder.families.chain``).

The development set: student functions written by hand, one classic bug each, for graded
functions of labs 1, 2 and 4 and for an instructor's function of our own (``point_in_a``,
a point carried through two frames, no code mistakes written for it), each named through
the path check() uses (``checks._mistake_hint``) on a few draws. The held-out corpus
(benchmarks/mistake_corpus) is not read here. A confusion test asks that neither family
names another dev mistake (of this set and of the pose and stack sets), and that right
answers are never named.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_families_poses import RELATIVE, _names, _trials

from autograder import checks, families
from autograder.families import chain
from autograder.spec_types import EXACT_TOL, FunctionSpec, Trial
from robots import geometry as geo

LEFT_OUT, TWICE = "factor left out", "input used twice"


def _apply(T, points):
    P = np.asarray(points, float)
    return P @ np.asarray(T, float)[:3, :3].T + np.asarray(T, float)[:3, 3]


# --------------------------------------------------------------------------- an instructor's


def _point_measure(value, trial):
    v = np.asarray(value, float)
    if v.shape != (3,):
        raise ValueError(f"point_in_a: expected a (3,) point, got shape {v.shape}")
    return {"position": float(np.linalg.norm(v - np.asarray(trial.truth, float)))}


def _point_spec():
    """point_in_a(a_T_b, b_T_c, p_c) -> p_a (3,) metres: an instructor's function (a point
    carried through a chain of two frames) with no code mistakes written for it."""
    from autograder.spec_types import Check

    def reference(a_T_b, b_T_c, p_c):
        return _apply(np.asarray(a_T_b) @ np.asarray(b_T_c), p_c)

    def make_trial(rng, index):
        a_T_b, b_T_c = (geo.make_pose(Rotation.random(random_state=rng).as_matrix(),
                                      rng.uniform(-1, 1, 3)) for _ in range(2))
        p_c = rng.uniform(-0.5, 0.5, 3)
        return Trial(args=(a_T_b, b_T_c, p_c), truth=reference(a_T_b, b_T_c, p_c),
                     tol={"position": 1e-6}, label="a point through two frames")
    return FunctionSpec("point_in_a", 2.0, 6, make_trial, _point_measure,
                        (Check("position", "m", 1.0, ((1.0, 1.0),), "the point in frame a"),),
                        "point_in_a(a_T_b, b_T_c, p_c) -> p_a (3,)",
                        parameters="a_T_b, b_T_c, p_c", reference=reference)


POINT = _point_spec()


def point_b_T_c_left_out(a_T_b, b_T_c, p_c):
    return _apply(a_T_b, p_c)


def point_a_T_b_left_out(a_T_b, b_T_c, p_c):
    return _apply(b_T_c, p_c)


def point_a_T_b_twice(a_T_b, b_T_c, p_c):
    return _apply(np.asarray(a_T_b) @ np.asarray(a_T_b), p_c)


def relative_inverse_left_out(a_T_b, a_T_c):
    return np.array(a_T_c, float)        # the inv(a_T_b) factor never applied


# --------------------------------------------------------------------------- the labs'


def residuals_transform_left_out(dst_T_src, src, dst):
    return np.linalg.norm(np.asarray(dst) - np.asarray(src), axis=1)


def residuals_src_for_dst(dst_T_src, src, dst):
    return np.linalg.norm(_apply(dst_T_src, src) - np.asarray(src), axis=1)


def rmse_transform_left_out(dst_T_src, src, dst):
    return np.sqrt(np.mean((np.asarray(dst) - np.asarray(src)) ** 2, axis=0))


def rmse_src_for_dst(dst_T_src, src, dst):
    # the residuals along src's axes (R^T r_i, r @ R for rows), src pasted for dst
    r = (_apply(dst_T_src, src) - np.asarray(src)) @ np.asarray(dst_T_src)[:3, :3]
    return np.sqrt(np.mean(r ** 2, axis=0))


def rotation_residual_x_left_out(A, B, X):
    A, B = np.asarray(A, float), np.asarray(B, float)
    return float(np.mean(np.sum((A[:, :3, :3] - B[:, :3, :3]) ** 2, axis=(1, 2))))


def translation_residual_x_left_out(A, B, X):
    A, B = np.asarray(A, float), np.asarray(B, float)
    return float(np.mean(np.sum((A[:, :3, 3] - B[:, :3, 3]) ** 2, axis=1)))


def motions_b_from_flanges(base_T_flange, cam_T_target, strategy="all"):
    from autograder.specs.lab2_handeye import motion_pairs_truth
    A, _ = motion_pairs_truth(base_T_flange, cam_T_target, strategy)
    _, B = motion_pairs_truth(base_T_flange, base_T_flange, strategy)  # copy-paste slip
    return A, B


# (lab or None for an instructor's spec, function, student function, family)
DEV = [
    ("lab1_flange", "per_point_residuals", residuals_transform_left_out, LEFT_OUT),
    ("lab1_flange", "per_point_residuals", residuals_src_for_dst, TWICE),
    ("lab1_flange", "per_axis_rmse", rmse_transform_left_out, LEFT_OUT),
    ("lab4_stereo", "per_axis_rmse", rmse_transform_left_out, LEFT_OUT),
    ("lab1_flange", "per_axis_rmse", rmse_src_for_dst, TWICE),
    ("lab4_stereo", "per_axis_rmse", rmse_src_for_dst, TWICE),
    ("lab2_handeye", "rotation_residual", rotation_residual_x_left_out, LEFT_OUT),
    ("lab2_handeye", "translation_residual", translation_residual_x_left_out, LEFT_OUT),
    ("lab2_handeye", "motions", motions_b_from_flanges, TWICE),
    ("point", "point_in_a", point_b_T_c_left_out, LEFT_OUT),
    ("point", "point_in_a", point_a_T_b_left_out, LEFT_OUT),
    ("point", "point_in_a", point_a_T_b_twice, TWICE),
    ("relative", "relative_pose", relative_inverse_left_out, LEFT_OUT),
]
# the input each dev mistake's words must name (by the function's parameter name)
WHICH = {residuals_transform_left_out: "dst_T_src", residuals_src_for_dst: "src",
         rmse_transform_left_out: ("dst_T_src", "base_T_cam"),
         rmse_src_for_dst: ("src", "cam_points"),
         rotation_residual_x_left_out: "X", translation_residual_x_left_out: "X",
         motions_b_from_flanges: "base_T_flange", point_b_T_c_left_out: "b_T_c",
         point_a_T_b_left_out: "a_T_b", point_a_T_b_twice: "a_T_b",
         relative_inverse_left_out: "a_T_b"}
WHICH = {f: (w,) if isinstance(w, str) else w for f, w in WHICH.items()}


def _spec(lab, name):
    return {"point": POINT, "relative": RELATIVE}.get(lab) or checks.spec_for(name, lab)


@pytest.mark.parametrize("lab, name, func, family", DEV,
                         ids=[f"{d[1]}-{d[2].__name__}" for d in DEV])
def test_each_dev_mistake_is_named_by_its_family_with_its_input(lab, name, func, family):
    spec = _spec(lab, name)
    trials = _trials(spec, 5, 3)
    names = _names(spec, func, trials)
    assert all(n is None or n.family == family for n in names), names   # never misnamed
    assert len(trials) == 3 and sum(n is not None for n in names) >= 2, names
    assert all(any(n.words.startswith(f"{w} ") or f" {w} " in n.words for w in WHICH[func])
               for n in names if n is not None), names


def test_no_chain_dev_mistake_is_named_by_another_family_and_right_answers_by_none():
    """The confusion table over this dev set on draws the per-mistake test did not use:
    each row's names fall in its own family's column (or none); the references and the
    instructor's function's right answers get no name."""
    confusion: dict[tuple[str, str | None], int] = {}
    for lab, name, func, family in DEV:
        spec = _spec(lab, name)
        for n in _names(spec, func, _trials(spec, 31, 2)):
            key = (family, None if n is None else n.family)
            confusion[key] = confusion.get(key, 0) + 1
    wrong = {k: v for k, v in confusion.items() if k[1] is not None and k[0] != k[1]}
    assert not wrong, confusion
    named = sum(v for k, v in confusion.items() if k[1] is not None)
    assert named >= 0.9 * sum(confusion.values()), confusion
    assert not [n for n in _names(POINT, POINT.reference, _trials(POINT, 31, 4)) if n]


def test_the_pose_and_stack_dev_mistakes_are_not_named_by_the_chain_families():
    """The other dev sets' mistakes (one draw each, the slice their own tests do not use)
    are never given one of these two names (all of them are labs' functions but the
    poses set's instructor one, which ``poses._spec`` knows)."""
    import test_families_poses as poses
    import test_families_stacks as stacks

    ours = {LEFT_OUT, TWICE}
    for dev in (poses, stacks):
        for row in dev.DEV:
            lab, name, func = row[:3]
            spec = poses._spec(lab, name)
            names = _names(spec, func, _trials(spec, 41, 1))
            assert not [n for n in names if n is not None and n.family in ours], (func, names)


def test_a_pose_used_twice_that_gives_the_identity_is_not_named():
    """inv(a_T_b) @ a_T_b is the identity: the prediction is a trivial answer, never named."""
    trial = RELATIVE.make_trial(np.random.default_rng(2), 0)
    assert checks._mistake_hint(RELATIVE, np.eye(4), trial) is None


def test_parameter_names_come_from_the_spec_and_fall_back_to_positions():
    assert chain.parameter_names(POINT, 3) == ["a_T_b", "b_T_c", "p_c"]
    spec = checks.spec_for("fit_plane_ransac", "lab5_depth")
    assert chain.parameter_names(spec, 2)[0] == "points"
    assert chain.parameter_names(RELATIVE, 2) == ["a_T_b", "a_T_c"]   # its signature's
    typed = FunctionSpec("f", 1.0, 1, None, _point_measure, (), "f(A: (3, 3), b) -> (3,)")
    assert chain.parameter_names(typed, 2) == ["A", "b"]
    bare = FunctionSpec("f", 1.0, 1, None, _point_measure, (), "f")
    assert chain.parameter_names(bare, 2) == ["input 1", "input 2"]


def test_the_chain_families_apply_by_kinds_only():
    keys = {f.key for f in families.applicable(POINT, POINT.make_trial(np.random.default_rng(0),
                                                                        0))}
    assert {"factor left out", "input used twice"} <= keys
    spec = checks.spec_for("fit_rigid", "lab1_flange")     # no pose among its inputs
    trial = _trials(spec, 0, 1)[0]
    assert "factor left out" not in {f.key for f in families.applicable(spec, trial)}
    exact = Trial(args=(np.eye(4), np.eye(4)), truth=np.eye(4), tol=dict(EXACT_TOL))
    assert chain.FAMILIES[0].predict(RELATIVE, exact) is not None


def test_practice_data_names_what_the_grader_names():
    """check() on a student's install weighs the input-side answers precomputed into
    practice data (no reference to call), each with its own words: the same names."""
    from dataclasses import replace

    from autograder import practice

    for func in (point_b_T_c_left_out, point_a_T_b_twice):
        for t in _trials(POINT, 13, 2):
            stored = replace(t, mistakes=practice.precomputed_mistakes(POINT, t))
            value = func(*t.args)
            live = checks._mistake_hint(POINT, value, t)
            assert live is not None and checks._mistake_hint(POINT, value, stored) == live


def test_an_answer_two_transforms_give_alike_is_listed_once():
    """K.T read entry by entry gives what K without (cx, cy) gives: one candidate, the
    principal point's (listed first), so practice data holds that image once."""
    from test_families_slips import PROJECT

    t = _trials(PROJECT, 3, 1)[0]
    found = [(n.family, n.words[:30]) for n, _ in
             families.predictions(PROJECT, t, sides=(families.INPUT,))]
    assert any(f == "missing part" for f, _ in found)
    assert not any(w.startswith("the input K was read transp") for _, w in found), found
