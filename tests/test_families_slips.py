"""Algorithmic slips (issue 52): a formula written wrong, not a unit or a sign, for labs 3
and 5 (and lab 4's reproject) and for an instructor's function of our own (``project``,
a point's pixel through a camera matrix, no code mistakes written for it).

Each slip is a student's function written by hand. Some are what a general family
describes (``autograder.families.matrix_input``: a camera matrix's principal point left
out, a square matrix input read transposed): those must be named by it through the path
check() uses. The others no family describes (a term of the interaction matrix, fx for fy,
a centre taken as a mean): those must never be named by a family. The held-out corpus
(benchmarks/mistake_corpus) is not read here; benchmarks/families_dev_slips.py scores the
same set on many draws.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_families_poses import _names, _trials

from autograder import checks, families
from autograder.families import matrix_input
from autograder.spec_types import Check, FunctionSpec, Trial
from autograder.specs import lab3_servoing as lab3
from autograder.specs import lab5_depth as lab5

TRANSPOSED, MISSING, CODE = "inverse/transpose", "missing part", "a lab's code mistake"
TWIN = "input used twice"   # an entry of K for its twin of the y axis (fx for fy)


# --------------------------------------------------------------------------- an instructor's


def _pixel(K, p_cam):
    p = np.asarray(p_cam, float)
    return np.array([K[0, 0] * p[0] / p[2] + K[0, 2], K[1, 1] * p[1] / p[2] + K[1, 2]])


def _pixel_measure(value, trial):
    v = np.asarray(value, float)
    if v.shape != (2,) or not np.all(np.isfinite(v)):
        raise ValueError(f"project: expected a finite (2,) pixel, got {v!r}")
    return {"pixel": float(np.linalg.norm(v - np.asarray(trial.truth, float)))}


def _project_spec() -> FunctionSpec:
    """project(K, p_cam) -> (u, v) px: a pinhole projection (an instructor's function)."""
    def make_trial(rng, index):
        f = rng.uniform(300, 900)
        K = np.array([[f, 0.0, rng.uniform(200, 440)], [0.0, f * rng.uniform(0.9, 1.1),
                                                        rng.uniform(150, 330)], [0, 0, 1.0]])
        p = np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(0.5, 2.0)])
        return Trial(args=(K, p), truth=_pixel(K, p), tol={"pixel": 0.01}, label="a point")
    return FunctionSpec("project", 2.0, 6, make_trial, _pixel_measure,
                        (Check("pixel", "px", 1.0, ((1.0, 1.0),), "the pixel"),),
                        "project(K: (3, 3), p_cam: (3,)) -> (2,) px", parameters="K, p_cam",
                        reference=_pixel)


PROJECT = _project_spec()


def project_no_principal_point(K, p_cam):
    p = np.asarray(p_cam, float)
    return np.array([K[0, 0] * p[0] / p[2], K[1, 1] * p[1] / p[2]])


def project_divided_by_x(K, p_cam):
    p = np.asarray(p_cam, float)
    return np.array([K[0, 0] * p[1] / p[0] + K[0, 2], K[1, 1] * p[1] / p[2] + K[1, 2]])


def project_fx_for_fy(K, p_cam):
    p = np.asarray(p_cam, float)
    return np.array([K[0, 0] * p[0] / p[2] + K[0, 2], K[0, 0] * p[1] / p[2] + K[1, 2]])


def project_cx_for_cy(K, p_cam):
    p = np.asarray(p_cam, float)
    return np.array([K[0, 0] * p[0] / p[2] + K[0, 2], K[1, 1] * p[1] / p[2] + K[0, 2]])


# --------------------------------------------------------------------------- the labs'


def interaction_x_row_y_squared(x, y, Z):
    L = lab3._true_interaction(x, y, Z).reshape(-1, 2, 6)
    L[:, 0, 4] = -(1 + y * y)                  # the y row's term copied into the x row
    return L.reshape(-1, 6)


def interaction_one_dropped(x, y, Z):
    L = lab3._true_interaction(x, y, Z).reshape(-1, 2, 6)
    L[:, 0, 4], L[:, 1, 3] = -x * x, y * y     # -(1 + x^2) and 1 + y^2 without the 1
    return L.reshape(-1, 6)


def _piece_with(K):
    def wrong(depth, uv, K_given):
        return lab3._window_position(depth, uv, K(np.asarray(K_given, float)))
    return wrong


def _no_pp(K):
    out = np.array(K)
    out[:2, 2] = 0.0
    return out


def _fx_for_fy(K):
    out = np.array(K)
    out[1, 1] = out[0, 0]
    return out


piece_no_principal_point = _piece_with(_no_pp)
piece_no_principal_point.__name__ = "piece_no_principal_point"
piece_fx_for_fy = _piece_with(_fx_for_fy)
piece_fx_for_fy.__name__ = "piece_fx_for_fy"


def backproject_no_principal_point(depth_raw, K, depth_scale):
    return lab5._true_backproject(depth_raw, _no_pp(K), depth_scale)


