"""``cobotlab data``: the real datasets shipped with cobotlab (list, export), and the import
of a capture made elsewhere into a capture folder for ``cobotlab calibrate``."""

from __future__ import annotations


def add_parser(sub) -> None:
    data = sub.add_parser(
        "data",
        help="list the real datasets shipped with cobotlab, or copy one out",
        description="Real captures shipped inside the package, with their source and licence.",
    )
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", required=True)
    data_sub.add_parser("list", help="name, description, source and licence of each dataset")
    export = data_sub.add_parser("export", help="copy a dataset's files (and README) to a folder")
    export.add_argument("name", metavar="NAME", help="a name from `cobotlab data list`")
    export.add_argument("dest", metavar="DIR", help="folder to copy into (created if needed)")
    imp = data_sub.add_parser(
        "import",
        help="make a capture folder for `cobotlab calibrate` from a pose text file and corners "
             "or images",
        description=(
            "Convert a hand-eye capture made elsewhere into a cobotlab capture folder. POSES is "
            "a text file with one base_T_flange per line: the 16 numbers of the 4 x 4 matrix, "
            "row-major, metres (as RWHE-Calib's RobotPosesVec.txt). The board comes either as "
            "--corners, an .npz with corners_px (n, N, 2), board_points_m (N, 3) and "
            "image_size_wh, or as --images (one image per pose, in name order) with --board. "
            "The intrinsics are calibrated from the corners (cv2.calibrateCamera)."
        ),
    )
    imp.add_argument("poses", metavar="POSES", help="robot pose text file, one pose per line")
    imp.add_argument("dest", metavar="CAPTURE_DIR", help="capture folder to write")
    board_source = imp.add_mutually_exclusive_group(required=True)
    board_source.add_argument("--corners", metavar="NPZ", help="detected corners (.npz)")
    board_source.add_argument("--images", metavar="DIR", help="folder of images, one per pose")
    imp.add_argument("--board", metavar="COLSxROWS:SQUARE_MM", default=None,
                     help="with --images: inner corners and square size, e.g. 8x6:39")
    imp.add_argument("--robot", default="", help="robot name to record (optional)")
    imp.add_argument("--camera", default="", help="camera name to record (optional)")
    imp.add_argument("--force", action="store_true", help="overwrite an existing capture folder")


def run(args) -> None:
    if args.data_command == "list":
        _data_list()
    elif args.data_command == "export":
        _data_export(args.name, args.dest)
    elif args.data_command == "import":
        _data_import(args)


def _datasets() -> dict:
    """Shipped datasets: folder name -> (folder Traversable, title, source line, licence line),
    read from each data folder's README (its title, first paragraph and Licence section)."""
    from importlib import resources

    found = {}
    root = resources.files("autograder").joinpath("data")
    for folder in sorted(root.iterdir(), key=lambda f: f.name):
        readme = folder.joinpath("README.md")
        if not readme.is_file():
            continue
        lines = readme.read_text().splitlines()
        title = next((text[2:].strip() for text in lines if text.startswith("# ")), folder.name)
        body = lines[lines.index(next(text for text in lines if text.startswith("# "))) + 1:]
        paragraph = []
        for line in body:
            if line.strip():
                paragraph.append(line.strip())
            elif paragraph:
                break
        source = " ".join(paragraph)
        licence = ""
        if "## Licence" in lines:
            after = lines[lines.index("## Licence") + 1:]
            licence = next((text.strip() for text in after if text.strip()), "")
        found[folder.name] = (folder, title, source, licence)
    return found


def _data_list() -> None:
    for name, (folder, title, source, licence) in _datasets().items():
        files = [f.name for f in folder.iterdir() if f.is_file()]
        print(f"{name}: {title}")
        print(f"  source:  {source}")
        print(f"  licence: {licence or 'see README.md'}")
        print(f"  files:   {', '.join(sorted(files))}")


def _data_export(name: str, dest) -> None:
    import shutil
    from importlib import resources
    from pathlib import Path

    datasets = _datasets()
    if name not in datasets:
        raise ValueError(f"no dataset named {name!r}; `cobotlab data list` shows: "
                         f"{', '.join(datasets) or 'none'}")
    folder = datasets[name][0]
    dest = Path(dest)
    files = [f for f in folder.iterdir() if f.is_file()]
    clashes = [f.name for f in files if (dest / f.name).exists()]
    if clashes:
        raise FileExistsError(f"{dest} already has {', '.join(clashes)}; export into an empty "
                              "folder or remove those files first")
    dest.mkdir(parents=True, exist_ok=True)
    for f in files:
        with resources.as_file(f) as source:
            shutil.copyfile(source, dest / f.name)
        print(f"copied {dest / f.name}")


def _data_import(args) -> None:
    """``cobotlab data import``: pose text file + corners or images -> a capture folder."""
    import re

    from robots.capture import import_pose_text_capture, save_capture

    board = None
    if args.images is not None:
        match = re.fullmatch(r"(\d+)x(\d+):([0-9.]+)", args.board or "")
        if not match:
            raise ValueError("--images needs --board COLSxROWS:SQUARE_MM (inner corners and the "
                             "square size in millimetres), e.g. --board 8x6:39")
        board = (int(match[1]), int(match[2]), float(match[3]) / 1000.0)
    capture = import_pose_text_capture(args.poses, corners_file=args.corners,
                                       images_dir=args.images, board=board,
                                       robot_name=args.robot, camera_name=args.camera)
    folder = save_capture(capture, args.dest, overwrite=args.force)
    i = capture.intrinsics
    print(f"imported {len(capture)} views ({len(capture.failed_indices)} without the board) "
          f"into {folder}; intrinsics fx {i.fx:.1f} fy {i.fy:.1f} cx {i.cx:.1f} cy {i.cy:.1f} "
          f"px, dist {' '.join(f'{v:.4f}' for v in i.dist)}")
    print(f"next: cobotlab calibrate {folder} --mount eye_in_hand (or eye_to_hand)")
