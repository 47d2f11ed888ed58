"""Families over poses and rotations (issue 52): a pose named part by part, a stack item by
item, the order of a product, a rotation block that is no rotation.

The development set: student functions written by hand, one classic bug each, for graded
functions of labs 0-5 and for an instructor's function of our own (``relative_pose``, a lab
nobody wrote code mistakes for), each named through the path check() uses
(``checks._mistake_hint``) on a few draws. The held-out corpus (benchmarks/mistake_corpus)
is not read here. A confusion test asks that no family names another's dev mistake, and
that right answers and their noisy estimates are never named.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from autograder import checks, families
from autograder.spec_types import EXACT_TOL, FunctionSpec, Trial, measure_pose, pose_checks
from autograder.specs import lab1_flange as lab1
from autograder.specs import lab2_handeye as lab2
from autograder.specs import lab5_depth as lab5
from robots import geometry as geo


def _pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


# --------------------------------------------------------------------------- dev mistakes


def invert_sign_t(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    return _pose(R.T, R.T @ t)          # the minus of -R^T t lost


def invert_rotated_wrong(a_T_b):
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    return _pose(R.T, -R @ t)           # R for R^T in the translation


def compose_translation_zero(poses):
    out = np.eye(4)
    for T in poses:
        out[:3, :3] = out[:3, :3] @ T[:3, :3]   # the translations never accumulated
    return out


def rotvec_half_angle(rvec, t):
    # a quaternion's half angle taken for the angle
    return geo.pose_from_rotvec(np.asarray(rvec, float) / 2, t)


def rotvec_no_square_term(rvec, t):
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    K = geo.skew(rvec / theta) if theta > 0 else np.zeros((3, 3))
    return _pose(np.eye(3) + np.sin(theta) * K, t)   # (1 - cos) K^2 left out


def rotvec_unnormalised_axis(rvec, t):
    rvec = np.asarray(rvec, float)
    theta = np.linalg.norm(rvec)
    K = geo.skew(rvec)                               # the axis never divided by theta
    return _pose(np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K, t)


def rotvec_translation_negated(rvec, t):
    return geo.pose_from_rotvec(rvec, -np.asarray(t, float))


def fit_covariance_transposed(src, dst):
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    U, _, Vt = np.linalg.svd(b.T @ a)                # dst x src, not src x dst
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return _pose(R, dst.mean(axis=0) - R @ src.mean(axis=0))


def fit_translation_left_out(src, dst):
    T = lab1._kabsch(src, dst)
    T[:3, 3] = 0.0
    return T


def fit_not_projected(src, dst):
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    M = np.linalg.lstsq(a, b, rcond=None)[0].T       # a linear map, never made a rotation
    return _pose(M, dst.mean(axis=0) - M @ src.mean(axis=0))


def motions_a_reversed(base_T_flange, cam_T_target, strategy="all"):
    A, B = lab2.motion_pairs_truth(base_T_flange, cam_T_target, strategy)
    n = len(base_T_flange)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)] if strategy == "all" \
        else [(i, i + 1) for i in range(n - 1)]
    A = np.array([base_T_flange[j] @ geo.invert(base_T_flange[i]) for i, j in pairs])
    return A, B


def motions_b_each_inverted(base_T_flange, cam_T_target, strategy="all"):
    A, B = lab2.motion_pairs_truth(base_T_flange, cam_T_target, strategy)
    return A, np.array([geo.invert(b) for b in B])


def _axes_rotation(A, B, transposed: bool):
    alpha = np.array([geo.rotvec_from_rotation(a[:3, :3]) for a in A])
    beta = np.array([geo.rotvec_from_rotation(b[:3, :3]) for b in B])
    H = alpha.T @ beta if transposed else beta.T @ alpha
    U, _, Vt = np.linalg.svd(H)
    return Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T


def axes_covariance_transposed(A, B):
    A, B = np.asarray(A, float), np.asarray(B, float)
    R = _axes_rotation(A, B, transposed=True)
    C = np.vstack([a[:3, :3] - np.eye(3) for a in A])
    d = np.concatenate([R @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B)])
    return _pose(R, np.linalg.lstsq(C, d, rcond=None)[0])


def tsai_translation_negated(A, B):
    X = lab2.he.solve_tsai(A, B)
    X[:3, 3] *= -1.0
    return X


def frame_z_not_normalised(p_origin, p_x, p_xy):
    x = (p_x - p_origin) / np.linalg.norm(p_x - p_origin)
    z = np.cross(x, p_xy - p_origin)                 # |z| is not 1
    return _pose(np.column_stack([x, np.cross(z, x), z]), p_origin)


def frame_cross_swapped(p_origin, p_x, p_xy):
    x = (p_x - p_origin) / np.linalg.norm(p_x - p_origin)
    z = np.cross(p_xy - p_origin, x)                 # (p_xy - o) x x: z points down
    z /= np.linalg.norm(z)
    return _pose(np.column_stack([x, np.cross(z, x), z]), p_origin)


def frame_x_not_normalised(p_origin, p_x, p_xy):
    x = p_x - p_origin                               # |x| is the points' spacing, not 1
    z = np.cross(x, p_xy - p_origin)
    z /= np.linalg.norm(z)
    return _pose(np.column_stack([x, np.cross(z, x), z]), p_origin)


def register_translation_unrotated(cam_centres, base_T_flanges):
    T = lab5._register(cam_centres, base_T_flanges)
    T[:3, 3] = T[:3, :3].T @ T[:3, 3]
    return T


def rectangle_translation_negated(*args):
    T = lab5._shape_pose(*args)
    T[:3, 3] *= -1.0
    return T


# an instructor's function: b_T_c from a_T_b and a_T_c (no code mistakes written for it)

def _relative_spec(noise_deg: float = 0.0):
    def make_trial(rng, index):
        a_T_b, a_T_c = (geo.make_pose(Rotation.random(random_state=rng).as_matrix(),
                                      rng.uniform(-1, 1, 3)) for _ in range(2))
        return Trial(args=(a_T_b, a_T_c), truth=geo.invert(a_T_b) @ a_T_c,
                     tol=dict(EXACT_TOL), label="two poses")
    return FunctionSpec("relative_pose", 2.0, 6, make_trial, measure_pose,
                        pose_checks("b_T_c = inv(a_T_b) @ a_T_c"), "relative_pose(a_T_b, a_T_c)",
                        reference=lambda a_T_b, a_T_c: geo.invert(a_T_b) @ a_T_c)


def relative_order_reversed(a_T_b, a_T_c):
    return a_T_c @ geo.invert(a_T_b)


def relative_translation_sign(a_T_b, a_T_c):
    T = geo.invert(a_T_b) @ a_T_c
    T[:3, 3] *= -1.0
    return T


def relative_half_angle(a_T_b, a_T_c):
    T = geo.invert(a_T_b) @ a_T_c
    T[:3, :3] = Rotation.from_rotvec(Rotation.from_matrix(T[:3, :3]).as_rotvec() / 2).as_matrix()
    return T


RELATIVE = _relative_spec()

# (lab or None for the instructor's spec, function, student function, family)
DEV = [
    ("lab0_frames", "invert_pose", invert_sign_t, "sign"),
    ("lab0_frames", "invert_pose", invert_rotated_wrong, "inverse/transpose"),
    ("lab0_frames", "compose_chain", compose_translation_zero, "missing part"),
    ("lab0_frames", "pose_from_rotvec", rotvec_half_angle, "half angle"),
    ("lab0_frames", "pose_from_rotvec", rotvec_translation_negated, "sign"),
    ("lab1_flange", "fit_rigid", fit_covariance_transposed, "inverse/transpose"),
    ("lab1_flange", "fit_rigid", fit_translation_left_out, "missing part"),
    ("lab2_handeye", "motions", motions_a_reversed, "reversed stack/order"),
    ("lab2_handeye", "motions", motions_b_each_inverted, "inverse/transpose"),
    ("lab2_handeye", "axes_ls", axes_covariance_transposed, "inverse/transpose"),
    ("lab4_stereo", "frame_from_three_points", frame_z_not_normalised, "not a rotation"),
    ("lab4_stereo", "frame_from_three_points", frame_x_not_normalised, "not a rotation"),
    ("lab5_depth", "base_T_cam_from_flanges", register_translation_unrotated,
     "inverse/transpose"),
    ("lab5_depth", "rectangle_pose", rectangle_translation_negated, "sign"),
    (None, "relative_pose", relative_order_reversed, "reversed stack/order"),
    (None, "relative_pose", relative_translation_sign, "sign"),
    (None, "relative_pose", relative_half_angle, "half angle"),
]


def _spec(lab, name):
    return RELATIVE if lab is None else checks.spec_for(name, lab)


def _trials(spec, seed: int, n: int):
    """``n`` ordinary problems (no edge case, no degenerate input) of ``spec``'s generator."""
    rng = np.random.default_rng(seed)
    found = []
    for i in range(8 * n):
        t = spec.make_trial(rng, i)
        if t.raises is None and not t.all_or_nothing:
            found.append(t)
        if len(found) == n:
            break
    return found


