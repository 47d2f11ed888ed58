"""Small real captures shipped with cobotlab, for labs and tests.

The files live under ``autograder/data/`` inside the installed package (found through
``importlib.resources``), so nothing outside the package is read at run time. Each data folder
has a README with its source, what the arrays mean and its licence.
"""

from __future__ import annotations

from importlib import resources

import numpy as np

__all__ = ["load_aubo_flange_capture"]

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
