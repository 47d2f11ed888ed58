"""Capture hand-eye data: move through poses, take a picture at each, detect the target.

:func:`capture_pose_pairs` drives any :class:`~robots.interfaces.Robot` and
:class:`~robots.interfaces.Camera` (simulated or real) and returns a :class:`Capture`: the
flange poses *as read back from the robot* (not as commanded), the detected target poses and
corners, and the images. Saved with :func:`save_capture`, a capture folder reloads with
:func:`load_capture` to exactly the same arrays, so a lab can be re-run offline from data
taken on a real robot.

A capture made elsewhere comes in by stages: :func:`read_views` (each view's corners, from
images or a corners file), :func:`solve_board_poses` (the board poses, with the camera's own
intrinsics when given, else calibrated from the corners) and :func:`capture_from_views`; pose
files of other layouts and conventions are read by ``robots.pose_files`` and decided by
``solutions.capture_import``.

Folder layout::

    poses.npz      arrays (no pickles): base_T_flange (M, 4, 4), cam_T_target (M, 4, 4)
                   (NaN where the detector gave no pose), commanded_base_T_flange (P, 4, 4),
                   pose_indices (M,), timestamps (M,), corners_px (M, Nmax, 2) and
                   object_points (M, Nmax, 3) padded with NaN, corner_counts (M,),
                   failed_indices (K,), intrinsics [fx, fy, cx, cy, width, height], dist (5,)
    images/view_007.png   the RGB image of commanded pose 7 (lossless PNG)
    images/failed_003.png images where detection failed, kept for inspection
    depth.npz      optional float32 depth images (M, H, W), when captured with keep_depth=True
    meta.yaml      human-readable summary: date, robot, camera, counts, why views failed,
                   and the target (kind, geometry, whether its corners can be read half a
                   turn round; absent in folders written before it was recorded)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from robots.geometry import as_pose, as_poses
from robots.interfaces import Camera, Frame, Intrinsics, Robot, UnreachableError

__all__ = [
    "Capture",
    "Detection",
    "TargetRecord",
    "ViewCorners",
    "capture_from_views",
    "capture_pose_pairs",
    "chessboard_detector",
    "corners_from_file",
    "corners_from_images",
    "import_pose_text_capture",
    "load_capture",
    "read_pose_text",
    "read_views",
    "save_capture",
    "solve_board_poses",
]

FORMAT = "cobotlab-capture/1"


@dataclass(frozen=True)
class TargetRecord:
    """What a capture's corners are of, saved in its meta.yaml so a later calibration knows.

    ``kind``: chessboard, circles, charuco, aruco, apriltag, or a name of the user's;
    ``geometry``: its numbers (SI units: metres), e.g. ``{"inner_cols": 9, "inner_rows": 6,
    "square_m": 0.025}``; ``half_turn_ambiguous``: True when the target looks the same turned
    half a turn, so its detected corner order may be reversed in some views
    (``robots.half_turn`` resolves it from the robot's motion)."""

    kind: str
    geometry: dict = field(default_factory=dict)
    half_turn_ambiguous: bool = False

    def to_dict(self) -> dict:
        return {"kind": self.kind, "geometry": dict(self.geometry),
                "half_turn_ambiguous": self.half_turn_ambiguous}

    @classmethod
    def from_dict(cls, data, where: str = "the target record") -> TargetRecord:
        """The record from its meta.yaml dict; ``ValueError`` naming ``where`` if malformed."""
        if (not isinstance(data, dict) or not isinstance(data.get("kind"), str)
                or not isinstance(data.get("geometry", {}), dict)
                or not isinstance(data.get("half_turn_ambiguous", False), bool)):
            raise ValueError(f"{where} must be a mapping with kind (text), geometry (a "
                             f"mapping) and half_turn_ambiguous (true/false), got {data!r}; "
                             "fix or delete it (the half-turn is then not checked)")
        return cls(data["kind"], dict(data.get("geometry", {})),
                   data.get("half_turn_ambiguous", False))


@dataclass
class Detection:
    """What a detector found in one image.

    ``cam_T_target`` (4, 4): the target's pose in the camera optical frame (metres), or None
    when the detector finds corners but does not solve for the pose. ``corners_px`` (N, 2):
    detected image points in pixels; ``object_points`` (N, 3): the same points in the target
    frame, metres. ``ok=False`` marks a failed detection (the view is skipped); ``reason``
    then says why, with the rule (e.g. how many points were found and how many are needed).
    """

    cam_T_target: np.ndarray | None
    corners_px: np.ndarray
    object_points: np.ndarray
    ok: bool = True
    reason: str = ""

    def __post_init__(self):
        self.corners_px = np.asarray(self.corners_px, dtype=float).reshape(-1, 2)
        self.object_points = np.asarray(self.object_points, dtype=float).reshape(-1, 3)
        if len(self.corners_px) != len(self.object_points):
            raise ValueError(
                f"Detection has {len(self.corners_px)} corners but {len(self.object_points)} "
                "object points; they must correspond one to one"
            )
        for name in ("corners_px", "object_points"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"Detection.{name} contains NaN or inf; drop those points instead")
        if self.cam_T_target is not None:
            self.cam_T_target = as_pose(self.cam_T_target, "Detection.cam_T_target")
        self.ok = bool(self.ok)


@dataclass
class Capture:
    """The data of one capture run. M views kept, P poses commanded, K views failed.

    ``base_T_flange[i]`` and ``cam_T_target[i]`` form the i-th hand-eye pair;
    ``cam_T_target[i]`` is all-NaN if the detector gave corners but no pose for that view
    (use :meth:`pose_pairs` to get only complete pairs). ``pose_indices[i]`` says which
    commanded pose view i came from. ``failed_indices`` / ``failed_reasons`` record the skipped
    ones. ``images`` are the kept views' RGB images, ``depths`` their depth images (or None).
    ``target``: what the corners are of (:class:`TargetRecord`), None when not known (a
    detector that does not say, or a folder saved before it was recorded).
    """

    base_T_flange: np.ndarray
    cam_T_target: np.ndarray
    corners_px: list[np.ndarray]
    object_points: list[np.ndarray]
    intrinsics: Intrinsics
    commanded_base_T_flange: np.ndarray
    pose_indices: np.ndarray
    timestamps: np.ndarray
    images: list[np.ndarray]
    failed_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    failed_reasons: list[str] = field(default_factory=list)
    failed_images: list[np.ndarray | None] = field(default_factory=list)
    depths: list[np.ndarray] | None = None
    robot_name: str = ""
    camera_name: str = ""
    created: str = ""
    target: TargetRecord | None = None

    def __len__(self) -> int:
        return len(self.base_T_flange)

    def pose_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(base_T_flange, cam_T_target), each (M', 4, 4), for views with a target pose."""
        has_pose = np.all(np.isfinite(self.cam_T_target), axis=(1, 2))
        return self.base_T_flange[has_pose], self.cam_T_target[has_pose]


# --------------------------------------------------------------------------- capture


def capture_pose_pairs(
    robot: Robot,
    camera: Camera,
    poses,
    detector,
    folder=None,
    progress: bool = True,
    speed: float = 0.1,
    settle_s: float | None = None,
    keep_depth: bool = False,
    overwrite: bool = False,
) -> Capture:
    """Visit each commanded ``base_T_flange`` pose, photograph the target and detect it.

    For each pose: ``robot.move_to(pose, speed)`` (m/s), wait ``settle_s`` seconds (default:
    ``robot.settle_time_s``, 0.5 s unless the backend says otherwise, so a real arm stops
    vibrating), read ``robot.flange_pose()``, ``camera.capture()``, then
    ``detector(frame, camera.intrinsics) -> Detection | None``. Views where the detection
    fails, or whose pose the arm cannot reach (UnreachableError), are skipped and recorded;
    a SafetyError stops the run, since the pose list itself needs fixing.

    ``poses``: (P, 4, 4) or a list of (4, 4), base frame, metres. If ``folder`` is given the
    capture is saved there (see :func:`save_capture`). Shows a tqdm progress bar unless
    ``progress=False``. The capture records the target when the detector carries a
    ``target`` attribute (a :class:`TargetRecord`, as :func:`chessboard_detector`'s does).
    Returns the :class:`Capture`.
    """
    from tqdm.auto import tqdm

    commanded = as_poses(poses, "poses", min_count=1)
    if not callable(detector):
        raise ValueError(
            "detector must be a callable detector(frame, intrinsics) -> Detection | None"
        )
    if settle_s is None:
        settle_s = float(getattr(robot, "settle_time_s", 0.5))
    if not np.isfinite(settle_s) or settle_s < 0:
        raise ValueError(f"settle_s must be a non-negative number of seconds, got {settle_s}")
    if folder is not None:
        _check_folder_free(Path(folder), overwrite)
    intrinsics = camera.intrinsics

    kept = {
        "flange": [],
        "target": [],
        "corners": [],
        "objects": [],
        "index": [],
        "time": [],
        "image": [],
        "depth": [],
    }
    failed_indices, failed_reasons, failed_images = [], [], []

    bar = tqdm(total=len(commanded), desc="capture", unit="pose", disable=not progress)
    try:
        for i, target in enumerate(commanded):
            try:
                robot.move_to(target, speed=speed)
            except UnreachableError as error:
                failed_indices.append(i)
                failed_reasons.append(f"unreachable: {error}")
                failed_images.append(None)
                bar.update(1)
                continue
            if settle_s > 0:
                time.sleep(settle_s)
            base_T_flange = robot.flange_pose()
            frame = camera.capture()
            if not isinstance(frame, Frame):
                raise TypeError(f"camera.capture() returned {type(frame).__name__}, not a Frame")
            detection = detector(frame, intrinsics)
            if detection is None or not detection.ok or len(detection.corners_px) == 0:
                failed_indices.append(i)
                failed_reasons.append(detection.reason if detection is not None
                                      and detection.reason else "target not detected")
                failed_images.append(frame.rgb)
            else:
                kept["flange"].append(as_pose(base_T_flange, "robot.flange_pose()"))
                kept["target"].append(
                    np.full((4, 4), np.nan)
                    if detection.cam_T_target is None
                    else detection.cam_T_target
                )
                kept["corners"].append(detection.corners_px)
                kept["objects"].append(detection.object_points)
                kept["index"].append(i)
                kept["time"].append(frame.timestamp)
                kept["image"].append(frame.rgb)
                kept["depth"].append(frame.depth)
            bar.update(1)
            bar.set_postfix(ok=len(kept["index"]), failed=len(failed_indices))
    finally:
        bar.close()

    if keep_depth and any(d is None for d in kept["depth"]):
        raise ValueError("keep_depth=True but the camera returned frames without depth")
    capture = Capture(
        base_T_flange=np.array(kept["flange"]).reshape(-1, 4, 4),
        cam_T_target=np.array(kept["target"]).reshape(-1, 4, 4),
        corners_px=kept["corners"],
        object_points=kept["objects"],
        intrinsics=intrinsics,
        commanded_base_T_flange=commanded,
        pose_indices=np.array(kept["index"], dtype=np.int64),
        timestamps=np.array(kept["time"], dtype=float),
        images=kept["image"],
        failed_indices=np.array(failed_indices, dtype=np.int64),
        failed_reasons=failed_reasons,
        failed_images=failed_images,
        depths=kept["depth"] if keep_depth else None,
        target=getattr(detector, "target", None),
        robot_name=robot.name,
        camera_name=camera.name,
        created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    if folder is not None:
        save_capture(capture, folder, overwrite=overwrite)
    return capture


# --------------------------------------------------------------------------- save / load


def _check_folder_free(folder: Path, overwrite: bool) -> None:
    if (folder / "poses.npz").exists() and not overwrite:
        raise FileExistsError(
            f"{folder} already holds a capture; pick a new folder or pass overwrite=True"
        )


def _pad(arrays: list[np.ndarray], width: int) -> tuple[np.ndarray, np.ndarray]:
    counts = np.array([len(a) for a in arrays], dtype=np.int64)
    n_max = int(counts.max()) if len(counts) else 0
    out = np.full((len(arrays), n_max, width), np.nan)
    for i, a in enumerate(arrays):
        out[i, : len(a)] = a
    return out, counts


def save_capture(capture: Capture, folder, overwrite: bool = False) -> Path:
    """Write ``capture`` to ``folder`` (created if needed); returns the folder path.

    Refuses to overwrite an existing capture unless ``overwrite=True``.
    """
    import cv2
    import yaml

    folder = Path(folder)
    _check_folder_free(folder, overwrite)
    images_dir = folder / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    for old in images_dir.glob("*.png"):  # only reached when overwriting
        old.unlink()

    corners, counts = _pad(capture.corners_px, 2)
    objects, _ = _pad(capture.object_points, 3)
    i = capture.intrinsics
    np.savez(
        folder / "poses.npz",
        base_T_flange=capture.base_T_flange,
        cam_T_target=capture.cam_T_target,
        commanded_base_T_flange=capture.commanded_base_T_flange,
        pose_indices=capture.pose_indices,
        timestamps=capture.timestamps,
        corners_px=corners,
        object_points=objects,
        corner_counts=counts,
        failed_indices=capture.failed_indices,
        intrinsics=np.array([i.fx, i.fy, i.cx, i.cy, i.width, i.height], dtype=float),
        dist=i.dist,
    )
    # An imported capture may have corners but no images; then none are written or expected.
    images_saved = len(capture.images) == len(capture)
    if capture.images and not images_saved:
        raise ValueError(f"the capture has {len(capture)} views but {len(capture.images)} "
                         "images; keep one image per view, or none")
    for index, rgb in zip(capture.pose_indices, capture.images):
        _write_png(cv2, images_dir / f"view_{index:03d}.png", rgb)
    for index, rgb in zip(capture.failed_indices, capture.failed_images):
        if rgb is not None:
            _write_png(cv2, images_dir / f"failed_{index:03d}.png", rgb)
    depth_file = folder / "depth.npz"
    if capture.depths is not None:
        np.savez_compressed(depth_file, depth=np.array(capture.depths, dtype=np.float32))
    elif depth_file.exists():
        depth_file.unlink()

    meta = {
        "format": FORMAT,
        "created": capture.created,
        "robot": capture.robot_name,
        "camera": capture.camera_name,
        "n_commanded": len(capture.commanded_base_T_flange),
        "n_views": len(capture),
        "intrinsics": i.to_dict(),
        "failed": [
            {"pose_index": int(k), "reason": r}
            for k, r in zip(capture.failed_indices, capture.failed_reasons)
        ],
        "failed_image_saved": [img is not None for img in capture.failed_images],
        "images_saved": images_saved,
    }
    if capture.target is not None:
        meta["target"] = capture.target.to_dict()
    with open(folder / "meta.yaml", "w") as f:
        yaml.safe_dump(meta, f, sort_keys=False)
    return folder


def _write_png(cv2, path: Path, rgb: np.ndarray) -> None:
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}; check the folder exists and is writable")


def _read_png(cv2, path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FileNotFoundError(
            f"missing or unreadable image {path}; the capture folder is incomplete"
        )
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def load_capture(folder) -> Capture:
    """Read a folder written by :func:`save_capture`; the arrays come back bit for bit equal."""
    import cv2
    import yaml

    folder = Path(folder)
    if not (folder / "poses.npz").is_file():
        raise FileNotFoundError(f"{folder} has no poses.npz; is it a capture folder?")
    with open(folder / "meta.yaml") as f:
        meta = yaml.safe_load(f)
    if meta.get("format") != FORMAT:
        raise ValueError(
            f"{folder}/meta.yaml has format {meta.get('format')!r}, expected {FORMAT!r}"
        )
    with np.load(folder / "poses.npz", allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    counts = data["corner_counts"]
    fx, fy, cx, cy, width, height = data["intrinsics"]
    intrinsics = Intrinsics(fx, fy, cx, cy, int(width), int(height), data["dist"])
    images = ([_read_png(cv2, folder / "images" / f"view_{k:03d}.png") for k in data["pose_indices"]]
              if meta.get("images_saved", True) else [])
    failed_images = [
        _read_png(cv2, folder / "images" / f"failed_{k:03d}.png") if saved else None
        for k, saved in zip(data["failed_indices"], meta["failed_image_saved"])
    ]
    depths = None
    if (folder / "depth.npz").is_file():
        with np.load(folder / "depth.npz", allow_pickle=False) as z:
            depths = list(z["depth"])
    return Capture(
        base_T_flange=data["base_T_flange"],
        cam_T_target=data["cam_T_target"],
        corners_px=[c[:n] for c, n in zip(data["corners_px"], counts)],
        object_points=[o[:n] for o, n in zip(data["object_points"], counts)],
        intrinsics=intrinsics,
        commanded_base_T_flange=data["commanded_base_T_flange"],
        pose_indices=data["pose_indices"],
        timestamps=data["timestamps"],
        images=images,
        failed_indices=data["failed_indices"],
        failed_reasons=[item["reason"] for item in meta["failed"]],
        failed_images=failed_images,
        depths=depths,
        robot_name=meta["robot"],
        camera_name=meta["camera"],
        created=meta["created"],
        target=(TargetRecord.from_dict(meta["target"], f"{folder}/meta.yaml's target")
                if meta.get("target") is not None else None),
    )


# --------------------------------------------------------------------------- a detector


def chessboard_detector(inner_cols: int, inner_rows: int, square_m: float):
    """Return ``detector(frame, intrinsics) -> Detection | None`` for a plain chessboard.

    ``inner_cols`` x ``inner_rows`` are the inner corners (a board of 9 x 7 squares has 8 x 6),
    ``square_m`` the square size in metres. The target frame has its origin at the first
    detected inner corner, x along the rows of corners, y down the columns, z into the board
    (OpenCV's convention for ``object_points``). The pose comes from ``cv2.solvePnP`` with the
    camera's distortion, after sub-pixel corner refinement.

    A chessboard looks the same turned half a turn, and OpenCV may list its corners from either
    end. As a first guess the detector keeps the order whose first row runs left to right in
    the image, which is wrong for a view whose camera is rolled past 90 degrees; the robot's
    motion tells the two orders apart, so pass the whole capture through
    :func:`robots.half_turn.resolve_half_turns` (or ``resolve_capture_half_turns``) before
    calibrating. A board not found whole gives None (all inner corners are needed).
    """
    if inner_cols < 2 or inner_rows < 2 or not square_m > 0:
        raise ValueError(
            "a chessboard needs at least 2 x 2 inner corners and a positive square size"
        )
    grid = np.zeros((inner_rows * inner_cols, 3))
    grid[:, :2] = np.mgrid[0:inner_cols, 0:inner_rows].T.reshape(-1, 2) * square_m

    def detect(frame: Frame, intrinsics: Intrinsics) -> Detection | None:
        import cv2

        gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(gray, (inner_cols, inner_rows), flags=flags)
        if not found:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
        if corners[inner_cols - 1, 0] < corners[0, 0]:  # a first guess at the half-turn, see above
            corners = corners[::-1].copy()
        ok, rvec, tvec = cv2.solvePnP(
            grid, corners, intrinsics.K, intrinsics.dist, flags=cv2.SOLVEPNP_ITERATIVE
        )
        if not ok:
            return None
        cam_T_target = np.eye(4)
        cam_T_target[:3, :3] = cv2.Rodrigues(rvec)[0]
        cam_T_target[:3, 3] = tvec.reshape(3)
        return Detection(cam_T_target, corners.astype(float), grid.copy())

    # capture_pose_pairs records it, so `cobotlab calibrate` resolves the half-turn later
    detect.target = TargetRecord("chessboard", {"inner_cols": int(inner_cols),
                                                "inner_rows": int(inner_rows),
                                                "square_m": float(square_m)}, True)
    return detect


# --------------------------------------------------------------------------- importing


def read_pose_text(path) -> np.ndarray:
    """Robot poses from a text file: one ``base_T_flange`` per line, the 16 numbers of the 4 x 4
    matrix in row-major order (metres), separated by spaces, tabs or commas; lines starting
    with ``#`` are skipped. This is the layout of RWHE-Calib's ``RobotPosesVec.txt``.
    Returns (n, 4, 4); ``ValueError`` names the first bad line."""
    poses = []
    for number, line in enumerate(Path(path).read_text().splitlines(), 1):
        text = line.split("#", 1)[0].replace(",", " ").strip()
        if not text:
            continue
        try:
            values = np.array([float(v) for v in text.split()])
        except ValueError:
            raise ValueError(f"{path}:{number}: not a list of numbers: {line.strip()[:60]!r}") from None
        if values.size != 16:
            raise ValueError(
                f"{path}:{number}: {values.size} numbers, expected 16 (a 4 x 4 base_T_flange, "
                "row-major, metres); convert quaternion or Euler-angle logs to matrices first")
        poses.append(values.reshape(4, 4))
    if not poses:
        raise ValueError(f"{path} holds no poses")
    poses = np.array(poses)
    if not np.allclose(poses[:, 3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        bad = int(np.flatnonzero(~np.all(np.isclose(poses[:, 3], [0, 0, 0, 1], atol=1e-6), axis=1))[0])
        raise ValueError(f"{path}: pose {bad} does not end in 0 0 0 1; is the matrix stored "
                         "column-major (transposed)?")
    return as_poses(poses, f"{path} poses")


#: Corners a view needs to be kept: the fewest cv2.calibrateCamera / solvePnP take from a
#: planar board with some margin against a degenerate view.
MIN_CORNERS = 6


@dataclass
class ViewCorners:
    """Corners found per view, before any pose is solved: ``corners`` (per view an (N_i, 2)
    pixel array or None when the target was not found), ``object_points`` (per view (N_i, 3)
    metres, target frame, or None), ``image_size`` (width, height) and the RGB ``images``
    (empty when the corners came from a file); ``reasons``: per view the detector's refusal
    with its rule, "" where the target was found (empty when the corners came from a file)."""

    corners: list
    object_points: list
    image_size: tuple[int, int]
    images: list = field(default_factory=list)
    #: per view, why its target was not found ("" when found or not said)
    reasons: list = field(default_factory=list)


def image_files(images_dir) -> list[Path]:
    """The images of a folder in name order, numbers compared as numbers (``image-2`` before
    ``image-10``): the order the pose file must follow."""
    from robots.pose_files import in_natural_order

    folder = Path(images_dir)
    if not folder.is_dir():
        raise FileNotFoundError(f"no image folder at {folder}")
    return in_natural_order(p for p in folder.iterdir()
                            if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp", ".tif",
                                                    ".tiff"))


def corners_from_images(images_dir, n_views: int, board=None, detect=None,
                        intrinsics: Intrinsics | None = None) -> ViewCorners:
    """Detect the target in each image of ``images_dir`` (one per pose, sorted by name).

    ``detect(frame, intrinsics) -> Detection | None``: any detector of ``robots.targets`` (a
    refusal's ``reason`` is kept per view), or ``board`` = (inner columns, inner rows,
    square m) for a plain chessboard. ``intrinsics``: the camera's, when known; the detectors
    also solve a pose, so without them a nominal camera stands in and only the corners are
    kept (the intrinsics may be calibrated from them next)."""
    import cv2

    if (board is None) == (detect is None):
        raise ValueError("give either board = (inner columns, inner rows, square_m) or detect")
    if detect is None:
        detect = chessboard_detector(*board)
    files = image_files(images_dir)
    if len(files) != n_views:
        raise ValueError(f"{images_dir} has {len(files)} images but the pose file {n_views} poses; "
                         "keep one image per pose, named so that they sort in pose order")
    images, corners, objects, reasons, size = [], [], [], [], None
    for path in files:
        rgb = _read_png(cv2, path)
        size = (rgb.shape[1], rgb.shape[0])
        camera = intrinsics or Intrinsics(float(size[0]), float(size[0]), size[0] / 2,
                                          size[1] / 2, size[0], size[1])
        found = detect(Frame(rgb=rgb, depth=None, timestamp=0.0), camera)
        ok = found is not None and found.ok
        images.append(rgb)
        corners.append(found.corners_px if ok else None)
        objects.append(found.object_points if ok else None)
        reasons.append("" if ok or found is None else found.reason)
    return ViewCorners(corners, objects, size, images, reasons)


def corners_from_file(corners_file, n_views: int) -> ViewCorners:
    """Corners from an ``.npz`` with ``corners_px`` (n, N, 2) pixels (NaN where a corner was not
    found), ``board_points_m`` (N, 3) metres and ``image_size_wh`` (the layout of
    ``autograder/data/rwhe_kuka``)."""
    with np.load(corners_file, allow_pickle=False) as data:
        missing = {"corners_px", "board_points_m", "image_size_wh"} - set(data.files)
        if missing:
            raise ValueError(f"{corners_file} lacks {', '.join(sorted(missing))}; it needs "
                             "corners_px (n, N, 2), board_points_m (N, 3), image_size_wh (2,)")
        pixels = np.array(data["corners_px"], dtype=float)
        board_points = np.array(data["board_points_m"], dtype=float)
        size = tuple(int(v) for v in data["image_size_wh"])
    if pixels.shape[0] != n_views or pixels.shape[1:] != (len(board_points), 2):
        raise ValueError(f"{corners_file} has corners of shape {pixels.shape} for {n_views} poses "
                         f"and {len(board_points)} board points; expected ({n_views}, "
                         f"{len(board_points)}, 2), one row of corners per pose line")
    corners, objects = [], []
    for view in pixels:
        ok = np.all(np.isfinite(view), axis=1)
        corners.append(view[ok])
        objects.append(board_points[ok])
    return ViewCorners(corners, objects, size)


#: With the camera's intrinsics given, a pose needs only 4 points (solvePnP on a planar
#: target, e.g. one marker's corners); MIN_CORNERS holds when they are calibrated from the views.
MIN_CORNERS_GIVEN_INTRINSICS = 4


def _refusal(found, reason: str, needed: int) -> str:
    if reason:
        return reason
    n = 0 if found is None else len(found)
    return (f"board not found: {n} corners found, at least {needed} needed" if n
            else "board not found: no corners detected")


def solve_board_poses(views: ViewCorners, intrinsics: Intrinsics | None = None):
    """Each kept view's ``cam_T_target`` (m) and the intrinsics used.

    A view is kept with at least ``MIN_CORNERS`` corners (``MIN_CORNERS_GIVEN_INTRINSICS``
    when the intrinsics are given: one marker's 4 corners then fix a pose). Given ``intrinsics`` are used as
    they are (``cv2.solvePnP`` per view); without them the camera is calibrated from every
    kept view's corners (``cv2.calibrateCamera``: K; k1, k2, p1, p2, k3) and the board poses
    are that calibration's. Returns (intrinsics, cam_T_target (M, 4, 4), kept view indices
    (M,), refused indices, the reason for each refused view). ``ValueError`` when fewer than 3
    views are kept, with the rule and each view's count."""
    import cv2

    n = len(views.corners)
    counts = [0 if c is None else len(c) for c in views.corners]
    needed = MIN_CORNERS if intrinsics is None else MIN_CORNERS_GIVEN_INTRINSICS
    keep = [i for i in range(n) if counts[i] >= needed]
    refused = [i for i in range(n) if i not in keep]
    reasons = [_refusal(views.corners[i], views.reasons[i] if views.reasons else "", needed)
               for i in refused]
    if len(keep) < 3:
        why = "; ".join(f"view {i}: {r}" for i, r in zip(refused, reasons))
        raise ValueError(
            f"the target was found in only {len(keep)} of {n} views; at least 3 are needed, "
            f"and a view counts with at least {needed} corners"
            + (" (6 when the intrinsics are calibrated from the views; give the camera's own "
               "calibration to need 4)" if intrinsics is None else "")
            + f" (corners found per view: {counts}; {why}). Check the target's geometry flags "
              "and that the images are in pose order")
    obj = [views.object_points[i].astype(np.float32) for i in keep]
    img = [views.corners[i].astype(np.float32).reshape(-1, 1, 2) for i in keep]
    if intrinsics is None:
        _, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, views.image_size, None, None)
        intrinsics = Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                                int(views.image_size[0]), int(views.image_size[1]),
                                dist.ravel()[:5].astype(float))
    else:
        rvecs, tvecs = [], []
        for o, c in zip(obj, img):
            ok, r, t = cv2.solvePnP(o, c, intrinsics.K, intrinsics.dist)
            rvecs.append(r)
            tvecs.append(t)
    cam_T_target = np.array([np.vstack([np.hstack([cv2.Rodrigues(r)[0], t.reshape(3, 1)]),
                                        [0.0, 0.0, 0.0, 1.0]]) for r, t in zip(rvecs, tvecs)])
    return intrinsics, cam_T_target, np.array(keep, dtype=np.int64), np.array(refused, dtype=np.int64), reasons


def capture_from_views(base_T_flange, views: ViewCorners, intrinsics: Intrinsics | None = None,
                       robot_name: str = "", camera_name: str = "") -> Capture:
    """A ``Capture`` from every view's ``base_T_flange`` (n, 4, 4), metres, and its corners
    (``solve_board_poses`` solves the board poses, and the intrinsics when not given)."""
    base_T_flange = as_poses(base_T_flange, "base_T_flange")
    if len(base_T_flange) != len(views.corners):
        raise ValueError(f"{len(base_T_flange)} robot poses but {len(views.corners)} views; "
                         "give one pose per image")
    intrinsics, cam_T_target, keep, failed, reasons = solve_board_poses(views, intrinsics)
    images = views.images
    return Capture(
        base_T_flange=base_T_flange[keep], cam_T_target=cam_T_target,
        corners_px=[views.corners[i] for i in keep],
        object_points=[views.object_points[i] for i in keep],
        intrinsics=intrinsics, commanded_base_T_flange=base_T_flange, pose_indices=keep,
        timestamps=np.zeros(len(keep)), images=[images[i] for i in keep] if images else [],
        failed_indices=failed, failed_reasons=reasons,
        failed_images=[images[i] if images else None for i in failed],
        robot_name=robot_name, camera_name=camera_name,
        created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )


def import_pose_text_capture(poses_file, corners_file=None, images_dir=None, board=None,
                             robot_name: str = "", camera_name: str = "",
                             intrinsics: Intrinsics | None = None) -> Capture:
    """A ``Capture`` from a robot pose text file and the board's corners or images.

    ``poses_file``: see ``read_pose_text``. Then either ``corners_file`` (see
    ``corners_from_file``) or ``images_dir`` (one image per pose, sorted by name) with
    ``board`` = (inner corner columns, rows, square size in metres) of a chessboard, detected
    here. ``intrinsics``: the camera's own calibration, used as given; without it the camera
    is calibrated from the corners (``solve_board_poses``). Views with fewer than
    ``MIN_CORNERS`` corners are recorded as failed, with the count. Other pose layouts and
    conventions: ``solutions.capture_import``.
    """
    base_T_flange = read_pose_text(poses_file)
    return capture_from_views(base_T_flange, read_views(len(base_T_flange), corners_file,
                                                        images_dir, board),
                              intrinsics, robot_name, camera_name)


def read_views(n_views: int, corners_file=None, images_dir=None, board=None, detect=None,
               intrinsics: Intrinsics | None = None) -> ViewCorners:
    """The corners of ``n_views`` views from ``corners_file``, or ``images_dir`` with ``board``
    (a chessboard) or ``detect`` (a ``robots.targets`` detector; ``corners_from_images``)."""
    if (corners_file is None) == (images_dir is None):
        raise ValueError("give either corners_file (an .npz of corners) or images_dir with board")
    if corners_file is not None:
        return corners_from_file(corners_file, n_views)
    if board is None and detect is None:
        raise ValueError("images_dir needs board = (inner columns, inner rows, square_m) or a "
                         "detector (detect=)")
    return corners_from_images(images_dir, n_views, board, detect, intrinsics)