def _names(spec, func, trials):
    out = []
    for t in trials:
        value = func(*t.args)
        out.append(checks._mistake_hint(spec, value, t))
    return out


@pytest.mark.parametrize("lab, name, func, family", DEV, ids=[d[2].__name__ for d in DEV])
def test_each_dev_mistake_is_named_by_its_family(lab, name, func, family):
    spec = _spec(lab, name)
    trials = _trials(spec, 5, 3)
    names = _names(spec, func, trials)
    assert all(n is None or n.family == family for n in names), names   # never misnamed
    assert len(trials) == 3 and sum(n is not None for n in names) >= 2, names


# A block that is no rotation, and whose nearest rotation is wrong too, has no one cause:
# a term of Rodrigues' formula left out, an axis never normalised, a linear fit that is no
# rotation fit. The grader says the symptom (a line of the errors) and names nothing.
NO_CAUSE = [
    ("lab0_frames", "pose_from_rotvec", rotvec_no_square_term),
    ("lab0_frames", "pose_from_rotvec", rotvec_unnormalised_axis),
    ("lab1_flange", "fit_rigid", fit_not_projected),
]


@pytest.mark.parametrize("lab, name, func", NO_CAUSE, ids=[d[2].__name__ for d in NO_CAUSE])
def test_a_block_that_is_no_rotation_says_so_and_names_no_cause(lab, name, func):
    spec = _spec(lab, name)
    trials = _trials(spec, 5, 3)
    outcomes = [checks.TrialOutcome(value=func(*t.args)) for t in trials]
    result = checks.score_function(spec, trials, outcomes)
    assert result.points < spec.points and result.mistakes == (), result.mistakes
    symptom = [e for e in result.problem_errors
               if e.message == families.not_rotation.NOT_A_ROTATION]
    assert symptom and all(e.leads for e in symptom), result.errors
    assert sum(families.not_rotation.NOT_A_ROTATION in line for line in result.errors) == 1


