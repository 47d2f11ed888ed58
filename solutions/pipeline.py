"""The hand-eye calibration of a capture, as a library: capture -> solve -> diagnose -> save.

A notebook and ``cobotlab calibrate`` make the same calls::

    from robots.capture import load_capture
    from solutions import pipeline

    capture = load_capture("my_capture")                  # or robots.pose_files' importer
    result = pipeline.calibrate_capture(capture, "eye_in_hand")   # a Calibration
    result.X, result.held_out.median_px, result.flagged_views
    result.diagnosis.table(), result.diagnosis.board_scale, result.warnings
    pipeline.save_calibration_result(result, capture, "flange_T_cam.yaml")

Each stage returns a typed value (``Calibration``, ``CornerFit``, ``HeldOut``,
``solutions.trust.CalibrationDiagnosis``); the command line only prints them. A capture
whose views cannot be made consistent raises ``solutions.trust.InconsistentCaptureError``
(its ``diagnosis`` the evidence). X is ``flange_T_cam`` (eye-in-hand) or ``base_T_cam`` (eye-to-hand),
metres; view numbers are the capture's ``pose_indices`` (the commanded pose each view came
from), so they name the same views as the capture folder's images.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robots import geometry as geo
from solutions import diagnostics, handeye, mle, trust

#: ``method`` values besides ``solutions.handeye.METHODS``: the default, and the corner fit.
AUTO_METHOD = "auto"
CORNERS_METHOD = "corners"
METHOD_CHOICES = (AUTO_METHOD, CORNERS_METHOD) + tuple(handeye.METHODS)

#: A view whose residual is this many times the median view's is marked large.
LARGE_VIEW_FACTOR = 5.0


@dataclass(frozen=True)
class CornerFit:
    """What the corner fit (``mle.calibrate_from_corners``) chose: ``choice`` (the model
    fitted, with its inner cross-validated score), ``choices`` (every candidate, chosen first),
    ``board_scale`` (the fitted factor on the board's stated size; 1 when not fitted),
    ``reprojection_rms_px`` over all views' corners and ``refinement``, the fit itself (X, Y,
    and the start ``mle.fit_candidate`` refits that model from)."""

    choice: mle.CornerNoiseChoice
    choices: tuple
    board_scale: float
    reprojection_rms_px: float
    refinement: mle.HandEyeRefinement | None = None


@dataclass(frozen=True)
class HeldOut:
    """The held-out error (``mle.held_out_view_rms``, one view left out at a time):
    ``per_view_px`` (n,) RMS pixels of each view's corners predicted through its robot pose by
    a calibration without it; ``views`` the capture's view numbers. ``model_kept``: the corner
    fit's chosen model was refitted as is, not chosen again without the view."""

    per_view_px: np.ndarray
    views: np.ndarray
    model_kept: bool

    @property
    def median_px(self) -> float:
        return float(np.median(self.per_view_px))

    @property
    def p95_px(self) -> float:
        return float(np.percentile(self.per_view_px, 95))

    @property
    def worst_view(self) -> int:
        return int(self.views[int(np.argmax(self.per_view_px))])


@dataclass(frozen=True)
class HalfTurnCheck:
    """Whether each view's corner order was checked against the robot's motion before solving
    (``robots.half_turn``): ``checked``; ``turned_views``, the capture's view numbers whose
    corners were read half a turn round and put back; ``summary``, one line for a person
    (what was done and on what evidence, or why it was not checked)."""

    checked: bool
    turned_views: tuple
    summary: str


