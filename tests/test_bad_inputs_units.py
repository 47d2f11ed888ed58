"""Mixed units and unclear messages in the hand-eye and registration solvers (issue 31, items 1
and 4): a table of bad inputs, each with its expected outcome.

* millimetres (or centimetres) among metres, on either side, through every AX = XB and AX = YB
  entry point: a ``ValueError`` naming the unit and the fix, never a translation hundreds of
  metres off;
* a board in millimetres and normalised coordinates passed as pixels to the corner-based
  solvers; noise levels in degrees where radians are expected;
* bad arguments (None, strings, wrong shapes, objects): a ``ValueError`` naming the argument,
  what was expected and what came;
* lists, tuples and integer arrays: the same answer as float64 arrays;
* no false alarm: every benchmark scenario, the real captures and the existing tests' problems
  pass the unit checks and the solvers without a unit error.
"""

from __future__ import annotations

import functools
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from autograder import synthetic as syn
from robots import geometry as geo
from solutions import ax_yb_closed_forms as closed_forms
from solutions import catalog, diagnostics, handeye, mle, registration, robot_world, units

NOISE = syn.NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5)
UNIT_ERROR = r"look like (milli|centi)metres|different units"


@functools.cache
def _problem(mount="eye_in_hand", seed=3, n=10):
    return syn.make_hand_eye(seed, mount, n_poses=n, noise=NOISE)


@functools.cache
def _pixel_problem(mount="eye_in_hand", seed=4, n=8):
    return syn.make_hand_eye(seed, mount, n_poses=n,
                             noise=syn.NoiseModel(pixel_px=0.3, robot_rot_deg=0.02,
                                                  robot_trans_mm=0.1))


def _scaled(T, factor):
    out = np.array(T, dtype=float, copy=True)
    out[..., :3, 3] *= factor
    return out


# --------------------------------------------------------------------------- 1. mixed units
# Every pose-level entry point, called the documented way on (base_T_flange, cam_T_target).


def _calibrate(method):
    def run(F, C, mount):
        solve = (handeye.calibrate_eye_in_hand if mount == "eye_in_hand"
                 else handeye.calibrate_eye_to_hand)
        return solve(F, C, method=method)
    return run


def _report(method):
    def run(F, C, mount):
        solve = (handeye.calibrate_eye_in_hand_report if mount == "eye_in_hand"
                 else handeye.calibrate_eye_to_hand_report)
        return solve(F, C, method=method).X
    return run


def _ax_yb(method):
    def run(F, C, mount):
        X, Y = robot_world.solve_ax_yb(F, geo.invert(C) if mount == "eye_in_hand" else C, method)
        return X if mount == "eye_in_hand" else Y
    return run


def _refine(F, C, mount):
    return mle.refine_hand_eye(F, C, mount).X


POSE_ENTRIES = {f"calibrate {m}": _calibrate(m) for m in handeye.METHODS}
POSE_ENTRIES.update({"calibrate_report park": _report("park"),
                     "calibrate_report nonlinear": _report("nonlinear"),
                     "refine_hand_eye": _refine})
POSE_ENTRIES.update({f"solve_ax_yb {m}": _ax_yb(m) for m in robot_world.METHODS})

# (side scaled, factor, the message's diagnosis and fix)
UNIT_CASES = [
    ("robot", 1000.0, r"base_T_flange translations look like millimetres.*"
                      r"Divide base_T_flange\[:, :3, 3\] by 1000"),
    ("camera", 1000.0, r"cam_T_target translations look like millimetres.*"
                       r"Divide cam_T_target\[:, :3, 3\] by 1000"),
    ("robot", 100.0, r"base_T_flange translations look like centimetres.*by 100"),
]


def _ax_yb_names(entry, side, factor):
    """solve_ax_yb names its arguments A and B."""
    which = "A" if side == "robot" else "B"
    unit = "millimetres" if factor == 1000.0 else "centimetres"
    return rf"{which} translations look like {unit}.*Divide {which}\[:, :3, 3\] by {int(factor)}"


@pytest.mark.parametrize("mount", handeye.MOUNTS)
@pytest.mark.parametrize("entry", list(POSE_ENTRIES))
@pytest.mark.parametrize(("side", "factor", "message"), UNIT_CASES,
                         ids=["robot-mm", "camera-mm", "robot-cm"])
def test_mixed_units_are_refused_at_every_pose_entry(mount, entry, side, factor, message):
    p = _problem(mount)
    F, C = p.base_T_flange, p.cam_T_target
    F, C = (_scaled(F, factor), C) if side == "robot" else (F, _scaled(C, factor))
    if entry.startswith("solve_ax_yb"):
        message = _ax_yb_names(entry, side, factor)
    with pytest.raises(ValueError, match=message) as err:
        POSE_ENTRIES[entry](F, C, mount)
    assert "a rigid rig needs 1" in str(err.value)


MOTION_SOLVERS = {
    "solve_tsai": handeye.solve_tsai,
    "solve_park": handeye.solve_park,
    "solve_daniilidis": handeye.solve_daniilidis,
    "solve_axes_ls": handeye.solve_axes_ls,
    "solve_nonlinear": handeye.solve_nonlinear,
    "solve_ax_xb": handeye.solve_ax_xb,
    "solve_ax_xb_report": lambda A, B: handeye.solve_ax_xb_report(A, B).X,
}


@pytest.mark.parametrize("solver", list(MOTION_SOLVERS))
@pytest.mark.parametrize(("side", "unit"), [("A", "millimetres"), ("B", "millimetres"),
                                            ("A", "centimetres")])
