"""``cobotlab demo``: every hand-eye method on one seeded problem per mount, against the truth.

Until the simulator chain lands this runs on synthetic data: board corners projected through a
pinhole camera with pixel noise (poses from ``cv2.solvePnP``, as on a real rig) and robot poses
with encoder-level noise.
"""

from __future__ import annotations

import time

from autograder.synthetic import NoiseModel, make_hand_eye
from robots import geometry as geo


def _solvers(problem):
    """(label, callable returning X) for every method, ours first, then OpenCV's."""
    from solutions import handeye, mle, robot_world
    from solutions.opencv_baseline import (HAND_EYE_METHODS, ROBOT_WORLD_METHODS,
                                           opencv_hand_eye, opencv_robot_world)

    robot, cam, mount = problem.base_T_flange, problem.cam_T_target, problem.mount
    calibrate = handeye.calibrate_eye_in_hand if mount == "eye_in_hand" else handeye.calibrate_eye_to_hand
    rows = [(f"{m}", lambda m=m: calibrate(robot, cam, method=m))
            for m in ("tsai", "park", "daniilidis", "axes_ls", "nonlinear")]
    A, B = robot, (geo.invert(cam) if mount == "eye_in_hand" else cam)

    def ax_yb(method):
        X, Y = robot_world.solve_ax_yb(A, B, method=method)
        return X if mount == "eye_in_hand" else Y  # eye_to_hand's AX=YB unknowns are swapped

    rows += [(f"ax_yb/{m}", lambda m=m: ax_yb(m)) for m in ("shah", "li", "nonlinear")]

    def reprojection():
        X0 = calibrate(robot, cam, method="nonlinear")
        return mle.refine_reprojection(
            problem.board.object_points(), problem.pixels, problem.camera.K, problem.camera.dist,
            robot, mount=mount, X0=X0).X

    rows.append(("refine_reprojection", reprojection))
    rows += [(f"opencv {m}", lambda m=m: opencv_hand_eye(robot, cam, mount, m)) for m in HAND_EYE_METHODS]
    rows += [(f"opencv RW {m}", lambda m=m: opencv_robot_world(robot, cam, mount, m)[0])
             for m in ROBOT_WORLD_METHODS]
    return rows


def run_demo(seed: int = 0, n_poses: int = 15, pixel_px: float = 0.3,
             robot_rot_deg: float = 0.05, robot_trans_mm: float = 0.2) -> None:
    """Print, per mount and method, the rotation (deg) and translation (mm) error of X."""
    noise = NoiseModel(pixel_px=pixel_px, robot_rot_deg=robot_rot_deg, robot_trans_mm=robot_trans_mm)
    print(f"cobotlab demo: seed {seed}, {n_poses} poses, pixel noise {pixel_px} px, "
          f"robot noise {robot_rot_deg} deg / {robot_trans_mm} mm per axis")
    for mount in ("eye_in_hand", "eye_to_hand"):
        problem = make_hand_eye(seed, mount, n_poses=n_poses, noise=noise)
        unknown = "flange_T_cam" if mount == "eye_in_hand" else "base_T_cam"
        print(f"\n{mount}: error of {unknown} against the truth")
        print(f"  {'method':<22}{'rotation (deg)':>15}{'translation (mm)':>18}{'time (ms)':>11}")
        for label, solve in _solvers(problem):
            start = time.perf_counter()
            try:
                X = solve()
            except Exception as exc:  # a method refusing this data is a result worth showing
                print(f"  {label:<22}  failed: {exc}")
                continue
            ms = (time.perf_counter() - start) * 1000
            print(f"  {label:<22}{geo.rotation_error_deg(X, problem.X_true):>15.4f}"
                  f"{geo.translation_error(X, problem.X_true) * 1000:>18.3f}{ms:>11.1f}")
    print("\nThe default method is 'nonlinear'; 'refine_reprojection' also uses the raw corners.")
