"""``cobotlab calibrate``: solve a saved capture folder, print X and its diagnosis, save it.

The calibration itself is ``solutions.pipeline.calibrate_capture``; this module prints it.
Nothing heavy is imported before the command runs, so ``cobotlab --help`` stays quick.
"""

from __future__ import annotations

from pathlib import Path

# The method names, for --help (solutions.pipeline holds the same, and checks them).
AUTO_METHOD = "auto"
CORNERS_METHOD = "corners"

#: The exit status when the capture's views cannot be made consistent (the evidence is
#: printed); 2 is every other error's (cobotlab.cli).
INCONSISTENT_EXIT = 3


def add_parser(sub) -> None:
    cal = sub.add_parser(
        "calibrate",
        help="solve the hand-eye calibration of a saved capture folder and write the YAML",
        description=(
            "Load a capture folder written by robots.capture (poses.npz, images/, meta.yaml), "
            "solve X (flange_T_cam for eye_in_hand, base_T_cam for eye_to_hand), print it with "
            "the residual of each view, the views the robust solver flagged and, for the "
            "corner fit, its diagnosis (each view's held-out error, the views distrusted and "
            "why, the board's fitted scale against its stated size with X both ways), and "
            "save it with robots.calibration_io. A capture whose views cannot be made "
            f"consistent is refused with the evidence (exit status {INCONSISTENT_EXIT})."
        ),
    )
    cal.add_argument("capture_dir", metavar="CAPTURE_DIR", help="a folder written by save_capture")
    cal.add_argument("--mount", default="eye_in_hand",
                     help="eye_in_hand (camera on the flange, default) or eye_to_hand")
    cal.add_argument("--method", default=AUTO_METHOD,
                     help="auto (default): corners when every view kept its board corners "
                          "(4 or more) and there are at least 4 views, else nonlinear; "
                          "corners: fit the detected corners themselves, the model (pixel-only, "
                          "a robot-error prior, the board's scale, or a pose-based fit) chosen "
                          "by held-out views (solutions.mle.calibrate_from_corners; best on the "
                          "real captures of benchmarks/handeye_real.py); nonlinear (robust, on "
                          "the board poses); tsai, park, daniilidis, axes_ls")
    cal.add_argument("--out", default=None,
                     help="result YAML (default CAPTURE_DIR/flange_T_cam.yaml or base_T_cam.yaml)")


def run(args) -> int:
    """Calibrate, print, save; 0, or ``INCONSISTENT_EXIT`` for a refused capture."""
    import sys

    from cobotlab.demo import require_solutions
    from robots.capture import load_capture

    require_solutions("calibrate")
    from solutions import pipeline, trust

    pipeline.check_choices(args.mount, args.method)
    capture = load_capture(args.capture_dir)
    try:
        result = pipeline.calibrate_capture(capture, args.mount, args.method,
                                            source=str(args.capture_dir))
    except trust.InconsistentCaptureError as refused:
        print_diagnosis(refused.diagnosis)
        print(f"cobotlab: error: refused, nothing saved: {refused}", file=sys.stderr)
        return INCONSISTENT_EXIT
    print_calibration(result, capture, args.capture_dir)
    out = Path(args.out) if args.out else Path(args.capture_dir) / f"{result.parent}_T_cam.yaml"
    pipeline.save_calibration_result(result, capture, out)
    print(f"saved {out}")
    return 0


def print_diagnosis(diagnosis) -> None:
    """Print a ``solutions.trust.CalibrationDiagnosis``: each view's corner error under the
    fit and held out, the distrusted views and why, the board scale, the warnings."""
    print(f"diagnosis of the corner fit ({diagnosis.model}): RMS corner error per view, px")
    print("  view      fit  held-out")
    for view, fit, held, why in diagnosis.table():
        print(f"  {view:4d} {fit:8.2f} {held:9.2f}" + ("  <- distrusted" if why else ""))
    print(f"distrusted views: {list(diagnosis.distrusted) or 'none'}")
    scale = diagnosis.board_scale
    if scale is not None:
        print(f"board scale: {scale.scale:.4f} x the stated size"
              + (" (past 1 %, see the warning)" if scale.off else " (within 1 %)"))
    for warning in diagnosis.warnings:
        print(f"WARNING: {warning}")


def print_calibration(result, capture, source) -> None:
    """Print a ``solutions.pipeline.Calibration``: X, the residuals, the flagged views, the
    corner fit's choice and the held-out error."""
    import numpy as np

    from robots.geometry import rpy_from_pose

    X, views = result.X, result.views
    print(f"capture: {source} ({capture.robot_name or 'robot ?'}, "
          f"{capture.camera_name or 'camera ?'}, {len(views)} views, "
          f"{len(capture.failed_indices)} failed at capture)")
    if result.half_turn is not None:
        print(f"half-turn of the corner order: {result.half_turn.summary}")
    print(f"{result.parent}_T_cam by {result.method} ({result.mount}){result.method_note}:")
    for row in X:
        print("  [" + "  ".join(f"{v:11.6f}" for v in row) + "]")
    print("translation (mm): " + "  ".join(f"{v:.2f}" for v in X[:3, 3] * 1000))
    print("rpy (deg, R = Rz(yaw) Ry(pitch) Rx(roll)): "
          + "  ".join(f"{v:.3f}" for v in rpy_from_pose(X, degrees=True)))
    print(f"motion residuals: rotation {result.rotation_residual:.3g} (Frobenius^2), "
          f"translation {np.sqrt(result.translation_residual) * 1000:.3f} mm (rms)")
    print("residual per view (the board pose each view implies vs their mean):")
    for view, r, t in zip(views, result.view_rotation_deg, result.view_translation_m):
        mark = ("  <- flagged by the robust solver" if int(view) in result.flagged_views
                else "  <- large" if int(view) in result.large_views else "")
        print(f"  view {int(view):3d}: {t * 1000:8.3f} mm {r:8.4f} deg{mark}")
    print(f"flagged views: {list(result.flagged_views) or 'none'}")
    fit = result.corner_fit
    if fit is not None:
        print(f"corner fit: {fit.choice.label} chosen by held-out views "
              f"({fit.choice.held_out_px:.3f} px; next best: "
              + ", ".join(f"{c.label} {c.held_out_px:.3f} px" for c in fit.choices[1:3])
              + f"); corner RMS {fit.reprojection_rms_px:.3f} px, board scale "
              f"{fit.board_scale:.4f}")
    held = result.held_out
    if held is not None:
        kept = ", the chosen model kept" if held.model_kept else ""
        print(f"held-out error (each view's corners predicted by a calibration without it{kept}, "
              f"through the robot pose): median {held.median_px:.2f} px, "
              f"p95 {held.p95_px:.2f} px, worst view {held.worst_view} at "
              f"{held.per_view_px.max():.2f} px")
    if result.diagnosis is not None:
        print_diagnosis(result.diagnosis)
    if result.mount_warning:
        print(result.mount_warning)