@pytest.mark.parametrize("strategy", ["all", "consecutive"])
def test_mixed_units_are_refused_by_every_motion_solver(solver, side, unit, strategy):
    p = _problem("eye_in_hand", seed=5, n=12)
    A, B, _ = handeye.hand_eye_motions(p.base_T_flange, p.cam_T_target, strategy=strategy)
    factor = 1000.0 if unit == "millimetres" else 100.0
    A, B = (_scaled(A, factor), B) if side == "A" else (A, _scaled(B, factor))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning blaming the convention first
        with pytest.raises(ValueError, match=rf"{side} translations look like {unit}"):
            MOTION_SOLVERS[solver](A, B)


def test_daniilidis_names_the_units_not_the_convention():
    # Before: Daniilidis came out 3.5-9 deg off and its warning blamed the pose convention.
    p = _problem("eye_in_hand")
    A, B, _ = handeye.hand_eye_motions(_scaled(p.base_T_flange, 1000.0), p.cam_T_target)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(ValueError, match="look like millimetres") as err:
            handeye.solve_daniilidis(A, B)
    assert not caught
    assert "convention" not in str(err.value)


@pytest.mark.parametrize("mount", handeye.MOUNTS)
def test_the_message_gives_the_sizes_and_the_fitted_factor(mount):
    p = _problem(mount)
    with pytest.raises(ValueError) as err:
        handeye.calibrate_eye_in_hand(_scaled(p.base_T_flange, 1000.0), p.cam_T_target) \
            if mount == "eye_in_hand" else \
            handeye.calibrate_eye_to_hand(_scaled(p.base_T_flange, 1000.0), p.cam_T_target)
    text = str(err.value)
    factor = float(text.split("base_T_flange's translations ")[1].split(" times")[0])
    assert 900 < factor < 1100
    assert "(medians)" in text and "cobotlab works in metres" in text


def test_consistent_millimetres_everywhere_are_not_a_unit_mix():
    # Both sides in millimetres is consistent: the result is in millimetres too.
    p = _problem("eye_in_hand")
    X = handeye.calibrate_eye_in_hand(_scaled(p.base_T_flange, 1000.0),
                                      _scaled(p.cam_T_target, 1000.0), method="park")
    assert geo.rotation_error_deg(X, p.X_true) < 0.5
    assert abs(np.linalg.norm(X[:3, 3]) / np.linalg.norm(p.X_true[:3, 3]) - 1000.0) < 20.0


# --------------------------------------------------------------------------- corners, board


def _reprojection_args(p, board_factor=1.0, robot_factor=1.0, pixels=None):
    start = mle.refine_hand_eye(p.base_T_flange, p.cam_T_target, p.mount)
    return dict(board_points=p.board.object_points() * board_factor,
                pixels=p.pixels if pixels is None else pixels, K=p.camera.K,
                dist=p.camera.dist, base_T_flange=_scaled(p.base_T_flange, robot_factor),
                mount=p.mount, X0=start.X, Y0=start.Y)


def _normalised(p):
    K = p.camera.K
    return (p.pixels - K[:2, 2]) / np.diag(K)[:2]


REPROJECTION_CASES = [
    ("board in mm", dict(board_factor=1000.0), r"board_points look like millimetres.*"
                                               r"Divide board_points by 1000"),
    ("board in cm", dict(board_factor=100.0), r"board_points look like centimetres"),
    ("robot in mm", dict(robot_factor=1000.0), r"base_T_flange, X0 and Y0 translations look "
                                               r"like millimetres.*Divide base_T_flange"),
    ("normalised pixels", dict(pixels="normalised"), r"pixels look like normalised image "
                                                     r"coordinates.*K @ \[x, y, 1\]"),
]


@pytest.mark.parametrize("mount", handeye.MOUNTS)
@pytest.mark.parametrize(("case", "change", "message"), REPROJECTION_CASES,
                         ids=[c[0] for c in REPROJECTION_CASES])
@pytest.mark.parametrize("fit_board_scale", [False, True])
def test_refine_reprojection_refuses_mixed_units(mount, case, change, message, fit_board_scale):
    # Before: a board in mm gave 28 deg of error, normalised pixels even said converged=True.
    p = _pixel_problem(mount)
    change = dict(change)
    if change.get("pixels") == "normalised":
        change["pixels"] = _normalised(p)
    with pytest.raises(ValueError, match=message):
        mle.refine_reprojection(**_reprojection_args(p, **change),
                                fit_board_scale=fit_board_scale)


def test_normalised_coordinates_with_an_identity_camera_matrix_are_fine():
    p = _pixel_problem("eye_in_hand")
    args = _reprojection_args(p, pixels=_normalised(p))
    args["K"], args["dist"] = np.eye(3), None
    res = mle.refine_reprojection(**args)
    assert geo.rotation_error_deg(res.X, p.X_true) < 0.5


def test_a_board_scale_fitted_far_from_one_is_refused():
    with pytest.raises(ValueError, match=r"board_points look like millimetres.*scale is 0.001"):
        units.check_board_scale(0.001)
    with pytest.raises(ValueError, match="not in the units of the robot poses"):
        units.check_board_scale(1e-7)
    units.check_board_scale(0.95)
    units.check_board_scale(1.4)


CORNER_CASES = [
    ("board in mm", dict(board_factor=1000.0), r"cam_T_target \(solvePnP on board_points\) "
                                               r"translations look like millimetres.*"
                                               r"Divide board_points by 1000"),
    ("robot in mm", dict(robot_factor=1000.0), r"base_T_flange translations look like "
                                               r"millimetres.*Divide base_T_flange"),
    ("normalised pixels", dict(pixels="normalised"), r"normalised image coordinates"),
]


@pytest.mark.parametrize(("case", "change", "message"), CORNER_CASES,
                         ids=[c[0] for c in CORNER_CASES])
