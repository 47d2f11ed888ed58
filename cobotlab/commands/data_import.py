"""``cobotlab data import``: a capture made elsewhere (images or corners, a pose file, maybe
the camera's own calibration) -> a capture folder for ``cobotlab calibrate``.

The import itself is ``solutions.capture_import.import_capture``; this module parses the
flags and prints what it decided, with the evidence.
"""

from __future__ import annotations

import re


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
            "where the data cannot tell, the flag to pass is named. The board comes as --images "
            "(one image per pose, in name order) with --board, or --corners (an .npz with "
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
    imp.add_argument("--board", metavar="COLSxROWS:SQUARE_MM", default=None,
                     help="with --images: inner corners and square size, e.g. 8x6:39")
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


def _board(args):
    if args.images is None:
        if args.board is not None:
            raise ValueError("--board goes with --images (the corners file holds the board)")
        return None
    match = re.fullmatch(r"(\d+)x(\d+):([0-9.]+)", args.board or "")
    if not match:
        raise ValueError("--images needs --board COLSxROWS:SQUARE_MM (inner corners and the "
                         "square size in millimetres), e.g. --board 8x6:39")
    return int(match[1]), int(match[2]), float(match[3]) / 1000.0


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


def run(args) -> None:
    from cobotlab.demo import require_solutions
    from robots.capture import save_capture

    require_solutions("data import")
    from solutions.capture_import import import_capture

    board = _board(args)
    imported = import_capture(
        args.poses, images=args.images, corners=args.corners, board=board,
        intrinsics=_intrinsics(args), mount=args.mount or "eye_in_hand",
        mount_given=args.mount is not None, length_unit=args.length_unit,
        angle_unit=args.angle_unit, quat_order=args.quat_order, direction=args.pose_direction,
        robot_name=args.robot, camera_name=args.camera)
    capture = imported.capture
    folder = save_capture(capture, args.dest, overwrite=args.force)
    i = capture.intrinsics
    print(f"imported {len(capture)} views ({len(capture.failed_indices)} without the board) "
          f"into {folder}; intrinsics fx {i.fx:.1f} fy {i.fy:.1f} cx {i.cx:.1f} cy {i.cy:.1f} "
          f"px, dist {' '.join(f'{v:.4f}' for v in i.dist)} ({imported.intrinsics_source})")
    for index, reason in zip(capture.failed_indices, capture.failed_reasons):
        print(f"  view {int(index)} left out: {reason}")
    print("poses read as:")
    for decision in imported.decisions:
        print(f"  {decision}")
    mount = args.mount or "eye_in_hand (or eye_to_hand)"
    print(f"next: cobotlab calibrate {folder} --mount {mount}")
