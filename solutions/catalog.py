"""Every hand-eye method, by label, ready to run on a synthetic problem.

One list serves the demo, the benchmark and the autograder's self-check, so they always compare
the same methods on the same data. Each entry is ``(label, solve)`` where ``solve()`` returns
X (``flange_T_cam`` for eye-in-hand, ``base_T_cam`` for eye-to-hand) or a result object with
an ``X`` attribute (and, for the robust default, ``outlier_pose_indices``).
"""

from __future__ import annotations

from collections.abc import Callable

from robots import geometry as geo

DEFAULT_METHOD = "nonlinear"
CLOSED_FORM_METHODS = ("tsai", "park", "daniilidis", "axes_ls")


def hand_eye_methods(problem, include_opencv: bool = True) -> list[tuple[str, Callable]]:
    """(label, solve) for our methods on ``problem`` (an ``autograder.synthetic.HandEyeProblem``),
    then OpenCV's when ``include_opencv``. Methods needing corner pixels are left out when the
    problem has none."""
    from solutions import diagnostics, handeye, mle, robot_world

    if not all(hasattr(problem, a) for a in ("base_T_flange", "cam_T_target", "mount")):
        raise ValueError("problem must be an autograder.synthetic.HandEyeProblem (with "
                         "base_T_flange, cam_T_target and mount), got "
                         f"{diagnostics.describe(problem)}")
    include_opencv = diagnostics.check_flag(include_opencv, "include_opencv")
    robot, cam, mount = problem.base_T_flange, problem.cam_T_target, problem.mount
    if mount == "eye_in_hand":
        report = handeye.calibrate_eye_in_hand_report
    else:
        report = handeye.calibrate_eye_to_hand_report

    rows: list[tuple[str, Callable]] = [
        (method, lambda m=method: report(robot, cam, method=m)) for method in CLOSED_FORM_METHODS
    ]
    rows.append((DEFAULT_METHOD, lambda: report(robot, cam, method=DEFAULT_METHOD)))

    # AX=YB with A = base_T_flange: eye-in-hand B = target_T_cam, and our X is its X;
    # eye-to-hand B = cam_T_target, and our X (base_T_cam) is its Y.
    B = geo.invert(cam) if mount == "eye_in_hand" else cam

    def ax_yb(method):
        X, Y = robot_world.solve_ax_yb(robot, B, method=method)
        return X if mount == "eye_in_hand" else Y

    rows += [(f"ax_yb {m}", lambda m=m: ax_yb(m)) for m in ("shah", "li", "nonlinear")]

    if getattr(problem, "pixels", None) is not None and problem.noise.pixel_px > 0:
        def reprojection():
            start = mle.refine_hand_eye(robot, cam, mount=mount)
            return mle.refine_reprojection(
                problem.board.object_points(), problem.pixels, problem.camera.K,
                problem.camera.dist, robot, mount=mount, X0=start.X, Y0=start.Y)

        rows.append(("refine_reprojection", reprojection))

    if include_opencv:
        from solutions.opencv_baseline import (
            HAND_EYE_METHODS,
            ROBOT_WORLD_METHODS,
            opencv_hand_eye,
            opencv_robot_world,
        )

        rows += [(f"opencv {m}", lambda m=m: opencv_hand_eye(robot, cam, mount, m))
                 for m in HAND_EYE_METHODS]
        rows += [(f"opencv RW {m}", lambda m=m: opencv_robot_world(robot, cam, mount, m)[0])
                 for m in ROBOT_WORLD_METHODS]
    return rows