def check_half_turns(capture):
    """The capture with each view's corners in the order the robot's motion agrees with, and
    a :class:`HalfTurnCheck`. Done for a target that can be read half a turn round (a plain
    chessboard: ``capture.target.half_turn_ambiguous``); a capture that does not record its
    target (a folder saved before targets were recorded) is returned as it is, and the check
    says the half-turn was not checked, as it does when the corners cannot be resolved (a view
    without the full grid, a square grid)."""
    from solutions.capture_import import _resolve_half_turns  # the import's own wording

    target = capture.target
    if target is None:
        return capture, HalfTurnCheck(False, (), (
            "not checked: the capture does not record its target (saved before targets were "
            "recorded); if it is a chessboard, a view with the camera rolled past 90 deg may "
            "have its corners reversed: capture or import it again, or pass it through "
            "robots.half_turn.resolve_capture_half_turns"))
    if not target.half_turn_ambiguous:
        return capture, HalfTurnCheck(True, (), f"not needed: a {target.kind}'s corners have "
                                                "one order")
    try:
        resolved, choice, decision = _resolve_half_turns(capture)
    except ValueError as exc:
        return capture, HalfTurnCheck(False, (), f"not checked: {exc}")
    turned = tuple(int(capture.pose_indices[k]) for k in choice.changed)
    return resolved, HalfTurnCheck(True, turned, str(decision))


@dataclass(frozen=True)
class Calibration:
    """A solved capture. ``X`` (4, 4) m: ``flange_T_cam`` (eye_in_hand) or ``base_T_cam``
    (eye_to_hand), by ``method`` (``method_note`` says why, for ``auto``). ``views`` (n,): the
    capture's view numbers of the n views with a target pose. ``rotation_residual``
    (Frobenius^2) and ``translation_residual`` (m^2) on the motions;
    ``view_rotation_deg``/``view_translation_m`` (n,): each view's residual (the board pose it
    implies against their mean, ``per_pose_residuals``). ``flagged_views``: the views the
    robust solver down-weighted; ``large_views``: the others far above the typical view.
    ``corner_fit`` and ``held_out`` are None when the method or the capture has no corners
    for them; ``mount_warning`` is "" unless the views cannot tell the mounts apart.
    ``diagnosis``: the corner fit's ``solutions.trust.CalibrationDiagnosis`` (each view's
    residual fitted and held out, the views distrusted and why, the board's scale against
    its stated size with X both ways), None for the pose-based methods. ``half_turn``: the
    corner order's check (:func:`check_half_turns`), None when it was not asked for."""

    X: np.ndarray
    mount: str
    method: str
    method_note: str
    views: np.ndarray
    rotation_residual: float
    translation_residual: float
    view_rotation_deg: np.ndarray
    view_translation_m: np.ndarray
    flagged_views: tuple
    large_views: tuple
    corner_fit: CornerFit | None
    held_out: HeldOut | None
    mount_warning: str
    diagnosis: trust.CalibrationDiagnosis | None = None
    half_turn: HalfTurnCheck | None = None

    @property
    def warnings(self) -> tuple[str, ...]:
        """Everything the user must be told: the mount warning and the diagnosis's."""
        found = (self.mount_warning,) if self.mount_warning else ()
        return found + (self.diagnosis.warnings if self.diagnosis is not None else ())

    @property
    def parent(self) -> str:
        """The frame X is expressed in: ``flange`` or ``base``."""
        return "flange" if self.mount == "eye_in_hand" else "base"


def per_pose_residuals(base_T_flange, cam_T_target, X, mount: str = "eye_in_hand"):
    """How far each pose disagrees with a hand-eye result X: (rotation_deg (n,), translation_m (n,)).

    The pose that X and each view imply for the fixed "other" frame (eye-in-hand: the board in
    the base frame, ``base_T_flange[i] @ X @ cam_T_target[i]``; eye-to-hand: the board in the
    flange frame, ``inv(base_T_flange[i]) @ X @ cam_T_target[i]``) should be the same for every
    view; the residual is each view's distance from their mean. A pose far above the others
    is a bad view (blurred corners, a wrong robot reading).
    """
    F = geo.as_poses(base_T_flange, "base_T_flange")
    C = geo.as_poses(cam_T_target, "cam_T_target")
    if len(F) != len(C):
        raise ValueError(f"{len(F)} flange poses but {len(C)} target poses; give one of each "
                         "per view")
    if mount == "eye_in_hand":
        implied = F @ geo.as_pose(X, "X") @ C
    elif mount == "eye_to_hand":
        implied = geo.invert(F) @ geo.as_pose(X, "X") @ C
    else:
        raise ValueError(f"mount must be 'eye_in_hand' or 'eye_to_hand', got {mount!r}")
    mean = geo.make_pose(geo.chordal_mean_rotation(implied), implied[:, :3, 3].mean(axis=0))
    return geo.rotation_error_deg(implied, mean), geo.translation_error(implied, mean)