def relative_translation_in_last_row(a_T_b, a_T_c):
    T = geo.invert(a_T_b) @ a_T_c
    out = np.eye(4)
    out[:3, :3], out[3, :3] = T[:3, :3], T[:3, 3]    # t written as a row, not a column
    return out


def _look_at(eye, target, up, x_first=lambda z, up: np.cross(z, up)):
    """world_T_cam of a camera at ``eye`` looking at ``target``: z forward, x = z cross up
    (right, for y down), y = z cross x."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = x_first(z, up)
    x /= np.linalg.norm(x)
    return _pose(np.column_stack([x, np.cross(z, x), z]), eye)


def _look_at_spec():
    def make_trial(rng, index):
        eye, target = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3) + [0.0, 0.0, 2.0]
        up = np.array([0.0, 0.0, 1.0])
        return Trial(args=(eye, target, up), truth=_look_at(eye, target, up),
                     tol=dict(EXACT_TOL), label="a view")
    return FunctionSpec("look_at", 2.0, 4, make_trial, measure_pose,
                        pose_checks("world_T_cam looking at the target"),
                        "look_at(eye, target, up)", reference=_look_at)


def test_an_instructors_frame_with_a_cross_product_reversed_is_named_two_axes_flipped():
    spec = _look_at_spec()
    trials = _trials(spec, 2, 3)
    reversed_cross = [_look_at(*t.args, x_first=lambda z, up: np.cross(up, z)) for t in trials]
    names = [checks._mistake_hint(spec, v, t) for v, t in zip(reversed_cross, trials)]
    assert all(n is not None and n.family == "sign" and "x and y axes point the wrong way"
               in n.words for n in names), names
    assert not [n for t in trials if (n := checks._mistake_hint(spec, _look_at(*t.args), t))]


def test_the_flip_family_predicts_what_lab_4_wrote_by_hand_for_its_frame():
    """Lab 4 wrote a code mistake for z = (p_xy - o) x x; its words speak there (listed
    first), and the family gives the same answer, so a lab without that code mistake gets
    the family's name."""
    spec = checks.spec_for("frame_from_three_points", "lab4_stereo")
    for t in _trials(spec, 4, 2):
        flipped = [p.answer for name, p in families.predictions(spec, t)
                   if "x axis)" in name.words and name.family == "sign"]
        assert len(flipped) == 1 and np.allclose(flipped[0], frame_cross_swapped(*t.args))


