"""What `cobotlab data import` decides about a pose file, measured on the real captures.

Run:  .venv/bin/python benchmarks/pose_import_conventions.py [--views 8] [--subsets 5] [--seed 0]

Each shipped real sequence (rwhe_kuka's kuka_1, kuka_2, kuka_3: eye-in-hand, base_T_flange in
metres) is written out in every layout and convention the importer reads: 4 x 4 matrices,
rotation vectors in radians or degrees, unlabelled quaternions xyzw or wxyz; metres or
millimetres; base_T_flange or its inverse. ``solutions.capture_import.import_capture`` (with
``--mount eye_in_hand``, nothing else given) must read each back to the true poses, or ask for
a flag; it must never read one wrong. Per sequence, on all its views and on ``--subsets``
random subsets of ``--views`` views (small captures are where the data says least), the table
counts right / asked / WRONG. WRONG must be 0; "asked" is the price of never guessing.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from autograder.datasets import load_rwhe_kuka
from robots import geometry as geo
from solutions.capture_import import import_capture

LAYOUTS = ("matrix", "rotvec rad", "rotvec deg", "quat xyzw", "quat wxyz")


def _rows(F: np.ndarray, layout: str, unit: str, inverse: bool) -> np.ndarray:
    T = geo.invert(F) if inverse else F
    t = T[:, :3, 3] * (1000.0 if unit == "mm" else 1.0)
    rotation = Rotation.from_matrix(T[:, :3, :3])
    if layout == "matrix":
        M = T.copy()
        M[:, :3, 3] = t
        return M.reshape(len(T), 16)
    if layout.startswith("rotvec"):
        return np.hstack([t, rotation.as_rotvec(degrees=layout.endswith("deg"))])
    q = rotation.as_quat()
    return np.hstack([t, q if layout.endswith("xyzw") else np.roll(q, 1, axis=1)])


def _outcome(F, corners_file, folder: Path, layout, unit, inverse) -> str:
    poses = folder / "poses.txt"
    np.savetxt(poses, _rows(F, layout, unit, inverse), fmt="%.12g")
    try:
        imported = import_capture(poses, corners=corners_file, mount="eye_in_hand")
    except ValueError as error:
        if "pass --" in str(error):
            return "asked"
        raise
    got = imported.capture.base_T_flange
    want = F[imported.capture.pose_indices]
    right = (np.max(geo.translation_error(got, want)) < 1e-6
             and np.max(geo.rotation_error_deg(got, want)) < 1e-6)
    return "right" if right else "WRONG"


def _subset_corners(sequence: str, views: np.ndarray, folder: Path) -> Path:
    source = resources.files("autograder").joinpath("data", "rwhe_kuka", sequence, "corners.npz")
    with resources.as_file(source) as path, np.load(path) as data:
        out = folder / "corners.npz"
        np.savez(out, corners_px=data["corners_px"][views],
                 board_points_m=data["board_points_m"], image_size_wh=data["image_size_wh"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8, help="views per random subset")
    parser.add_argument("--subsets", type=int, default=5, help="random subsets per sequence")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    cases = list(itertools.product(LAYOUTS, ("m", "mm"), (False, True)))
    print(f"{len(cases)} pose files per capture ({', '.join(LAYOUTS)}; m, mm; as given, "
          "inverted); --mount eye_in_hand given, nothing else")
    print("| sequence | views | captures | right | asked | WRONG |")
    print("| --- | --- | --- | --- | --- | --- |")
    for sequence in ("kuka_1", "kuka_2", "kuka_3"):
        F_all = load_rwhe_kuka(sequence).base_T_flange
        subsets = [np.arange(len(F_all))] + [
            np.sort(rng.choice(len(F_all), size=args.views, replace=False))
            for _ in range(args.subsets)]
        for label, chosen in (("all", subsets[:1]), (str(args.views), subsets[1:])):
            counts = {"right": 0, "asked": 0, "WRONG": 0}
            for views in chosen:
                with tempfile.TemporaryDirectory() as tmp:
                    folder = Path(tmp)
                    corners = _subset_corners(sequence, views, folder)
                    for layout, unit, inverse in cases:
                        counts[_outcome(F_all[views], corners, folder, layout, unit,
                                        inverse)] += 1
            print(f"| {sequence} | {label if label != 'all' else len(F_all)} | {len(chosen)} | "
                  f"{counts['right']} | {counts['asked']} | {counts['WRONG']} |")


if __name__ == "__main__":
    main()