# --------------------------------------------------------------------------- the stages


def check_choices(mount: str, method: str) -> None:
    """``ValueError`` naming the choices for an unknown mount or method."""
    if mount not in handeye.MOUNTS:
        raise ValueError(f"--mount must be eye_in_hand or eye_to_hand, got {mount!r}")
    if method not in METHOD_CHOICES:
        raise ValueError(f"unknown --method {method!r}; choose one of {', '.join(METHOD_CHOICES)}")


def auto_method(capture, kept) -> tuple[str, str]:
    """``method="auto"``: (the method, a note saying why) for this capture.

    The corner fit wins on the real captures of benchmarks/handeye_real.py (the pose-based
    ``nonlinear`` is the best of the rest there), but it needs every view's corners.
    """
    short = [int(capture.pose_indices[i]) for i in kept if len(capture.corners_px[i]) < 4]
    if len(kept) >= 4 and not short:
        return CORNERS_METHOD, " (auto: every view has its board corners)"
    if len(short) == len(kept):
        why = "no view has board corners (4 or more): the capture holds poses only"
    elif short:
        why = f"views {short} have fewer than 4 corners"
    else:
        why = f"only {len(kept)} views, the corner fit's cross-validation needs 4"
    return "nonlinear", f" (auto: {why})"


def mount_warning(F, C, mount: str) -> str:
    """Refuse views that fit the other mount far better; return a warning when they fit both
    about equally (``solutions.diagnostics``, the check every hand-eye solver makes), else ""."""
    d = diagnostics.diagnose_hand_eye(F, C, mount, full=True)
    other = "eye_to_hand" if mount == "eye_in_hand" else "eye_in_hand"
    if d.verdict == "flipped":
        raise ValueError(
            f"these views fit --mount {other} far better (median rotation residual "
            f"{d.flipped_residual_deg:.3g} deg per view against {d.residual_deg:.3g} deg, "
            f"{d.ratio:.0f} times what their noise explains): check where the camera is mounted, "
            "and that base_T_flange is not inverted (flange_T_base) nor cam_T_target "
            "(target_T_cam)")
    if d.verdict == "ok" and diagnostics.mounts_indistinguishable(d):
        return (f"WARNING: these views fit --mount {other} as well (median rotation residual "
                f"{d.flipped_residual_deg:.3g} deg against {d.residual_deg:.3g} deg), so they "
                "cannot tell the two mounts apart and the result rests on --mount being right. "
                "Add views that roll the camera about its viewing axis (15-45 deg) to make it "
                "unambiguous")
    return ""


def board_corners(capture, kept) -> tuple[np.ndarray, np.ndarray]:
    """One board for the kept views: (board_points (N, 3) m, the distinct object points of all
    views; pixels (n, N, 2), each view's corners at their board index, NaN where unseen). A
    ChArUco board or a board partly out of view gives each view a different subset."""
    objects = [np.asarray(capture.object_points[i], dtype=float) for i in kept]
    corners = [np.asarray(capture.corners_px[i], dtype=float) for i in kept]
    board, index = np.unique(np.round(np.concatenate(objects), 9), axis=0, return_inverse=True)
    pixels = np.full((len(kept), len(board), 2), np.nan)
    start = 0
    for k, c in enumerate(corners):
        pixels[k, index.ravel()[start:start + len(c)]] = c
        start += len(c)
    return board, pixels


def _corner_fit(board, pixels, K, dist, F, C, mount: str):
    """``method="corners"``: (the chosen model's ``HandEyeRefinement``, a ``CornerFit``, the
    raw candidate list ``choices`` of ``mle.calibrate_from_corners``)."""
    fit, choices = mle.calibrate_from_corners(board, pixels, K, dist, F, mount, C)
    summary = CornerFit(choice=choices[0], choices=tuple(choices), board_scale=fit.board_scale,
                        reprojection_rms_px=fit.reprojection_rms_px, refinement=fit)
    return fit, summary, choices