def test_calibrate_from_corners_refuses_mixed_units(case, change, message):
    p = _pixel_problem("eye_in_hand")
    change = dict(change)
    if change.get("pixels") == "normalised":
        change["pixels"] = _normalised(p)
    args = _reprojection_args(p, **change)
    with pytest.raises(ValueError, match=message):
        mle.calibrate_from_corners(args["board_points"], args["pixels"], args["K"], args["dist"],
                                   args["base_T_flange"], p.mount, robot_weights=(0.0,),
                                   fit_board_scale=(False,), pose_candidates=("li",))


# --------------------------------------------------------------------------- degrees as radians


DEGREE_CASES = [
    ("refine_hand_eye sigma", lambda p: mle.refine_hand_eye(
        p.base_T_flange, p.cam_T_target, sigma=(5.0, 0.0005)), r"sigma\[0\] \(rotation\) = 5"),
    ("refine_hand_eye robot sigma", lambda p: mle.refine_hand_eye(
        p.base_T_flange, p.cam_T_target, robot_rotation_sigma_rad=10.0),
     "robot_rotation_sigma_rad = 10"),
    ("cramer_rao rotation", lambda p: mle.cramer_rao_covariance(
        p.X_true, p.Y_true, p.base_T_flange, rotation_sigma_rad=45.0, translation_sigma_m=1e-3),
     "rotation_sigma_rad = 45"),
    ("cramer_rao robot", lambda p: mle.cramer_rao_covariance(
        p.X_true, p.Y_true, p.base_T_flange, rotation_sigma_rad=1e-3, translation_sigma_m=1e-3,
        robot_rotation_sigma_rad=4.0), "robot_rotation_sigma_rad = 4"),
    ("refine_reprojection robot_sigma", lambda p: mle.refine_reprojection(
        **_reprojection_args(_pixel_problem()), robot_sigma=(30.0, 0.0)),
     r"robot_sigma\[0\] \(rotation\) = 30"),
]


@pytest.mark.parametrize(("case", "call", "name"), DEGREE_CASES, ids=[c[0] for c in DEGREE_CASES])
def test_degrees_given_for_radians_are_refused(case, call, name):
    with pytest.raises(ValueError, match=rf"{name} rad is more than pi: it looks like degrees; "
                                         r"pass np.radians"):
        call(_problem())


@pytest.mark.parametrize("value", [0.0, 1e-3, 0.5, math.pi])
def test_radians_up_to_pi_pass(value):
    assert units.check_radians(value, "x") == value


# --------------------------------------------------------------------------- flange calibration


@pytest.mark.parametrize(("scale", "which"), [
    (1000.0, "base_points look like millimetres and cam_points like metres"),
    (0.001, "cam_points look like millimetres and base_points like metres"),
    (100.0, "base_points look like centimetres"),
    (0.01, "cam_points look like centimetres"),
])
@pytest.mark.parametrize("call", ["calibrate_flange", "fit_rigid", "with_offset"])
def test_flange_calibration_with_mixed_units_warns_naming_the_unit(scale, which, call):
    p = syn.make_flange(2, n_points=12, noise_mm=0.5, fixed_orientation=False)
    cam, F = p.cam_points, p.base_T_flange
    if scale > 1:
        F = _scaled(F, scale)
    else:
        cam = cam / scale
    with pytest.warns(UserWarning, match=which):
        if call == "calibrate_flange":
            registration.calibrate_flange(cam, F[:, :3, 3])
        elif call == "fit_rigid":
            registration.fit_rigid(cam, F[:, :3, 3], src_name="cam_points",
                                   dst_name="base_points")
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                try:
                    registration.calibrate_flange_with_offset(cam, F)
                except ValueError:
                    pass  # the warning came first; the offset fit may then fail


# --------------------------------------------------------------------------- 4. clear messages


def _args():
    """Valid arguments of each entry point (built once), for the table below."""
    p, pp = _problem(), _pixel_problem()
    F, C = p.base_T_flange, p.cam_T_target
    A, B, _ = handeye.hand_eye_motions(F, C)
    start = mle.refine_hand_eye(pp.base_T_flange, pp.cam_T_target)
    fl = syn.make_flange(1, n_points=12, noise_mm=0.5, fixed_orientation=False)
    return dict(p=p, pp=pp, F=F, C=C, A=A, B=B, start=start, fl=fl,
                P=pp.board.object_points(), K=pp.camera.K)


ARGS = functools.cache(_args)

