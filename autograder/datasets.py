"""Small real captures shipped with cobotlab, for labs and tests.

The files live under ``autograder/data/`` inside the installed package (found through
``importlib.resources``), so nothing outside the package is read at run time. Each data folder
has a README with its source, what the arrays mean and its licence.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np

__all__ = ["RWHE_KUKA_SEQUENCES", "RealHandEyeCapture", "load_aubo_flange_capture",
           "load_rwhe_kuka"]

_AUBO_FLANGE = ("data", "bionicdl_aubo_i5_flange", "calibration_data.npz")
_AUBO_FLANGE_POINTS = 50


def load_aubo_flange_capture() -> tuple[np.ndarray, np.ndarray]:
    """The real Aubo-i5 + RealSense flange-calibration capture (eye-on-base, 50 poses).

    Returns ``(cam_points, base_points)``, both float64 (50, 3) in metres:
    ``cam_points[i]`` is the checkerboard centre taped on the flange, in the camera's optical
    frame (from the aligned depth image); ``base_points[i]`` the tool0 position in the robot
    base frame (from the controller). The orientation is the same at every pose.
    Source: ancorasir/BionicDL-CobotLearning-Project2 (MIT); see the README next to the file.
    """
    resource = resources.files("autograder").joinpath(*_AUBO_FLANGE)
    with resources.as_file(resource) as path, np.load(path, allow_pickle=False) as data:
        cam_points = np.array(data["arr_0"], dtype=float)
        base_points = np.array(data["arr_1"], dtype=float)
    expected = (_AUBO_FLANGE_POINTS, 3)
    if cam_points.shape != expected or base_points.shape != expected:
        raise ValueError(
            f"{resource} holds arrays of shape {cam_points.shape} and {base_points.shape}, "
            f"expected {expected} each; the packaged data file is damaged, reinstall cobotlab"
        )
    return cam_points, base_points


RWHE_KUKA_SEQUENCES = ("kuka_1", "kuka_2", "kuka_3")


@dataclass(frozen=True)
class RealHandEyeCapture:
    """A real hand-eye capture as the solvers take it (no ground truth).

    ``base_T_flange`` (n, 4, 4): the controller's flange poses, metres. ``pixels`` (n, N, 2):
    the board corners detected in each view (x right, y down, pixel centres at integers as in
    OpenCV), NaN where a corner was not found. ``board_points_m`` (N, 3): the same corners in
    the board frame as printed (metres, z = 0). ``image_size_wh``: (width, height) in pixels.
    ``image_names``: the original image of each view. ``mount`` is ``"eye_in_hand"`` or
    ``"eye_to_hand"``; ``pattern`` says how the corners were found.
    """

    name: str
    base_T_flange: np.ndarray
    pixels: np.ndarray
    board_points_m: np.ndarray
    image_size_wh: tuple[int, int]
    image_names: tuple[str, ...]
    mount: str
    pattern: str


def load_rwhe_kuka(sequence: str = "kuka_1") -> RealHandEyeCapture:
    """One of the three real eye-in-hand KUKA sequences of Ali et al. (Sensors 2019).

    ``sequence`` is ``"kuka_1"`` (30 views, chessboard of 20 mm squares at 1.15-1.65 m),
    ``"kuka_2"`` (28 views, 15 mm squares at 0.37-0.61 m, another camera) or ``"kuka_3"``
    (29 views, ChArUco of 60 mm squares at 1.5-2 m). The robot poses are the original
    ``RobotPosesVec.txt`` (row-major ``base_T_flange``, metres); the corners were detected with
    OpenCV. Source: github.com/ihtishamaliktk/RWHE-Calib; the licence is unclear, see the
    README next to the files before passing them on.
    """
    if sequence not in RWHE_KUKA_SEQUENCES:
        raise ValueError(f"sequence must be one of {RWHE_KUKA_SEQUENCES}, got {sequence!r}")
    folder = resources.files("autograder").joinpath("data", "rwhe_kuka", sequence)
    poses_file = folder.joinpath("RobotPosesVec.txt")
    with resources.as_file(poses_file) as path:
        rows = np.loadtxt(path, dtype=float, ndmin=2)
    with resources.as_file(folder.joinpath("corners.npz")) as path, \
            np.load(path, allow_pickle=False) as data:
        pixels = np.array(data["corners_px"], dtype=float)
        board = np.array(data["board_points_m"], dtype=float)
        size = tuple(int(v) for v in data["image_size_wh"])
        names = tuple(str(v) for v in data["image_names"])
        pattern = str(data["pattern"])
    n = len(names)
    if rows.shape != (n, 16) or pixels.shape != (n, len(board), 2) or board.shape[1:] != (3,):
        raise ValueError(
            f"{folder} holds {rows.shape} pose numbers, corners {pixels.shape} and board points "
            f"{board.shape} for {n} images; expected ({n}, 16), ({n}, N, 2) and (N, 3): the "
            "packaged data is damaged, reinstall cobotlab")
    base_T_flange = rows.reshape(n, 4, 4)
    if not np.allclose(base_T_flange[:, 3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{poses_file}: a pose's last row is not 0 0 0 1; the file is damaged")
    return RealHandEyeCapture(
        name=sequence, base_T_flange=base_T_flange, pixels=pixels, board_points_m=board,
        image_size_wh=size, image_names=names, mount="eye_in_hand", pattern=pattern)
