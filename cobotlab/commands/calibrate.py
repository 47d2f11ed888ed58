"""``cobotlab calibrate``: solve a saved capture folder, print X and its diagnosis, save it.

The calibration itself is ``solutions.pipeline.calibrate_capture``; this module prints it.
Nothing heavy is imported before the command runs, so ``cobotlab --help`` stays quick.
"""

from __future__ import annotations

from pathlib import Path

# The method names, for --help (solutions.pipeline holds the same, and checks them).
AUTO_METHOD = "auto"
CORNERS_METHOD = "corners"


def add_parser(sub) -> None:
    cal = sub.add_parser(
        "calibrate",
        help="solve the hand-eye calibration of a saved capture folder and write the YAML",
        description=(
            "Load a capture folder written by robots.capture (poses.npz, images/, meta.yaml), "
            "solve X (flange_T_cam for eye_in_hand, base_T_cam for eye_to_hand), print it with "
            "the residual of each view and the views the robust solver flagged, and save it "
            "with robots.calibration_io."
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


def run(args) -> None:
    from cobotlab.demo import require_solutions
    from robots.capture import load_capture

    require_solutions("calibrate")
    from solutions import pipeline

    pipeline.check_choices(args.mount, args.method)
    capture = load_capture(args.capture_dir)
    result = pipeline.calibrate_capture(capture, args.mount, args.method,
                                        source=str(args.capture_dir))
    print_calibration(result, capture, args.capture_dir)
    out = Path(args.out) if args.out else Path(args.capture_dir) / f"{result.parent}_T_cam.yaml"
    pipeline.save_calibration_result(result, capture, out)
    print(f"saved {out}")


def print_calibration(result, capture, source) -> None:
    """Print a ``solutions.pipeline.Calibration``: X, the residuals, the flagged views, the
    corner fit's choice and the held-out error."""
    import numpy as np

    from robots.geometry import rpy_from_pose

    X, views = result.X, result.views
    print(f"capture: {source} ({capture.robot_name or 'robot ?'}, "
          f"{capture.camera_name or 'camera ?'}, {len(views)} views, "
          f"{len(capture.failed_indices)} failed at capture)")
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
    if result.mount_warning:
        print(result.mount_warning)