# (label, call(args, bad), bad value, regex the message must match)
MESSAGE_CASES = [
    ("solve_ax_xb method None", lambda a, v: handeye.solve_ax_xb(a["A"], a["B"], method=v),
     None, r"method must be one of .*got None"),
    ("solve_ax_xb method array", lambda a, v: handeye.solve_ax_xb(a["A"], a["B"], method=v),
     np.array(["park", "tsai"]), r"method must be one of .*got an array of shape \(2,\)"),
    ("solve_ax_xb robust string", lambda a, v: handeye.solve_ax_xb(a["A"], a["B"], "nonlinear",
                                                                    robust=v),
     "no", r"robust must be True, False or None, got the string 'no'"),
    ("solve_nonlinear robust string", lambda a, v: handeye.solve_nonlinear(a["A"], a["B"], v),
     "yes", r"robust must be True or False, got the string 'yes'"),
    ("solve_ax_xb_report pairs shape", lambda a, v: handeye.solve_ax_xb_report(a["A"], a["B"],
                                                                                 pairs=v),
     np.zeros((3, 2), int), r"pairs must be an \(45, 2\) array of non-negative integer pose "
                            r"indices.*got an array of shape \(3, 2\)"),
    ("solve_ax_xb_report pairs string", lambda a, v: handeye.solve_ax_xb_report(a["A"], a["B"],
                                                                                  pairs=v),
     "all", r"pairs must be an \(45, 2\) array of pose indices.*got the string 'all'"),
    ("solve_ax_xb_report pairs negative", lambda a, v: handeye.solve_ax_xb_report(
        a["A"], a["B"], pairs=v), -np.ones((45, 2)), r"pairs must be .*non-negative integer"),
    ("calibrate pairs None", lambda a, v: handeye.calibrate_eye_in_hand(a["F"], a["C"], pairs=v),
     None, r"pairs must be one of \('all', 'consecutive'\), got None"),
    ("calibrate pairs unknown", lambda a, v: handeye.calibrate_eye_in_hand(a["F"], a["C"],
                                                                           pairs=v),
     "every", r"unknown pair strategy 'every': pairs must be one of"),
    ("calibrate method number", lambda a, v: handeye.calibrate_eye_in_hand(a["F"], a["C"],
                                                                           method=v),
     3, r"method must be one of .*got the number 3"),
    ("calibrate robust string", lambda a, v: handeye.calibrate_eye_in_hand(a["F"], a["C"],
                                                                           robust=v),
     "False", r"robust must be True, False or None, got the string 'False'"),
    ("hand_eye_motions mount None", lambda a, v: handeye.hand_eye_motions(a["F"], a["C"],
                                                                          mount=v),
     None, r"mount must be one of \('eye_in_hand', 'eye_to_hand'\), got None"),
    ("hand_eye_motions strategy list", lambda a, v: handeye.hand_eye_motions(a["F"], a["C"],
                                                                             strategy=v),
     ["all"], r"strategy must be one of .*got a list of 1 item"),
    ("motion_pairs strategy", lambda a, v: handeye.motion_pairs(a["F"], v), 2,
     r"strategy must be one of .*got the number 2"),
    ("solve_ax_yb method None", lambda a, v: robot_world.solve_ax_yb(a["F"], geo.invert(a["C"]),
                                                                     method=v),
     None, r"method must be one of \('shah', 'li', 'nonlinear'\), got None"),
    ("solve_ax_yb loss unknown", lambda a, v: robot_world.solve_ax_yb(
        a["F"], geo.invert(a["C"]), "nonlinear", loss=v), "tukey",
     r"unknown robust loss 'tukey': loss must be one of"),
    ("loss_weights loss array", lambda a, v: closed_forms.loss_weights(np.ones(3), v),
     np.zeros(2), r"loss must be one of"),
    ("refine_hand_eye mount", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], mount=v),
     "eye_on_base", r"mount must be one of \('eye_in_hand', 'eye_to_hand'\), got the string"),
    ("refine_hand_eye max_iter string", lambda a, v: mle.refine_hand_eye(a["F"], a["C"],
                                                                         max_iter=v),
     "10", r"max_iter must be an integer >= 1, got the string '10'"),
    ("refine_hand_eye max_iter float", lambda a, v: mle.refine_hand_eye(a["F"], a["C"],
                                                                        max_iter=v),
     2.5, r"max_iter must be an integer >= 1, got the number 2.5"),
    ("refine_hand_eye max_iter zero", lambda a, v: mle.refine_hand_eye(a["F"], a["C"],
                                                                       max_iter=v),
     0, r"max_iter must be an integer >= 1, got 0"),
    ("refine_hand_eye robust None", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], robust=v),
     None, r"robust must be True or False, got None"),
    ("refine_hand_eye loss", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], loss=v),
     None, r"loss must be one of \('huber', 'soft_l1', 'cauchy'\), got None"),
    ("refine_hand_eye noise_model", lambda a, v: mle.refine_hand_eye(a["F"], a["C"],
                                                                     noise_model=v),
     "pnp", r"unknown noise model 'pnp': noise_model must be one of"),
    ("refine_hand_eye sigma string", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], sigma=v),
     "0.1", r"sigma must be \(rotation_rad, translation_m\).*got the string '0.1'"),
    ("refine_hand_eye sigma object", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], sigma=v),
     {"rot": 0.1}, r"sigma must be \(rotation_rad, translation_m\).*got a dict"),
    ("refine_hand_eye sigma shape", lambda a, v: mle.refine_hand_eye(a["F"], a["C"], sigma=v),
     (0.001, 0.001, 0.001), r"sigma must be \(rotation_rad, translation_m\).*got \(0.001"),
    ("refine_hand_eye robot sigma string", lambda a, v: mle.refine_hand_eye(
        a["F"], a["C"], robot_rotation_sigma_rad=v), "small",
     r"robot_rotation_sigma_rad must be a finite number >= 0 \(radians\), got the string"),
    ("refine_hand_eye robot sigma negative", lambda a, v: mle.refine_hand_eye(
        a["F"], a["C"], robot_rotation_sigma_rad=v), -1e-3,
     r"robot_rotation_sigma_rad must be a finite number >= 0 \(radians\), got -0.001"),
    ("pose_residuals mount", lambda a, v: mle.pose_residuals(a["p"].X_true, a["p"].Y_true,
                                                             a["F"], a["C"], mount=v),
     1, r"mount must be one of .*got the number 1"),
    ("cramer_rao sigma None", lambda a, v: mle.cramer_rao_covariance(
        a["p"].X_true, a["p"].Y_true, a["F"], rotation_sigma_rad=v, translation_sigma_m=1e-3),
     None, r"rotation_sigma_rad must be a finite number, got None"),
    ("cramer_rao no poses", lambda a, v: mle.cramer_rao_covariance(
        a["p"].X_true, a["p"].Y_true, v, rotation_sigma_rad=1e-3, translation_sigma_m=1e-3),
     [], r"base_T_flange needs at least 3 poses, got 0"),
    ("refine_reprojection board None", lambda a, v: mle.refine_reprojection(
        v, a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), None, r"board_points must be a finite \(N, 3\) array.*got None"),
    ("refine_reprojection board shape", lambda a, v: mle.refine_reprojection(
        v, a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), np.zeros((48, 2)), r"board_points must be .*got shape \(48, 2\)"),
    ("refine_reprojection pixels string", lambda a, v: mle.refine_reprojection(
        a["P"], v, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X, Y0=a["start"].Y),
     "corners.npz", r"pixels must be an \(n_views, N, 2\) array.*got the string"),
    ("refine_reprojection pixels shape", lambda a, v: mle.refine_reprojection(
        a["P"], v, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X, Y0=a["start"].Y),
     np.zeros((8, 2, 48)), r"pixels must have shape \(n_views, N, 2\) = \(8, 48, 2\).*"
                           r"got \(8, 2, 48\)"),
    ("refine_reprojection K Intrinsics", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, v, None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), "intrinsics", r"K must be the \(3, 3\) camera matrix, got a "
                                        r"robots.interfaces.Intrinsics object: pass intrinsics.K"),
    ("refine_reprojection K None", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, v, None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), None, r"K must be a finite \(3, 3\) camera matrix in pixels, got None"),
    ("refine_reprojection dist string", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, a["K"], v, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), "none", r"dist must be 4, 5, 8, 12 or 14 OpenCV distortion "
                                  r"coefficients, or None, got the string 'none'"),
    ("refine_reprojection dist matrix", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, a["K"], v, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y), np.zeros((2, 2)), r"dist must be a vector .*got shape \(2, 2\)"),
    ("refine_reprojection X0 None", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, X0=v, Y0=a["start"].Y),
     None, r"needs a start X0 and Y0"),
    ("refine_reprojection fit_board_scale string", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y, fit_board_scale=v), "yes",
     r"fit_board_scale must be True or False, got the string 'yes'"),
    ("refine_reprojection robot_sigma string", lambda a, v: mle.refine_reprojection(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, X0=a["start"].X,
        Y0=a["start"].Y, robot_sigma=v), "0", r"robot_sigma must be \(rotation_rad, "
                                              r"translation_m\), both finite and >= 0"),
    ("calibrate_from_corners folds string", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, folds=v),
     "3", r"folds must be an integer >= 2, got the string '3'"),
    ("calibrate_from_corners robot_weights float", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, robot_weights=v),
     0.1, r"robot_weights must be a tuple of fractions, e.g. .*got the number 0.1"),
    ("calibrate_from_corners robot_weights string", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, robot_weights=v),
     ("a",), r"robot_weights\[0\] must be a finite number >= 0, got the string 'a'"),
    ("calibrate_from_corners fit_board_scale bool", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, fit_board_scale=v),
     True, r"fit_board_scale must be a tuple of booleans.*got the boolean True"),
    ("calibrate_from_corners fit_intrinsics None", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, fit_intrinsics=v),
     None, r"fit_intrinsics must be a tuple of booleans.*got None"),
    ("calibrate_from_corners pose_candidates string", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, pose_candidates=v),
     "li", r"pose_candidates must be a tuple of method names.*got the string 'li'"),
    ("calibrate_from_corners cam_T_target length", lambda a, v: mle.calibrate_from_corners(
        a["P"], a["pp"].pixels, a["K"], None, a["pp"].base_T_flange, cam_T_target=v),
     "short", r"cam_T_target has 3 poses but base_T_flange has 8"),
    ("predicted_corners result", lambda a, v: mle.predicted_corners(
        v, a["P"], a["K"], None, a["pp"].base_T_flange), np.eye(4),
     r"result must be a HandEyeRefinement .*got an array of shape \(4, 4\)"),
    ("predicted_corners K", lambda a, v: mle.predicted_corners(
        a["start"], a["P"], v, None, a["pp"].base_T_flange), "K",
     r"K must be a finite \(3, 3\) camera matrix in pixels, got the string 'K'"),
    ("view_rms_px shapes", lambda a, v: mle.view_rms_px(v, a["pp"].pixels), np.zeros((8, 48)),
     r"predicted and pixels must both have shape \(n_views, N, 2\), got \(8, 48\)"),
    ("view_rms_px None", lambda a, v: mle.view_rms_px(a["pp"].pixels, v), None,
     r"pixels must be an \(n, N, 2\) array of pixels, got None"),
    ("fit_rigid src None", lambda a, v: registration.fit_rigid(v, a["fl"].base_points),
     None, r"src must be an \(N, 3\) array of points in metres, got None"),
    ("fit_rigid dst ragged", lambda a, v: registration.fit_rigid(a["fl"].cam_points, v),
     [[0, 0, 0], [1, 2]], r"dst must be an \(N, 3\) array of points in metres, got a list of "
                          r"2 items that is not numeric"),
    ("fit_rigid weights string", lambda a, v: registration.fit_rigid(
        a["fl"].cam_points, a["fl"].base_points, weights=v), "equal",
     r"weights must be \(12,\) non-negative weights, one per point, got the string"),
    ("fit_rigid robust string", lambda a, v: registration.fit_rigid(
        a["fl"].cam_points, a["fl"].base_points, robust=v), "no",
     r"robust must be True or False, got the string 'no'"),
    ("fit_rigid k None", lambda a, v: registration.fit_rigid(
        a["fl"].cam_points, a["fl"].base_points, robust=True, k=v), None,
     r"k must be a finite number > 0 \(robust scales\), got None"),
    ("fit_rigid threshold string", lambda a, v: registration.fit_rigid(
        a["fl"].cam_points, a["fl"].base_points, robust=True, threshold_m=v), "5 mm",
     r"threshold_m must be a finite number > 0 \(metres\), got the string '5 mm'"),
    ("residuals expressed_in object", lambda a, v: registration.residuals(
        a["fl"].base_T_cam_true, a["fl"].cam_points, a["fl"].base_points, expressed_in=v),
     {"frame": "cam"}, r"expressed_in must be 'dst', 'src', a \(4, 4\) pose or a \(3, 3\) "
                       r"rotation, got a dict"),
    ("frame_from_three_points min_angle", lambda a, v: registration.frame_from_three_points(
        [0, 0, 0], [1, 0, 0], [0, 1, 0], min_angle_deg=v), "1",
     r"min_angle_deg must be a finite number >= 0 \(degrees\), got the string '1'"),
    ("frame_from_three_points point None", lambda a, v: registration.frame_from_three_points(
        v, [1, 0, 0], [0, 1, 0]), None, r"p_origin must be a 3-vector \(m\), got None"),
    ("calibrate_flange robust None", lambda a, v: registration.calibrate_flange(
        a["fl"].cam_points, a["fl"].base_points, robust=v), None,
     r"robust must be True or False, got None"),
    ("calibrate_flange cam_points string", lambda a, v: registration.calibrate_flange(
        v, a["fl"].base_points), "points.csv",
     r"cam_points must be an \(N, 3\) array of points in metres, got the string"),
    ("with_offset min_spread None", lambda a, v: registration.calibrate_flange_with_offset(
        a["fl"].cam_points, a["fl"].base_T_flange, min_spread_deg=v), None,
     r"min_spread_deg must be a finite number >= 0 \(degrees\), got None"),
    ("diagnose_hand_eye full", lambda a, v: diagnostics.diagnose_hand_eye(a["F"], a["C"],
                                                                          full=v),
     "yes", r"full must be True or False, got the string 'yes'"),
    ("diagnose_hand_eye mount array", lambda a, v: diagnostics.diagnose_hand_eye(
        a["F"], a["C"], mount=v), np.zeros(2), r"mount must be one of .*got an array"),
    ("hand_eye_methods problem", lambda a, v: catalog.hand_eye_methods(v), None,
     r"problem must be an autograder.synthetic.HandEyeProblem .*got None"),
    ("hand_eye_methods include_opencv", lambda a, v: catalog.hand_eye_methods(
        a["p"], include_opencv=v), "no", r"include_opencv must be True or False"),
]


