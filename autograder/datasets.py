"""Small real captures shipped with cobotlab, for labs and tests.

The files live under ``autograder/data/`` inside the installed package (found through
``importlib.resources``), so nothing outside the package is read at run time. Each data folder
has a README with its source, what the arrays mean and its licence.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np

__all__ = ["RWHE_KUKA_SEQUENCES", "RealHandEyeCapture", "VISP_FRANKA_MOUNTS",
           "load_aubo_flange_capture", "load_rwhe_kuka", "load_visp_franka"]

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
    ``"eye_to_hand"``; ``pattern`` says how the corners were found. ``K`` (3, 3) and ``dist``
    (5,): the camera's intrinsics when the capture came with them (None: calibrate them from
    the corners). ``notes``: what loading decided, with its evidence (e.g. views whose corner
    order was turned to agree with the robot's motion).
    """

    name: str
    base_T_flange: np.ndarray
    pixels: np.ndarray
    board_points_m: np.ndarray
    image_size_wh: tuple[int, int]
    image_names: tuple[str, ...]
    mount: str
    pattern: str
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    notes: tuple[str, ...] = ()


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


VISP_FRANKA_MOUNTS = ("eye_in_hand", "eye_to_hand")


def _visp_pose(path) -> np.ndarray:
    """base_T_flange from a ViSP ``vpPoseVector`` YAML: tx ty tz (m), theta-u (rad)."""
    import yaml

    from robots import geometry as geo

    with open(path) as f:
        values = np.array(yaml.safe_load(f)["data"], dtype=float).ravel()
    if values.shape != (6,):
        raise ValueError(f"{path}: {values.size} numbers, expected 6 (tx ty tz tux tuy tuz)")
    return geo.pose_from_rotvec(values[3:], values[:3])


def _visp_camera(path) -> tuple[np.ndarray, tuple[int, int]]:
    """K and (width, height) from a ViSP camera XML (``perspectiveProjWithDistortion`` with
    kud = 0 here, so no distortion)."""
    import xml.etree.ElementTree as ElementTree

    root = ElementTree.parse(path).getroot().find("camera")
    model = root.find("model")
    value = {k: float(model.find(k).text) for k in ("px", "py", "u0", "v0", "kud")}
    if value["kud"] != 0.0:
        raise ValueError(f"{path}: kud = {value['kud']}; ViSP's radial model is not OpenCV's")
    K = np.array([[value["px"], 0, value["u0"]], [0, value["py"], value["v0"]], [0, 0, 1.0]])
    return K, (int(root.find("image_width").text), int(root.find("image_height").text))


def load_visp_franka(mount: str = "eye_in_hand") -> RealHandEyeCapture:
    """One of ViSP's two real Franka hand-eye captures (8 views each, intrinsics given).

    ``"eye_in_hand"``: a camera on the flange looks at a 9 x 6 (inner corners) chessboard of
    23.6 mm squares; one view has the camera rolled about half a turn, so the corner order is
    resolved from the robot's motion (:func:`robots.half_turn.resolve_half_turns`) and said in
    ``notes``. ``"eye_to_hand"``: a fixed camera looks at one 48 mm AprilTag (36h11) on the
    flange; its 4 corners per view. Robot poses: ViSP's ``rPe`` (base_T_flange, translation m
    and theta-u rad). Corners are detected here in the shipped images with OpenCV. Source:
    github.com/lagadic/visp, GPL-2.0-or-later; see the README next to the files.
    """
    import cv2

    from robots.capture import chessboard_detector
    from robots.half_turn import resolve_half_turns
    from robots.interfaces import Frame, Intrinsics
    from robots.targets import aruco_detector

    if mount not in VISP_FRANKA_MOUNTS:
        raise ValueError(f"mount must be one of {VISP_FRANKA_MOUNTS}, got {mount!r}")
    folder = resources.files("autograder").joinpath("data", "visp_franka", mount)
    with resources.as_file(folder) as root:
        K, size = _visp_camera(root / "franka_camera.xml")
        intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], *size)
        if mount == "eye_in_hand":
            detect, pattern = chessboard_detector(9, 6, 0.0236), "chessboard 9 x 6, 23.6 mm"
        else:
            detect = aruco_detector("DICT_APRILTAG_36h11", 0.048)
            pattern = "AprilTag 36h11, 48 mm, 4 corners"
        names = tuple(f"franka_image-{i}.png" for i in range(1, 9))
        poses, corners, board = [], [], None
        for i, name in enumerate(names, 1):
            poses.append(_visp_pose(root / f"franka_pose_rPe_{i}.yaml"))
            bgr = cv2.imread(str(root / name), cv2.IMREAD_COLOR)
            if bgr is None:
                raise FileNotFoundError(f"{root / name} is missing; reinstall cobotlab")
            found = detect(Frame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), None, 0.0), intrinsics)
            if found is None or not found.ok:
                why = "" if found is None else f": {found.reason}"
                raise ValueError(f"{root / name}: the target was not found{why}")
            corners.append(found.corners_px)
            board = found.object_points
    base_T_flange = np.array(poses)
    notes: tuple[str, ...] = ()
    if mount == "eye_in_hand":
        corners, _, choice = resolve_half_turns(base_T_flange, corners, board, intrinsics)
        notes = (choice.summary(),)
    return RealHandEyeCapture(
        name=f"visp_franka_{mount}", base_T_flange=base_T_flange, pixels=np.array(corners),
        board_points_m=board, image_size_wh=size, image_names=names, mount=mount,
        pattern=pattern, K=K, dist=np.zeros(5), notes=notes)
