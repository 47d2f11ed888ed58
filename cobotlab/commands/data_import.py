"""``cobotlab data import``: a capture made elsewhere (images or corners, a pose file, maybe
the camera's own calibration) -> a capture folder for ``cobotlab calibrate``.

The import itself is ``solutions.capture_import.import_capture``; this module parses the
flags and prints what it decided, with the evidence.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

#: ``--target`` choices (solutions.capture_import.TARGET_KINDS, kept here so that --help does
#: not import the solvers).
TARGET_KINDS = ("chessboard", "charuco", "aruco", "apriltag", "circles")
DEFAULT_DICTIONARY = {"aruco": "DICT_4X4_50", "apriltag": "DICT_APRILTAG_36h11",
                      "charuco": "DICT_4X4_50"}
BOARD_FORMS = {"chessboard": ("COLSxROWS:SQUARE_MM", 1, "9x6:23.6"),
               "circles": ("COLSxROWS:SPACING_MM", 1, "4x11:20"),
               "charuco": ("SQUARESxSQUARES:SQUARE_MM:MARKER_MM", 2, "7x5:40:30"),
               "aruco": ("COLSxROWS:MARKER_MM:GAP_MM", 2, "4x3:48:12"),
               "apriltag": ("COLSxROWS:MARKER_MM:GAP_MM", 2, "4x3:48:12")}


def add_parser(data_sub) -> None:
    imp = data_sub.add_parser(
        "import",
        help="make a capture folder for `cobotlab calibrate` from a pose file and images or "
             "corners",
        description=(
            "Convert a hand-eye capture made elsewhere into a cobotlab capture folder. POSES is "
            "a text/CSV file with a row per view (16 numbers: a 4 x 4 matrix, row-major; 6: x y "
            "z + rotation vector (theta-u); 7: x y z + quaternion; a header such as "
            "x,y,z,qx,qy,qz,qw may name the columns) or a folder of YAML/JSON files, one per "
            "view (docs/calibrate_your_capture.md). Units, quaternion order and pose direction "
            "not given by a flag are decided from the data and printed with the evidence; "
            "where the data cannot tell, the flag to pass is named. The target comes as --images "
            "(one image per pose, in name order) with --target and its geometry (below; a "
            "view where it is not found is named with the rule it failed; a chessboard's "
            "corner order is resolved from the robot's motion), or --corners (an .npz with "
            "corners_px (n, N, 2), board_points_m (N, 3), image_size_wh). The camera's "
            "intrinsics are used as given (--intrinsics or --fx --fy --cx --cy [--dist]), else "
            "calibrated from the corners (cv2.calibrateCamera)."
        ),
    )
    imp.add_argument("poses", metavar="POSES", help="robot pose file, or a folder of one "
                                                    "YAML/JSON file per view")
    imp.add_argument("dest", metavar="CAPTURE_DIR", help="capture folder to write")
    board_source = imp.add_mutually_exclusive_group(required=True)
    board_source.add_argument("--corners", metavar="NPZ", help="detected corners (.npz)")
    board_source.add_argument("--images", metavar="DIR", help="folder of images, one per pose")
    target = imp.add_argument_group(
        "the target in the images (sizes in millimetres)",
        "chessboard: --board COLSxROWS:SQUARE (inner corners), e.g. 9x6:23.6; "
        "circles: --board COLSxROWS:SPACING [--asymmetric]; "
        "charuco: --board SQUARESxSQUARES:SQUARE:MARKER [--dict DICT_4X4_50] [--legacy]; "
        "aruco/apriltag: one marker --tag SIZE[:ID], or a grid --board COLSxROWS:SIZE:GAP "
        "[--dict] (default dictionaries DICT_4X4_50 and DICT_APRILTAG_36h11)")
    target.add_argument("--target", default="chessboard", choices=TARGET_KINDS,
                        help="the target's kind (default chessboard)")
    target.add_argument("--board", metavar="COLSxROWS:MM[:MM...]", default=None,
                        help="the board's geometry, as above, e.g. 8x6:39")
    target.add_argument("--tag", metavar="SIZE_MM[:ID]", default=None,
                        help="one marker: its black square's side in mm, and its id when "
                             "several are in view, e.g. 48 or 48:0")
    target.add_argument("--dict", default=None, metavar="DICT",
                        help="the cv2.aruco dictionary, e.g. DICT_APRILTAG_36h11, DICT_5X5_100")
    target.add_argument("--asymmetric", action="store_true", help="circles: an asymmetric grid")
    target.add_argument("--legacy", action="store_true",
                        help="charuco: a board made before OpenCV 4.6 (black first square)")
    camera = imp.add_argument_group("the camera's own calibration (default: calibrated from "
                                    "the corners)")
    camera.add_argument("--intrinsics", metavar="FILE", default=None,
                        help="an OpenCV calibration (YAML/XML FileStorage: camera_matrix, "
                             "distortion_coefficients) or a ROS camera_info YAML")
    for name in ("fx", "fy", "cx", "cy"):
        camera.add_argument(f"--{name}", type=float, default=None, metavar="PX",
                            help=f"{name} in pixels (with the other three)")
    camera.add_argument("--dist", default=None, metavar="K1,K2,P1,P2[,K3]",
                        help="with --fx..: OpenCV distortion coefficients (default none)")
    conventions = imp.add_argument_group("pose conventions (default: decided from the data)")
    conventions.add_argument("--mount", default=None, choices=("eye_in_hand", "eye_to_hand"),
                             help="where the camera is (default eye_in_hand; give it when the "
                                  "pose direction must be decided from the data)")
    conventions.add_argument("--length-unit", default=None, choices=("m", "mm"))
    conventions.add_argument("--angle-unit", default=None, choices=("rad", "deg"),
                             help="of rotation vectors")
    conventions.add_argument("--quat-order", default=None, choices=("xyzw", "wxyz"))
    conventions.add_argument("--pose-direction", default=None,
                             choices=("base_T_flange", "flange_T_base"),
                             help="what each pose is: the flange in the base frame, or the "
                                  "inverse")
    imp.add_argument("--robot", default="", help="robot name to record (optional)")
    imp.add_argument("--camera", default="", help="camera name to record (optional)")
    imp.add_argument("--force", action="store_true", help="overwrite an existing capture folder")


def _board_numbers(args) -> tuple[int, int, list[float]]:
    """(columns, rows, the sizes in metres) of ``--board`` in the form ``--target`` takes."""
    form, sizes, example = BOARD_FORMS[args.target]
    match = re.fullmatch(r"(\d+)x(\d+)((?::[0-9.]+)+)", args.board or "")
    numbers = match[3].split(":")[1:] if match else []
    if not match or len(numbers) != sizes:
        raise ValueError(f"--target {args.target} needs --board {form} (millimetres), e.g. "
                         f"--board {example}; got {args.board!r}")
    try:
        metres = [float(v) / 1000.0 for v in numbers]
    except ValueError:
        raise ValueError(f"--board {args.board!r}: the sizes must be numbers of mm, e.g. "
                         f"{example}") from None
    return int(match[1]), int(match[2]), metres


def _tag(args) -> tuple[float, int | None]:
    """(side m, id or None) of ``--tag SIZE_MM[:ID]``."""
    match = re.fullmatch(r"([0-9.]+)(?::(\d+))?", args.tag)
    if not match:
        raise ValueError(f"--tag must be SIZE_MM or SIZE_MM:ID (the black square's side in mm, "
                         f"e.g. 48 or 48:0), got {args.tag!r}")
    return float(match[1]) / 1000.0, None if match[2] is None else int(match[2])


def _target(args):
    """The ``solutions.capture_import.Target`` the flags describe, or None for --corners."""
    from solutions import capture_import as ci

    if args.images is None:
        for flag, value in (("--board", args.board), ("--tag", args.tag)):
            if value is not None:
                raise ValueError(f"{flag} goes with --images (the corners file holds the board)")
        return None
    kind = args.target
    markers = kind in ("aruco", "apriltag")
    if args.tag is not None and not markers:
        raise ValueError(f"--tag is for --target aruco or apriltag, not {kind}; give --board")
    if markers and (args.tag is None) == (args.board is None):
        raise ValueError(f"--target {kind} needs either --tag SIZE_MM[:ID] (one marker) or "
                         "--board COLSxROWS:MARKER_MM:GAP_MM (a grid of markers)")
    if args.dict is not None and kind not in DEFAULT_DICTIONARY:
        raise ValueError(f"--dict is for markers and ChArUco boards, not --target {kind}")
    dictionary = args.dict or DEFAULT_DICTIONARY.get(kind)
    if markers and args.tag is not None:
        side, marker_id = _tag(args)
        return ci.marker_target(kind, dictionary, side, marker_id)
    cols, rows, sizes = _board_numbers(args)
    if kind == "chessboard":
        return ci.chessboard_target(cols, rows, sizes[0])
    if kind == "circles":
        return ci.circle_grid_target(cols, rows, sizes[0], args.asymmetric)
    if kind == "charuco":
        return ci.charuco_target(cols, rows, sizes[0], sizes[1], dictionary, args.legacy)
    return ci.marker_target(kind, dictionary, sizes[0], grid=(cols, rows),
                            separation_m=sizes[1])


def _image_size(args):
    """(width, height) of the first image, or of the corners file."""
    import cv2
    import numpy as np

    if args.images is not None:
        from robots.capture import image_files

        files = image_files(args.images)
        if not files:
            raise ValueError(f"{args.images} holds no images (.png, .jpg, .bmp, .tif)")
        image = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"cannot read the image {files[0]}")
        return image.shape[1], image.shape[0]
    with np.load(args.corners, allow_pickle=False) as data:
        if "image_size_wh" not in data.files:
            return None
        return tuple(int(v) for v in data["image_size_wh"])


def _intrinsics(args):
    """The given intrinsics, or None (then they are calibrated from the corners)."""
    from robots import pose_files

    numbers = [getattr(args, n) for n in ("fx", "fy", "cx", "cy")]
    if args.intrinsics is not None:
        if any(v is not None for v in numbers) or args.dist is not None:
            raise ValueError("give the intrinsics either as --intrinsics FILE or as --fx --fy "
                             "--cx --cy [--dist], not both")
        return pose_files.read_intrinsics(args.intrinsics, _image_size(args))
    if all(v is None for v in numbers):
        if args.dist is not None:
            raise ValueError("--dist needs --fx --fy --cx --cy too")
        return None
    if any(v is None for v in numbers):
        missing = [f"--{n}" for n, v in zip(("fx", "fy", "cx", "cy"), numbers) if v is None]
        raise ValueError(f"the intrinsics need {', '.join(missing)} too (pixels)")
    try:
        dist = [float(v) for v in (args.dist or "").replace(",", " ").split()]
    except ValueError:
        raise ValueError(f"--dist must be numbers separated by commas (k1,k2,p1,p2[,k3]), got "
                         f"{args.dist!r}") from None
    width, height = _image_size(args)
    return pose_files.intrinsics_from(*numbers, width, height, dist)


def _target_record(args, target):
    """The ``robots.capture.TargetRecord`` the folder keeps: the --images target's kind and
    description, or for --corners the kind --target names (default chessboard) and the file."""
    from robots.capture import TargetRecord

    if target is not None:
        return TargetRecord(target.kind, {"description": target.description},
                            target.half_turn_ambiguous)
    return TargetRecord(args.target, {"corners_file": Path(args.corners).name},
                        args.target == "chessboard"
                        or (args.target == "circles" and not args.asymmetric))


def run(args) -> None:
    from cobotlab.demo import require_solutions
    from robots.capture import save_capture

    require_solutions("data import")
    from solutions.capture_import import import_capture

    target = _target(args)
    imported = import_capture(
        args.poses, images=args.images, corners=args.corners, target=target,
        intrinsics=_intrinsics(args), mount=args.mount or "eye_in_hand",
        mount_given=args.mount is not None, length_unit=args.length_unit,
        angle_unit=args.angle_unit, quat_order=args.quat_order, direction=args.pose_direction,
        robot_name=args.robot, camera_name=args.camera)
    # Recorded in the folder, so `cobotlab calibrate` checks a chessboard's half-turn again
    # (for --corners, the first time: the corners are taken as --target's).
    capture = dataclasses.replace(imported.capture, target=_target_record(args, target))
    folder = save_capture(capture, args.dest, overwrite=args.force)
    i = capture.intrinsics
    print(f"imported {len(capture)} views ({len(capture.failed_indices)} without the board) "
          f"into {folder}; intrinsics fx {i.fx:.1f} fy {i.fy:.1f} cx {i.cx:.1f} cy {i.cy:.1f} "
          f"px, dist {' '.join(f'{v:.4f}' for v in i.dist)} ({imported.intrinsics_source})")
    for index, reason in zip(capture.failed_indices, capture.failed_reasons):
        print(f"  view {int(index)} left out: {reason}")
    if target is not None:
        print(f"target: {target.description}")
    print("poses read as:")
    for decision in imported.decisions:
        print(f"  {decision}")
    mount = args.mount or "eye_in_hand (or eye_to_hand)"
    print(f"next: cobotlab calibrate {folder} --mount {mount}")