def _resolve(label, value, a):
    if isinstance(value, str) and value == "intrinsics":
        from robots.interfaces import Intrinsics
        return Intrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
    if isinstance(value, str) and value == "short" and "cam_T_target" in label:
        return a["pp"].cam_T_target[:3]
    return value


@pytest.mark.parametrize(("label", "call", "bad", "message"), MESSAGE_CASES,
                         ids=[c[0] for c in MESSAGE_CASES])
def test_bad_arguments_are_named_with_what_was_expected_and_what_came(label, call, bad, message):
    a = ARGS()
    with pytest.raises(ValueError, match=message):
        call(a, _resolve(label, bad, a))


@pytest.mark.parametrize(("value", "text"), [
    (None, "None"), ("abc", "the string 'abc'"), (np.zeros((2, 3), np.int32),
                                                  "an array of shape (2, 3) and dtype int32"),
    ([1, 2], "a list of 2 items"), ((), "a tuple of 0 items"), (True, "the boolean True"),
    (2.5, "the number 2.5"), (object(), "an object"), ({}, "a dict"),
])
def test_describe_says_what_came(value, text):
    assert diagnostics.describe(value) == text


# --------------------------------------------------------------------------- lists, ints


def _integer_problem():
    """Eye-in-hand poses whose translations are whole millimetres... in metres: an integer
    array is exact only for identity rotations, so integer-valued data come as rotations
    about the axes by multiples of 90 deg with integer translations."""
    rng = np.random.default_rng(0)
    X = geo.pose_from_rpy(np.pi / 2, 0, np.pi / 2, [0, 0, 1])
    Y = geo.pose_from_rpy(np.pi, 0, 0, [3, 1, 0])
    F = []
    for rpy in ([0, 0, 0], [np.pi / 2, 0, 0], [0, np.pi / 2, 0], [0, 0, np.pi / 2],
                [np.pi / 2, np.pi / 2, 0], [0, np.pi / 2, np.pi / 2]):
        F.append(geo.pose_from_rpy(*rpy, t=rng.integers(-3, 4, 3)))
    F = np.round(np.array(F))
    C = geo.invert(X) @ geo.invert(F) @ Y
    return F.astype(int), np.round(C).astype(int), X