def test_a_name_one_edge_problem_gives_but_another_problem_rules_out_is_not_given():
    """Where b and c share a rotation, b_T_c's block is the identity, symmetric: t written
    in the last row is then exactly the whole 4x4 transposed. On the other problems the
    answer is beyond the noise of that transpose, so that is not the slip: no name."""
    rng = np.random.default_rng(3)
    trials = [RELATIVE.make_trial(rng, i) for i in range(3)]
    a_T_b = trials[0].args[0]
    a_T_c = geo.make_pose(a_T_b[:3, :3], rng.uniform(-1, 1, 3))
    trials.insert(0, replace(trials[0], args=(a_T_b, a_T_c), truth=geo.invert(a_T_b) @ a_T_c))
    answers = [relative_translation_in_last_row(*t.args) for t in trials]
    edge = checks._mistake_hint(RELATIVE, answers[0], trials[0])
    assert edge is not None and edge.family == "inverse/transpose", edge   # alone, it fits
    result = checks.score_function(RELATIVE, trials,
                                   [checks.TrialOutcome(value=a) for a in answers])
    assert result.points < RELATIVE.points and result.mistakes == (), result.mistakes
    assert not any(e.message.startswith(checks.MISTAKE_NOTE) for e in result.problem_errors)


def test_a_slip_named_on_every_problem_it_fits_keeps_its_name():
    trials = _trials(RELATIVE, 4, 3)
    result = checks.score_function(
        RELATIVE, trials, [checks.TrialOutcome(value=relative_translation_sign(*t.args))
                           for t in trials])
    assert [m.family for m in result.mistakes] == ["sign"], result.mistakes


# --------------------------------------------------------------------------- no misnaming


def rotvec_angle_squared(rvec, t):
    rvec = np.asarray(rvec, float)
    # r * theta: the angle theta^2 about the right axis (scipy: no warning past a full turn)
    return _pose(Rotation.from_rotvec(rvec * np.linalg.norm(rvec)).as_matrix(), t)


def compose_translations_added(poses):
    R = np.eye(3)
    for T in poses:
        R = R @ T[:3, :3]
    return _pose(R, sum(np.asarray(T, float)[:3, 3] for T in poses))


def _garbage_translation(func, seed=0):
    rng = np.random.default_rng(seed)

    def wrong(*args):
        T = np.array(func(*args), dtype=float)
        T[:3, 3] += rng.uniform(-0.5, 0.5, 3)
        return T
    return wrong


def _angle_scaled(func, factor: float):
    """``func`` with its rotation's angle times ``factor`` about the same axis (a Rodrigues
    built from an axis of norm ``factor``, taken by scipy as a rotation vector)."""
    def wrong(*args):
        T = np.array(func(*args), dtype=float)
        r = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        T[:3, :3] = Rotation.from_rotvec(r * factor).as_matrix()
        return T
    return wrong


# mistakes no family describes: unnamed, or named by the lab's own code mistake (family None)
UNDESCRIBED = [
    ("lab5_depth", "rectangle_pose", _angle_scaled(lab5._shape_pose, 1.5)),
    ("lab5_depth", "rectangle_pose", _angle_scaled(lab5._shape_pose, 3.7)),
    ("lab2_handeye", "tsai_lenz", _angle_scaled(lab2.he.solve_tsai, 1.3)),
    # t_X's sign, where the translation noise spans t_X itself: -t is within the noise of t
    ("lab2_handeye", "tsai_lenz", tsai_translation_negated),
    ("lab0_frames", "pose_from_rotvec", rotvec_angle_squared),
    ("lab0_frames", "compose_chain", compose_translations_added),
    ("lab1_flange", "fit_rigid", _garbage_translation(lab1._kabsch)),
    ("lab2_handeye", "axes_ls", _garbage_translation(lab2.he.solve_axes_ls)),
    (None, "relative_pose", _garbage_translation(RELATIVE.reference)),
]


@pytest.mark.parametrize("lab, name, func", UNDESCRIBED, ids=[f"{u[1]}-{i}" for i, u in
                                                             enumerate(UNDESCRIBED)])
def test_a_mistake_no_family_describes_is_not_named_by_one(lab, name, func):
    spec = _spec(lab, name)
    trials = _trials(spec, 9, 4)
    names = _names(spec, func, trials)
    allowed = {None, "sign"} if func is tsai_translation_negated else {None}
    assert all(n is None or n.family in allowed for n in names), names