def backproject_fx_for_fy(depth_raw, K, depth_scale):
    return lab5._true_backproject(depth_raw, _fx_for_fy(K), depth_scale)


def circle_centre_as_mean(rim_points, radius_m):
    _, normal = lab5._refined_circle(rim_points, radius_m)
    return np.asarray(rim_points, float).mean(axis=0), normal    # an arc's mean, no fit


def reproject_q_transposed(u, v, d, Q):
    X, Y, Z, W = np.asarray(Q, float).T @ np.array([u, v, d, 1.0])
    return np.array([X, Y, Z]) / W


# (lab or None for the instructor's project, function, slip, the family that describes it
# or None where none does)
DEV = [
    ("lab3_servoing", "interaction_matrix", interaction_x_row_y_squared, None),
    ("lab3_servoing", "interaction_matrix", interaction_one_dropped, None),
    ("lab3_servoing", "piece_position", piece_no_principal_point, MISSING),
    # lab 3's camera has fx = fy: the slip changes nothing there, and nothing is named
    ("lab3_servoing", "piece_position", piece_fx_for_fy, None),
    ("lab5_depth", "backproject", backproject_no_principal_point, MISSING),
    ("lab5_depth", "backproject", backproject_fx_for_fy, TWIN),
    # lab 5 wrote a code mistake for it (family None): named by the lab's own words
    ("lab5_depth", "fit_flange_circle", circle_centre_as_mean, CODE),
    ("lab4_stereo", "reproject", reproject_q_transposed, TRANSPOSED),
    (None, "project", project_no_principal_point, MISSING),
    (None, "project", project_divided_by_x, None),
    (None, "project", project_fx_for_fy, TWIN),
    (None, "project", project_cx_for_cy, TWIN),
]


def spec_of(lab, name):
    return PROJECT if lab is None else checks.spec_for(name, lab)


def verdict(name, family) -> str:
    """"named" (by its family, or by the lab's code mistake written for it), "misnamed" (by
    another, or any name where none describes it), "unnamed"."""
    if name is None:
        return "unnamed"
    found = CODE if name.family is None else name.family
    return "named" if family is not None and found == family else "misnamed"


@pytest.mark.parametrize("lab, name, func, family", DEV, ids=[d[2].__name__ for d in DEV])
def test_each_slip_is_named_by_its_family_or_by_none(lab, name, func, family):
    spec = spec_of(lab, name)
    trials = _trials(spec, 5, 2)
    verdicts = [verdict(n, family) for n in _names(spec, func, trials)]
    assert "misnamed" not in verdicts, (verdicts, _names(spec, func, trials))
    if family is not None:
        assert verdicts.count("named") >= 1, verdicts


def test_the_words_name_the_input():
    spec = checks.spec_for("reproject", "lab4_stereo")
    (n, *_) = [n for n in _names(spec, reproject_q_transposed, _trials(spec, 5, 2)) if n]
    assert "the input Q was read transposed" in n.words
    n = _names(PROJECT, project_no_principal_point, _trials(PROJECT, 5, 1))[0]
    assert "principal point (cx, cy) of K" in n.words
    n = _names(PROJECT, project_fx_for_fy, _trials(PROJECT, 5, 1))[0]
    assert n.words.startswith("K's fx was used where its fy belongs (K[0, 0] read for K[1, 1])")


def test_the_matrix_families_apply_by_kinds_only():
    keys = {f.key for f in families.applicable(PROJECT, _trials(PROJECT, 0, 1)[0])}
    assert {"input transposed", "no principal point", "entry for its twin"} <= keys
    assert matrix_input.is_camera_matrix(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]))
    assert not matrix_input.is_camera_matrix(np.eye(3))           # symmetric, no offset
    assert not matrix_input.is_camera_matrix(np.eye(4))           # a pose
    spec = checks.spec_for("fit_rigid", "lab1_flange")            # no matrix input
    keys = {f.key for f in families.applicable(spec, _trials(spec, 0, 1)[0])}
    assert not keys & {"input transposed", "no principal point", "entry for its twin"}


def test_right_answers_of_the_instructors_function_get_no_name():
    assert not [n for n in _names(PROJECT, PROJECT.reference, _trials(PROJECT, 7, 4)) if n]


def test_the_other_dev_sets_are_never_given_these_two_mistakes():
    """The pose, stack and chain dev sets' mistakes (one draw each) are never told that an
    input was read transposed or a principal point left out (their family names are
    shared with other families: the words tell)."""
    import test_families_chain as chain_dev
    import test_families_poses as poses
    import test_families_stacks as stacks

    ours = ("read transposed ([column, row]", "the principal point (cx, cy)",
            "x pixels go with fx and cx")
    for dev, spec_of_row in ((poses, poses._spec), (stacks, poses._spec),
                             (chain_dev, chain_dev._spec)):
        for row in dev.DEV:
            spec = spec_of_row(row[0], row[1])
            for n in _names(spec, row[2], _trials(spec, 43, 1)):
                assert n is None or not any(w in n.words for w in ours), (row[2], n)