SAME_RESULT_CASES = [
    ("calibrate park", lambda F, C: handeye.calibrate_eye_in_hand(F, C, method="park")),
    ("calibrate tsai", lambda F, C: handeye.calibrate_eye_in_hand(F, C, method="tsai")),
    ("solve_ax_yb li", lambda F, C: robot_world.solve_ax_yb(F, geo.invert(np.asarray(C, float)),
                                                            "li")[0]),
    ("refine_hand_eye", lambda F, C: mle.refine_hand_eye(F, C).X),
]


@pytest.mark.parametrize(("label", "solve"), SAME_RESULT_CASES, ids=[c[0] for c in SAME_RESULT_CASES])
@pytest.mark.parametrize("form", ["list of arrays", "nested lists", "tuple"])
def test_lists_and_tuples_give_the_same_result_as_float_arrays(label, solve, form):
    p = _problem(seed=6, n=8)
    F, C = p.base_T_flange, p.cam_T_target
    convert = {"list of arrays": list, "nested lists": lambda a: a.tolist(),
               "tuple": lambda a: tuple(a)}[form]
    expected = solve(F, C)
    np.testing.assert_allclose(solve(convert(F), convert(C)), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("label", "solve"), SAME_RESULT_CASES[::2],
                         ids=[c[0] for c in SAME_RESULT_CASES[::2]])