def test_no_dev_mistake_is_named_by_another_family_and_right_answers_by_none():
    """The confusion table over the dev set, on draws the per-mistake test did not use:
    each row's names all fall in its own family's column (or none), and at least 90 % of
    the problems are named."""
    confusion: dict[tuple[str, str | None], int] = {}
    for lab, name, func, family in DEV:
        spec = _spec(lab, name)
        trials = _trials(spec, 23, 2)
        for n in _names(spec, func, trials):
            key = (family, None if n is None else n.family)
            confusion[key] = confusion.get(key, 0) + 1
    # the labs' references are test_families.py's; the instructor's function's here
    trials = _trials(RELATIVE, 23, 4)
    assert not [n for n in _names(RELATIVE, RELATIVE.reference, trials) if n is not None]
    wrong = {k: v for k, v in confusion.items() if k[1] is not None and k[0] != k[1]}
    assert not wrong, confusion
    named = sum(v for k, v in confusion.items() if k[1] is not None)
    assert named >= 0.9 * sum(confusion.values()), confusion


def test_a_half_turn_is_its_own_transpose_and_is_not_named_transposed():
    """R(pi) = R(pi)^T: a right rotation with a wrong translation is no transposed
    rotation (the loose families weigh only a rotation mistake that moves the rotation)."""
    spec = RELATIVE
    R = Rotation.from_rotvec(np.pi * np.array([0.0, 0.6, 0.8])).as_matrix()
    truth = _pose(R, [0.3, -0.2, 0.5])
    trial = Trial(args=(np.eye(4), truth), truth=truth, tol=dict(EXACT_TOL))
    wrong = _pose(R, [0.1, 0.4, -0.2])
    assert checks._mistake_hint(spec, wrong, trial) is None
    flipped = _pose(R, -truth[:3, 3])      # the translation's sign, rotation right
    assert checks._mistake_hint(spec, flipped, trial).family == "sign"


def test_the_new_families_show_in_the_applicable_list_of_a_pose_function():
    spec = RELATIVE
    trial = spec.make_trial(np.random.default_rng(0), 0)
    keys = {f.key for f in families.applicable(spec, trial)}
    assert {"translation sign", "translation rotated", "translation zero", "half angle",
            "transposed rotation, any translation", "product order", "not a rotation"} <= keys
    assert "each pose inverted" not in keys      # no stack answer here


def test_a_part_of_a_tuple_answer_with_its_sign_flipped_is_named():
    """A circle's normal flipped beside its right centre: the sign of that part (on lab 5's
    function without its code mistakes, as an instructor's lab that wrote none)."""
    spec = replace(checks.spec_for("fit_flange_circle", "lab5_depth"), code_mistakes=())
    trials = _trials(spec, 3, 3)

    def flipped(*args):
        centre, normal = lab5._refined_circle(*args)
        return centre, -np.asarray(normal, float)
    names = _names(spec, flipped, trials)
    assert all(n is None or n.family == "sign" for n in names), names
    assert sum(n is not None for n in names) >= 2, names
    assert "item 2" in next(n for n in names if n is not None).words


def test_radians_are_not_named_where_undoing_them_wraps_past_a_turn():
    """An angle of (theta + 2 pi) * pi/180 times 180/pi wraps onto theta, but no angle in
    radians taken for degrees gives it: not named; theta * pi/180 is."""
    axis = np.array([0.0, 0.6, 0.8])
    truth = _pose(Rotation.from_rotvec(0.5 * axis).as_matrix(), [0.3, -0.2, 0.5])
    trial = Trial(args=(np.eye(4), truth), truth=truth, tol=dict(EXACT_TOL))

    def turned(angle):
        return _pose(Rotation.from_rotvec(angle * axis).as_matrix(), truth[:3, 3])
    assert checks._mistake_hint(RELATIVE, turned(np.radians(0.5)), trial).family \
        == "units rad/deg"
    assert checks._mistake_hint(RELATIVE, turned(np.radians(0.5 + 2 * np.pi)), trial) is None


def test_practice_data_names_what_the_grader_names():
    """check() on a student's install weighs precomputed answers (no reference to call):
    the same names as the grader's live families, the wrapping rule of the reference's
    estimate in degrees included (tsai_lenz with its angle times 1.3 lands near that
    estimate on one of these draws by chance)."""
    from autograder import practice

    spec = checks.spec_for("tsai_lenz", "lab2_handeye")
    func = _angle_scaled(lab2.he.solve_tsai, 1.3)
    for t in _trials(spec, 9, 6):
        stored = replace(t, mistakes=practice.precomputed_mistakes(spec, t))
        value = func(*t.args)
        assert checks._mistake_hint(spec, value, stored) == checks._mistake_hint(spec, value, t)