def _pose_refit(solve, method: str, F, C, mount: str):
    """``refit(keep)`` for a pose-based method: its X on those views, and the board pose Y
    (base_T_target eye-in-hand, flange_T_target eye-to-hand) as the mean of what they imply."""
    H = geo.invert(F) if mount == "eye_in_hand" else F

    def refit(keep):
        X = solve(F[keep], C[keep], method=method).X
        implied = geo.invert(H[keep]) @ X @ C[keep]
        Y = geo.make_pose(geo.chordal_mean_rotation(implied), implied[:, :3, 3].mean(axis=0))
        return mle.HandEyeRefinement(X=X, Y=Y, mount=mount, rotation_sigma_rad=0.0,
                                     translation_sigma_m=0.0, weights=np.ones(int(keep.sum())),
                                     outlier_indices=(), cost=float("nan"), n_iterations=0,
                                     converged=True)

    return refit


def held_out_error(refit, board, pixels, capture, F, views, model_kept: bool) -> HeldOut:
    """Leave-one-view-out ``mle.held_out_view_rms`` of ``refit(keep)`` on the capture's
    intrinsics."""
    def quiet(keep):
        with warnings.catch_warnings():  # the full fit has already warned about these views
            warnings.simplefilter("ignore", UserWarning)
            return refit(keep)

    rms = mle.held_out_view_rms(quiet, board, pixels, capture.intrinsics.K,
                                capture.intrinsics.dist, F)
    return HeldOut(per_view_px=rms, views=np.asarray(views), model_kept=model_kept)


def _diagnose(fit, choices, board, pixels, capture, F, views, mount: str):
    """``trust.diagnose_corner_calibration`` with the capture's view numbers (not 0..n-1) in
    its rows and sentences; an ``InconsistentCaptureError`` keeps them too."""
    i = capture.intrinsics
    size = (i.width, i.height)
    try:
        d = trust.diagnose_corner_calibration(fit, choices, board, pixels, i.K, i.dist, F, mount,
                                              size)
    except trust.InconsistentCaptureError as error:
        named = _with_view_numbers(error.diagnosis, views)
        raise trust.InconsistentCaptureError(named.warnings[0], named) from None
    return _with_view_numbers(d, views)


def _with_view_numbers(d: trust.CalibrationDiagnosis, views) -> trust.CalibrationDiagnosis:
    """``d`` with the capture's view numbers; its warnings rebuilt from the typed values in
    the order ``trust`` gives them (the refusal, the distrusted views, the board scale)."""
    import dataclasses

    number = [int(v) for v in views]
    rows = tuple(dataclasses.replace(v, index=number[v.index]) for v in d.views)
    texts = ((d.warnings[0],) if not d.consistent else ()) + tuple(
        f"view {v.index}: {v.why}" for v in rows if v.distrusted)
    if d.board_scale is not None and d.board_scale.off:
        texts += (d.board_scale.message(),)
    return dataclasses.replace(d, views=rows, distrusted=tuple(number[k] for k in d.distrusted),
                               warnings=texts)