def test_integer_arrays_give_the_same_result_as_float_arrays(label, solve):
    F, C, X = _integer_problem()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a few exact 90-degree motions may be dropped
        out_int = solve(F, C)
        out_float = solve(F.astype(float), C.astype(float))
    np.testing.assert_allclose(out_int, out_float, rtol=0, atol=1e-12)
    assert geo.rotation_error_deg(out_int, X) < 1e-6


@pytest.mark.parametrize("form", ["int array", "list", "tuple"])
def test_point_sets_as_lists_and_integers_give_the_same_fit(form):
    rng = np.random.default_rng(1)
    src = rng.integers(-5, 6, (8, 3))
    T = geo.pose_from_rpy(0, 0, np.pi / 2, [1, 2, 3])
    dst = np.round(geo.transform_points(T, src)).astype(int)
    convert = {"int array": lambda a: a, "list": lambda a: a.tolist(),
               "tuple": lambda a: tuple(map(tuple, a))}[form]
    fit = registration.fit_rigid(convert(src), convert(dst))
    np.testing.assert_allclose(fit, registration.fit_rigid(src.astype(float),
                                                           dst.astype(float)), atol=1e-12)
    frame = registration.frame_from_three_points(*convert(np.array([[0, 0, 0], [2, 0, 0],
                                                                    [0, 3, 0]])))
    np.testing.assert_allclose(frame, np.eye(4), atol=1e-12)


@pytest.mark.parametrize("form", ["lists", "int K"])
def test_reprojection_inputs_as_lists_give_the_same_result(form):
    p = _pixel_problem()
    args = _reprojection_args(p)
    expected = mle.refine_reprojection(**args).X
    if form == "lists":
        args.update(board_points=args["board_points"].tolist(), pixels=args["pixels"].tolist(),
                    K=args["K"].tolist(), base_T_flange=list(args["base_T_flange"]))
    else:
        args["K"] = np.round(args["K"] * 2).astype(int) / 2  # 319.5 stays exact
        args["K"] = args["K"].tolist()
    np.testing.assert_allclose(mle.refine_reprojection(**args).X, expected, atol=1e-9)


# --------------------------------------------------------------------------- 2. no false alarm
# Every benchmark problem generator, the real captures and the existing tests' problems pass
# the unit checks; the solvers' entry points run on a sample of them without a unit error.


def _benchmark_scenarios():
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import handeye_accuracy

    return handeye_accuracy.scenarios(quick=False)


def _unit_checks(F, C, mount, pixels=None, board=None, K=None, X=None, Y=None):
    """Run every unit check on one problem (raises on a false alarm); returns the fitted
    scales (pose form, all-pairs motions, consecutive motions)."""
    A, B = diagnostics._to_ax_yb(geo.as_poses(F), geo.as_poses(C), mount)
    fits = [units.check_pose_units(A, B)]
    for strategy in ("all", "consecutive"):
        MA, MB, _ = handeye.hand_eye_motions(F, C, mount, strategy)
        rvA = geo.rotvecs_from_rotations(MA[:, :3, :3])
        rvB = geo.rotvecs_from_rotations(MB[:, :3, :3])
        fits.append(units.check_motion_units(MA, MB, rvA, rvB))
    if pixels is not None:
        valid = np.all(np.isfinite(pixels), axis=2)
        units.check_normalised_pixels(pixels, valid, K)
        H = geo.invert(F) if mount == "eye_in_hand" else F
        units.check_board_distance(board, pixels, valid, K, geo.invert(X) @ H @ Y)
    return fits


def test_no_unit_alarm_on_any_benchmark_scenario():
    scenarios = _benchmark_scenarios()
    assert len(scenarios) == 62
    checked = 0
    for scenario in scenarios:
        for seed in range(3):
            p = scenario.problem(seed)
            fits = _unit_checks(p.base_T_flange, p.cam_T_target, p.mount, p.pixels,
                                None if p.board is None else p.board.object_points(),
                                None if p.camera is None else p.camera.K, p.X_true, p.Y_true)
            # Far from the threshold, not just under it.
            assert all(f.k is None or abs(math.log(f.k)) < math.log(units.UNIT_RATIO) / 2
                       or f.se > 0.3 for f in fits), (scenario, seed, [(f.k, f.se) for f in fits])
            checked += 1
    assert checked == 186


def test_no_unit_alarm_on_the_real_captures():
    import cv2

    from autograder.datasets import RWHE_KUKA_SEQUENCES, load_aubo_flange_capture, load_rwhe_kuka

    for name in RWHE_KUKA_SEQUENCES:
        cap = load_rwhe_kuka(name)
        obj = [cap.board_points_m.astype(np.float32)] * len(cap.pixels)
        img = [px.astype(np.float32) for px in cap.pixels]
        _, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, tuple(cap.image_size_wh),
                                                       None, None)
        C = np.array([geo.make_pose(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs)])
        start = mle.refine_hand_eye(cap.base_T_flange, C)
        fits = _unit_checks(cap.base_T_flange, C, "eye_in_hand", cap.pixels,
                            cap.board_points_m, K, start.X, start.Y)
        assert abs(fits[0].k - 1.0) < 0.06, (name, fits[0].k)
    cam, base = load_aubo_flange_capture()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        registration.calibrate_flange(cam, base)


