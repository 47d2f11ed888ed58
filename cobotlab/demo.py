"""``cobotlab demo``: every hand-eye method on one seeded problem per mount, against the truth.

Until the simulator chain lands this runs on synthetic data: board corners projected through a
pinhole camera with pixel noise (poses from ``cv2.solvePnP``, as on a real rig) and robot poses
with encoder-level noise.
"""

from __future__ import annotations

import time

from autograder.synthetic import NoiseModel, make_hand_eye
from robots import geometry as geo
from solutions.catalog import DEFAULT_METHOD, hand_eye_methods


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
        for label, solve in hand_eye_methods(problem):
            start = time.perf_counter()
            try:
                result = solve()
            except Exception as exc:  # a method refusing this data is a result worth showing
                print(f"  {label:<22}  failed: {exc}")
                continue
            ms = (time.perf_counter() - start) * 1000
            X = getattr(result, "X", result)
            print(f"  {label:<22}{geo.rotation_error_deg(X, problem.X_true):>15.4f}"
                  f"{geo.translation_error(X, problem.X_true) * 1000:>18.3f}{ms:>11.1f}")
    print(f"\nThe default method is '{DEFAULT_METHOD}'; 'refine_reprojection' also uses the raw corners.")