def calibrate_capture(capture, mount: str = "eye_in_hand", method: str = AUTO_METHOD,
                      source: str = "the capture") -> Calibration:
    """Solve a ``robots.capture.Capture``: X, the residual of each view, the views the robust
    solver flagged, (when every view has 4 or more corners) the held-out error, and for the
    corner fit its diagnosis (``solutions.trust.diagnose_corner_calibration``). First, a
    chessboard's corner order is checked against the robot's motion (:func:`check_half_turns`;
    ``result.half_turn`` says what was done).

    ``method``: one of ``METHOD_CHOICES``; ``auto`` is the corner fit when every view with a
    target pose kept 4 or more corners and there are at least 4 such views, else
    ``nonlinear``. ``source`` names the capture in messages. ``ValueError`` for too few
    views, a mount the views contradict, or corners too few for ``corners``;
    ``solutions.trust.InconsistentCaptureError`` (a ValueError, its ``diagnosis`` the evidence)
    when the corner fit's views cannot be made consistent.
    """
    check_choices(mount, method)
    capture, half_turn = check_half_turns(capture)
    has_pose = np.all(np.isfinite(capture.cam_T_target), axis=(1, 2))
    F, C = capture.pose_pairs()
    views = capture.pose_indices[has_pose]
    if len(F) < 3:
        raise ValueError(f"{source} has {len(F)} views with a target pose; a hand-eye "
                         "calibration needs at least 3 (better 10-15) with varied orientations")
    warning = mount_warning(F, C, mount)
    solve = (handeye.calibrate_eye_in_hand_report if mount == "eye_in_hand"
             else handeye.calibrate_eye_to_hand_report)
    kept = np.flatnonzero(has_pose)
    note = ""
    if method == AUTO_METHOD:
        method, note = auto_method(capture, kept)
    with_corners = all(len(capture.corners_px[i]) >= 4 for i in kept)
    if method == CORNERS_METHOD and not with_corners:
        raise ValueError("--method corners needs at least 4 detected corners in every view with "
                         "a board pose; use another --method or drop those views")
    board, pixels = board_corners(capture, kept) if with_corners else (None, None)
    K, dist = capture.intrinsics.K, capture.intrinsics.dist
    corner_fit = diagnosis = None
    if method == CORNERS_METHOD:
        fit, corner_fit, choices = _corner_fit(board, pixels, K, dist, F, C, mount)

        def refit(keep):  # the chosen model as it is (its intrinsics too), on fewer views
            return mle.fit_candidate(choices[0], board, pixels[keep], K, dist, F[keep],
                                     C[keep], mount, fit)

        diagnosis = _diagnose(fit, choices, board, pixels, capture, F, views, mount)
        X, outliers = fit.X, fit.outlier_indices
        A, B, _ = handeye.hand_eye_motions(F, C, mount)
        rotation_residual = handeye.rotation_residual(A, B, X)
        translation_residual = handeye.translation_residual(A, B, X)
    else:
        report = solve(F, C, method=method)
        X, outliers = report.X, report.outlier_pose_indices
        rotation_residual = report.rotation_residual
        translation_residual = report.translation_residual
        refit = _pose_refit(solve, method, F, C, mount)
    rot, trans = per_pose_residuals(F, C, X, mount)
    flagged = tuple(int(views[i]) for i in outliers)
    typical = max(float(np.median(trans)) * LARGE_VIEW_FACTOR, 1e-3)
    large = tuple(int(v) for v, t in zip(views, trans) if t > typical and int(v) not in flagged)
    held_out = None
    diagnosed = (np.array([v.held_out_px for v in diagnosis.views]) if diagnosis is not None
                 else None)
    if len(F) >= 4 and diagnosed is not None and np.all(np.isfinite(diagnosed)):
        # The diagnosis has already refitted the chosen model without each view and predicted
        # it: the same numbers mle.held_out_view_rms gives (tests/test_import_targets_cli.py),
        # so the corner fit's n refits are not done twice.
        held_out = HeldOut(per_view_px=diagnosed, views=np.asarray(views), model_kept=True)
    elif len(F) >= 4 and with_corners:
        held_out = held_out_error(refit, board, pixels, capture, F, views,
                                  model_kept=method == CORNERS_METHOD)
    return Calibration(X=X, mount=mount, method=method, method_note=note, views=views,
                       rotation_residual=float(rotation_residual),
                       translation_residual=float(translation_residual),
                       view_rotation_deg=rot, view_translation_m=trans, flagged_views=flagged,
                       large_views=large, corner_fit=corner_fit, held_out=held_out,
                       mount_warning=warning, diagnosis=diagnosis, half_turn=half_turn)


def save_calibration_result(result: Calibration, capture, path) -> Path:
    """Write ``result`` with ``robots.calibration_io.save_calibration`` (parent frame, "cam",
    method, the number of views, the residuals, the capture's robot and camera names)."""
    from robots.calibration_io import save_calibration

    path = Path(path)
    save_calibration(path, result.X, result.parent, "cam", result.method, len(result.views),
                     {"rotation_residual": result.rotation_residual,
                      "translation_residual_m2": result.translation_residual,
                      "per_pose_rotation_deg": result.view_rotation_deg,
                      "per_pose_translation_m": result.view_translation_m},
                     robot_id=capture.robot_name, camera_id=capture.camera_name)
    return path