def _far_fixed_camera(seed, n=10):
    """Eye-to-hand with the camera 2.5-3 m from the base and small robot motions (2 cm, 10-25
    deg), 0.5 deg / 5 mm of camera noise: the geometry where the two sides' translations
    differ most on consistent data."""
    rng = np.random.default_rng(seed)
    eye = np.array([2.6, rng.uniform(-0.5, 0.5), 1.2])
    z = np.array([0.5, 0.0, 0.4]) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    X = geo.make_pose(np.column_stack([x, np.cross(z, x), z]), eye)
    Y = geo.pose_from_rpy(0.1, -0.1, 0.2, [0.0, 0.02, 0.05])
    F = []
    for _ in range(n):
        axis = rng.normal(size=3)
        R = geo.rotation_from_rotvec(np.radians(rng.uniform(10, 25)) * axis / np.linalg.norm(axis))
        F.append(geo.make_pose(R @ geo.pose_from_rpy(np.pi, 0, 0)[:3, :3],
                               [0.5, 0.0, 0.4] + rng.uniform(-0.02, 0.02, 3)))
    F = np.array(F)
    C = geo.invert(X) @ F @ Y
    C = np.array([syn.perturb_pose(T, np.radians(0.5), 0.005, rng) for T in C])
    return F, C, X


def _camera_turning_about_itself(seed, n=10):
    """Eye-in-hand views that turn the camera about its own optical centre (a TCP set at the
    camera): the camera side's translations barely change, so the scale is undetermined."""
    rng = np.random.default_rng(seed)
    X = geo.pose_from_rpy(0.1, 0.2, 0.3, [0.05, -0.03, 0.12])
    centre = np.array([0.5, 0.0, 0.6])
    Y = geo.pose_from_rpy(np.pi, 0, 0.4, [0.5, 0.1, 0.0])
    F = []
    for _ in range(n):
        axis = rng.normal(size=3)
        R = geo.rotation_from_rotvec(np.radians(rng.uniform(5, 20)) * axis / np.linalg.norm(axis))
        base_T_cam = geo.make_pose(R @ geo.pose_from_rpy(np.pi, 0, 0)[:3, :3], centre)
        F.append(base_T_cam @ geo.invert(X))
    F = np.array(F)
    C = geo.invert(X) @ geo.invert(F) @ Y
    C = np.array([syn.perturb_pose(T, np.radians(0.2), 0.002, rng) for T in C])
    return F, C, X


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("make", [_far_fixed_camera, _camera_turning_about_itself],
                         ids=["far fixed camera", "camera turning about itself"])
def test_no_unit_alarm_on_extreme_but_consistent_rigs(make, seed):
    F, C, X = make(seed)
    mount = "eye_to_hand" if make is _far_fixed_camera else "eye_in_hand"
    _unit_checks(F, C, mount)
    solve = handeye.calibrate_eye_to_hand if mount == "eye_to_hand" else handeye.calibrate_eye_in_hand
    X_est = solve(F, C, method="park")
    assert geo.rotation_error_deg(X_est, X) < 2.0
    # ... while the same rig with the robot in millimetres is still caught.
    if make is _far_fixed_camera:
        with pytest.raises(ValueError, match="base_T_flange translations look like millimetres"):
            solve(_scaled(F, 1000.0), C, method="park")


def _entry_sample():
    """One seed of each quick benchmark row, both mounts, plus the generators the existing
    tests use (OpenCV's scenario, the real-like capture, small motions, outliers)."""
    problems = [s.problem(0) for s in _benchmark_scenarios()[::4]]
    problems += [syn.make_opencv_scenario(1, m, 10) for m in handeye.MOUNTS]
    problems += [syn.make_real_like_hand_eye(0, n_poses=12)]
    problems += [syn.make_hand_eye(2, m, 5, syn.NoiseModel(cam_rot_deg=1.0, cam_trans_mm=5.0))
                 for m in handeye.MOUNTS]
    return problems


def test_no_unit_alarm_from_the_solver_entry_points():
    count = 0
    for p in _entry_sample():
        F, C, mount = p.base_T_flange, p.cam_T_target, p.mount
        calls = [lambda: handeye.calibrate_eye_in_hand(F, C, method="park")
                 if mount == "eye_in_hand" else handeye.calibrate_eye_to_hand(F, C, method="park"),
                 lambda: mle.refine_hand_eye(F, C, mount),
                 lambda: robot_world.solve_ax_yb(F, geo.invert(C) if mount == "eye_in_hand"
                                                 else C, "li"),
                 lambda: handeye.solve_ax_xb(*handeye.hand_eye_motions(F, C, mount)[:2], "tsai")]
        if p.pixels is not None and p.noise.pixel_px > 0:
            def reprojection():
                start = mle.refine_hand_eye(F, C, mount)
                return mle.refine_reprojection(p.board.object_points(), p.pixels, p.camera.K,
                                               p.camera.dist, F, mount, X0=start.X, Y0=start.Y,
                                               fit_board_scale=True)
            calls.append(reprojection)
        for call in calls:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                call()  # a unit alarm would raise ValueError here
            assert not [w for w in caught if "look like" in str(w.message)]
            count += 1
    assert count >= 50


def test_no_unit_warning_from_flange_and_three_point_problems():
    count = 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for seed in range(4):
            for noise_mm in (0.0, 0.5, 2.0):
                p = syn.make_flange(seed, n_points=10, noise_mm=noise_mm, depth_noise_mm=noise_mm,
                                    fixed_orientation=bool(seed % 2))
                registration.calibrate_flange(p.cam_points, p.base_points)
                q = syn.make_flange(seed, n_points=12, noise_mm=noise_mm, fixed_orientation=False,
                                    marker_offset_m=[0.01, -0.02, 0.03])
                registration.calibrate_flange_with_offset(q.cam_points, q.base_T_flange)
                t = syn.make_three_point(seed, camera_noise_mm=noise_mm,
                                         pointer_noise_mm=noise_mm, inclined=bool(seed % 2))
                registration.fit_rigid(np.vstack([t.cam_points, t.check_cam]),
                                       np.vstack([t.base_points, t.check_base]))
                count += 3
    assert count == 36
