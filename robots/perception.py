"""Perception helpers for the visual-servoing lab: see a target, turn pixels into metres.

Everything here works on a :class:`~robots.interfaces.Frame` and the camera's
:class:`~robots.interfaces.Intrinsics`, on a simulated or a real camera alike.

* Target detectors (chessboard, ChArUco, single ArUco markers, asymmetric circle grid) return a
  :class:`~robots.capture.Detection`: ``cam_T_target`` (4, 4, metres) and the corner pixels with
  their object points, the same type :func:`robots.capture.capture_pose_pairs` stores.
* :func:`project` / :func:`deproject` go between camera-frame points (metres) and pixels, with
  the lens distortion in ``intrinsics.dist`` (OpenCV's model).
* :func:`base_T_cam_from` and :func:`to_base` map camera-frame points to the robot base through a
  saved calibration (``flange_T_cam`` for a wrist camera, ``base_T_cam`` for a fixed one).
* Chess boards: :func:`detect_chess_board` finds the board's pose from its inner corners and
  :func:`square_at` / :func:`square_centre` name the squares a1..h8.

Chess frame (the same as the simulator's): origin at the OUTER corner of square a1 on the
playing surface, x along the files (a -> h), y along the ranks (1 -> 8), z up out of the board.
Square (file f, rank r), both 0-based, has its centre at ``((f + 0.5) s, (r + 0.5) s, 0)``.

Servoing errors (:class:`ServoError` and its subclasses) live here too, so that lab code can
raise and catch them without importing the reference solutions.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from robots.capture import Detection, chessboard_detector
from robots.geometry import as_pose, compose, invert, make_pose, pose_from_rotvec, transform_points
from robots.interfaces import Frame, Intrinsics

__all__ = [
    "FILES",
    "ChessBoardDetection",
    "Detection",
    "ServoDivergedError",
    "ServoError",
    "ServoTimeoutError",
    "TargetLostError",
    "TargetOutOfViewError",
    "NORMALISED_MAX",
    "base_T_cam_from",
    "check_normalised",
    "deproject",
    "depth_at",
    "detect_aruco",
    "detect_charuco",
    "detect_chess_board",
    "detect_chessboard",
    "detect_circle_grid",
    "point_cloud",
    "project",
    "square_at",
    "square_centre",
    "square_index",
    "square_name",
    "to_base",
]

FILES = "abcdefgh"


# --------------------------------------------------------------------------- errors


class ServoError(RuntimeError):
    """A visual servo stopped without reaching its goal. The robot has been stopped."""


class TargetLostError(ServoError):
    """The target was not detected in the latest image."""


class TargetOutOfViewError(ServoError):
    """The target (or some of its features) left the image, or would with the next move."""


class ServoDivergedError(ServoError):
    """The servo error grew instead of shrinking (wrong sign, wrong calibration, bad gain)."""


class ServoTimeoutError(ServoError):
    """The servo (or a stage of the grasp) did not converge within its iteration/time budget."""


# --------------------------------------------------------------------------- pixels <-> metres

#: A normalised image coordinate (x = X / Z = (u - cx) / fx) beyond this in magnitude is a ray
#: more than 84 deg off the optical axis: no camera of the labs sees it (a D435's colour
#: camera sees about 35 deg off axis, a wide-angle lens 60). Pixels are 10 to thousands.
NORMALISED_MAX = 10.0


def _transposed_hint(arr: np.ndarray, dim: int, name: str) -> str:
    """"; transposed? ..." when ``arr`` is (dim, N) where (N, dim) was asked, else ""."""
    if arr.ndim == 2 and arr.shape[0] == dim:
        return f"; transposed? pass {name}.T (shape {arr.shape[::-1]})"
    return ""


def check_normalised(xy, name: str) -> np.ndarray:
    """``xy`` (..., 2), normalised image coordinates ``(x, y) = (X / Z, Y / Z)``, as a float64
    array; ``ValueError`` naming ``name`` when a coordinate exceeds ``NORMALISED_MAX`` (10) in
    magnitude: those are pixels, which must be normalised with K^-1 first.

    The shared check for everything that takes normalised coordinates (the servo laws, the
    lab 3 helpers). The shape's last axis must be 2 (a (2, N) array gets a "transposed?"
    hint); NaN is left to the caller."""
    arr = np.asarray(xy, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) (normalised image coordinates x, y), "
                         f"got shape {arr.shape}{_transposed_hint(arr, 2, name)}")
    if arr.size <= 64:  # a servo law's few features: plain floats beat numpy's call overhead
        flat = arr.ravel().tolist()
        if flat and -NORMALISED_MAX <= min(flat) and max(flat) <= NORMALISED_MAX:
            return arr
    big = np.abs(arr) > NORMALISED_MAX  # NaN compares False: not this check's business
    if big.any():
        k = np.unravel_index(int(np.argmax(big)), arr.shape)[:-1]
        at = f"{name}[{', '.join(map(str, k))}]" if k else name
        raise ValueError(
            f"{name} look like pixel coordinates, not normalised image coordinates: {at} = "
            f"{np.array2string(arr[k], precision=4)}, while a normalised coordinate x = X / Z "
            f"stays within +-{NORMALISED_MAX:g} (a ray 84 deg off the optical axis). Normalise "
            "the pixels with K^-1 first: [x, y, 1] = np.linalg.inv(K) @ [u, v, 1], i.e. "
            "x = (u - cx) / fx, y = (v - cy) / fy (with lens distortion: "
            "cv2.undistortPoints(uv, K, dist))")
    return arr


def _as_points(points, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}) or ({dim},), got "
                         f"{np.shape(points)}{_transposed_hint(arr, dim, name)}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is not finite ({arr[bad[0]]}); drop it first")
    return arr


def _undistort(uv, intrinsics: Intrinsics) -> np.ndarray:
    """Normalised coordinates (N, 2) of pixels (N, 2). ``cv2.undistortPoints``' default 5
    iterations leave ~1e-5 errors at the corners of a strongly distorted image; iterate to
    convergence instead (a no-op without distortion)."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 1, 2)
    if not np.any(intrinsics.dist):
        return ((uv.reshape(-1, 2) - [intrinsics.cx, intrinsics.cy])
                / [intrinsics.fx, intrinsics.fy])
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    return cv2.undistortPointsIter(uv, intrinsics.K, intrinsics.dist, None, None,
                                   criteria).reshape(-1, 2)


def project(points_cam, intrinsics: Intrinsics) -> np.ndarray:
    """Pixels (N, 2) of camera-frame points (N, 3) metres, with the lens distortion.

    The points must be in front of the camera (z > 0); a point behind it has no image and
    raises ValueError rather than wrapping round to a bogus pixel.
    """
    pts = _as_points(points_cam, 3, "points_cam")
    behind = np.flatnonzero(pts[:, 2] <= 0)
    if behind.size:
        raise ValueError(
            f"points_cam[{behind[0]}] has z = {pts[behind[0], 2]:.4g} m: it is behind the camera "
            "(the optical frame looks along +z); check the frame of the points"
        )
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), intrinsics.K, intrinsics.dist)
    return uv.reshape(-1, 2)


def deproject(uv, depth, intrinsics: Intrinsics) -> np.ndarray:
    """Camera-frame points (N, 3) metres from pixels (N, 2) and their depths (N,) metres.

    ``depth`` is the z coordinate (distance along the optical axis, what a RealSense or the
    simulator's depth image reports), not the range along the ray. Distortion is removed with
    ``cv2.undistortPoints``, so ``project(deproject(uv, z)) == uv``.
    """
    uv = _as_points(uv, 2, "uv")
    z = np.broadcast_to(np.asarray(depth, dtype=float).reshape(-1), (len(uv),))
    bad = np.flatnonzero(~(np.isfinite(z) & (z > 0)))
    if bad.size:
        raise ValueError(
            f"depth[{bad[0]}] = {z[bad[0]]}: depths must be positive finite metres; a NaN depth "
            "pixel has no measurement, use depth_at() to take the median of its neighbours"
        )
    xy = _undistort(uv, intrinsics)
    return np.column_stack([xy * z[:, None], z])


def depth_at(frame: Frame, uv, window: int = 5) -> np.ndarray:
    """Median of the valid depths (metres) in a ``window`` x ``window`` box around each pixel.

    Returns (N,) with NaN where the whole box has no measurement (or lies outside the image).
    """
    if frame.depth is None:
        raise ValueError("this frame has no depth image; use an RGB-D camera or give depths")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be a positive odd number of pixels, got {window}")
    uv = _as_points(uv, 2, "uv")
    h, w = frame.depth.shape
    r = window // 2
    out = np.full(len(uv), np.nan)
    for i, (u, v) in enumerate(np.rint(uv).astype(int)):
        patch = frame.depth[max(v - r, 0):min(v + r + 1, h), max(u - r, 0):min(u + r + 1, w)]
        valid = patch[np.isfinite(patch) & (patch > 0)]
        if valid.size:
            out[i] = float(np.median(valid))
    return out


def point_cloud(depth, intrinsics: Intrinsics) -> np.ndarray:
    """Organised point cloud (H, W, 3) metres in the camera frame from a depth image (H, W).

    NaN where the depth is missing. Distortion is removed per pixel.
    """
    depth = np.asarray(depth, dtype=float)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth has shape {depth.shape} but the intrinsics are for "
            f"{intrinsics.height}x{intrinsics.width}; give the depth image of that camera"
        )
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=float),
                       np.arange(intrinsics.height, dtype=float))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    xy = _undistort(uv, intrinsics).reshape(depth.shape + (2,))
    z = np.where(depth > 0, depth, np.nan)
    return np.concatenate([xy * z[..., None], z[..., None]], axis=2)


# --------------------------------------------------------------------------- calibration


def base_T_cam_from(calibration, base_T_flange=None) -> np.ndarray:
    """The camera pose in the base frame from a saved calibration.

    ``calibration`` is a :class:`~robots.calibration_io.CalibrationResult` (or a path to its
    YAML file) holding ``flange_T_cam`` (wrist camera: then ``base_T_flange``, the robot's
    current ``flange_pose()``, is required) or ``base_T_cam`` (fixed camera).
    """
    from robots.calibration_io import CalibrationResult, load_calibration

    if not isinstance(calibration, CalibrationResult):
        calibration = load_calibration(calibration)
    if (calibration.parent, calibration.child) == ("base", "cam"):
        return calibration.pose.copy()
    if (calibration.parent, calibration.child) == ("flange", "cam"):
        if base_T_flange is None:
            raise ValueError(
                "a flange_T_cam calibration needs base_T_flange: pass robot.flange_pose() "
                "read when the picture was taken"
            )
        return compose(as_pose(base_T_flange, "base_T_flange"), calibration.pose)
    raise ValueError(
        f"calibration is {calibration.name}; expected flange_T_cam (wrist camera) or base_T_cam "
        "(fixed camera)"
    )


def to_base(points_cam, calibration, base_T_flange=None) -> np.ndarray:
    """Map camera-frame points (N, 3) metres to the robot base frame through a calibration
    (see :func:`base_T_cam_from` for the arguments)."""
    pts = _as_points(points_cam, 3, "points_cam")
    return transform_points(base_T_cam_from(calibration, base_T_flange), pts)


# --------------------------------------------------------------------------- target detectors


def _gray(frame: Frame) -> np.ndarray:
    if not isinstance(frame, Frame):
        raise ValueError(  # noqa: TRY004 (the project reports all bad input as ValueError)
            f"expected a robots.interfaces.Frame, got {type(frame).__name__}")
    return cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)


def _solve_pnp(object_points, corners, intrinsics: Intrinsics, flags=cv2.SOLVEPNP_ITERATIVE):
    ok, rvec, tvec = cv2.solvePnP(np.asarray(object_points, float), np.asarray(corners, float),
                                  intrinsics.K, intrinsics.dist, flags=flags)
    if not ok:
        return None
    return pose_from_rotvec(rvec.ravel(), tvec.ravel())


def detect_chessboard(frame: Frame, intrinsics: Intrinsics, inner_cols: int, inner_rows: int,
                      square_m: float) -> Detection | None:
    """A plain chessboard of ``inner_cols`` x ``inner_rows`` inner corners, squares of
    ``square_m`` metres (the detector of :mod:`robots.capture`). None if not found.

    Target frame: the first detected inner corner, x along a row of corners, y down the
    columns, z into the board (OpenCV's convention).
    """
    return chessboard_detector(inner_cols, inner_rows, square_m)(frame, intrinsics)


def detect_charuco(frame: Frame, intrinsics: Intrinsics, board, min_corners: int = 6
                   ) -> Detection | None:
    """A ChArUco board (a ``cv2.aruco.CharucoBoard``, its squares and markers in metres).

    Uses OpenCV 4.x's ``cv2.aruco.CharucoDetector``. Target frame: the board's own (top-left
    outer corner, x right, y down, z into the board). None if fewer than ``min_corners``
    ChArUco corners are found (a pose from very few corners is unreliable).
    """
    if not isinstance(board, cv2.aruco.CharucoBoard):
        raise ValueError("board must be a cv2.aruco.CharucoBoard (make one with "  # noqa: TRY004
                         "cv2.aruco.CharucoBoard((cols, rows), square_m, marker_m, dictionary))")
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(_gray(frame))
    if ids is None or len(ids) < max(min_corners, 4):
        return None
    objp = board.getChessboardCorners()[ids.ravel()]
    corners = corners.reshape(-1, 2)
    pose = _solve_pnp(objp, corners, intrinsics)
    return None if pose is None else Detection(pose, corners, objp)


def _square_pose(objp, corners, intrinsics) -> np.ndarray:
    """Pose of a square marker: both IPPE solutions, the one that reprojects best, refined
    with Levenberg-Marquardt. (A nearly fronto-parallel square has two poses that fit almost
    equally; taking IPPE's first answer alone was measured 13 px off in such a view.)"""
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(objp, corners, intrinsics.K, intrinsics.dist,
                                             flags=cv2.SOLVEPNP_IPPE_SQUARE)
    best = None
    for rvec, tvec in zip(rvecs, tvecs):
        rvec, tvec = cv2.solvePnPRefineLM(objp, corners, intrinsics.K, intrinsics.dist,
                                          rvec.copy(), tvec.copy())
        proj, _ = cv2.projectPoints(objp, rvec, tvec, intrinsics.K, intrinsics.dist)
        err = float(np.sum((proj.reshape(-1, 2) - corners) ** 2))
        if best is None or err < best[0]:
            best = (err, rvec, tvec)
    # cv2.Rodrigues, not pose_from_rotvec: LM may return its rotation vector unwrapped (a
    # length of 3e8 rad was seen), a right rotation that pose_from_rotvec would rightly
    # question as degrees.
    return make_pose(cv2.Rodrigues(best[1])[0], best[2].ravel())


def detect_aruco(frame: Frame, intrinsics: Intrinsics, marker_m: float,
                 dictionary: int = cv2.aruco.DICT_5X5_100) -> dict[int, Detection]:
    """Every ArUco marker of side ``marker_m`` metres in the image, as ``{id: Detection}``.

    ``dictionary`` is an OpenCV predefined dictionary id (the simulator prints DICT_5X5_100).
    Target frame: OpenCV's marker frame (marker centre, x right, y up, z out of the marker);
    corners are listed top-left, top-right, bottom-right, bottom-left. The pose comes from
    ``SOLVEPNP_IPPE_SQUARE``; empty dict if no marker is seen.
    """
    if not marker_m > 0:
        raise ValueError(f"marker_m must be the marker's side in metres (> 0), got {marker_m}")
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(dictionary), params)
    corners, ids, _ = detector.detectMarkers(_gray(frame))
    if ids is None:
        return {}
    h = marker_m / 2
    objp = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    out = {}
    for marker_id, c in zip(ids.ravel(), corners):
        c = c.reshape(4, 2).astype(float)
        out[int(marker_id)] = Detection(_square_pose(objp, c, intrinsics), c, objp.copy())
    return out


def detect_circle_grid(frame: Frame, intrinsics: Intrinsics, pattern_size: tuple[int, int],
                       spacing_m: float) -> Detection | None:
    """An asymmetric circle grid: ``pattern_size = (circles per row, rows)``, circle
    (row i, column j) at ``((2 j + i % 2) spacing, i spacing, 0)`` (OpenCV's layout).

    Target frame: the first circle's centre, x right, y down, z into the board.
    """
    cols, rows = (int(n) for n in pattern_size)
    if cols < 2 or rows < 3 or not spacing_m > 0:
        raise ValueError("an asymmetric circle grid needs >= 2 circles per row, >= 3 rows and "
                         f"a positive spacing; got {pattern_size}, {spacing_m}")
    ok, centres = cv2.findCirclesGrid(_gray(frame), (cols, rows),
                                      flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
    if not ok:
        return None
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    objp = np.stack([(2 * j + i % 2).ravel() * spacing_m, i.ravel() * spacing_m,
                     np.zeros(rows * cols)], axis=1)
    centres = centres.reshape(-1, 2)
    pose = _solve_pnp(objp, centres, intrinsics)
    return None if pose is None else Detection(pose, centres, objp)


# --------------------------------------------------------------------------- chess board


def square_name(file: int, rank: int) -> str:
    """'a1'..'h8' from a 0-based file (a = 0) and rank (rank 1 = 0)."""
    if not (0 <= int(file) < 8 and 0 <= int(rank) < 8):
        raise ValueError(f"file and rank must be in 0..7, got ({file}, {rank})")
    return f"{FILES[int(file)]}{int(rank) + 1}"


def square_index(name: str) -> tuple[int, int]:
    """(file, rank), both 0-based, of a square name such as 'e4'."""
    if not (isinstance(name, str) and len(name) == 2 and name[0] in FILES
            and name[1] in "12345678"):
        raise ValueError(f"square names run 'a1'..'h8' (file letter, rank digit), got {name!r}")
    return FILES.index(name[0]), int(name[1]) - 1


def square_centre(name: str, square_m: float) -> np.ndarray:
    """Centre (3,) of a square on the playing surface, in the chess frame, metres."""
    f, r = square_index(name)
    return np.array([(f + 0.5) * square_m, (r + 0.5) * square_m, 0.0])


def square_at(points_chess, square_m: float) -> list[str | None]:
    """Name of the square under each chess-frame point (N, 3), or None off the board.

    Only x and y count (a piece's top names the square it stands on).
    """
    pts = _as_points(points_chess, 3, "points_chess")
    f = np.floor(pts[:, 0] / square_m).astype(int)
    r = np.floor(pts[:, 1] / square_m).astype(int)
    return [square_name(a, b) if 0 <= a < 8 and 0 <= b < 8 else None for a, b in zip(f, r)]


@dataclass
class ChessBoardDetection:
    """A detected chess board: ``cam_T_chess`` (4, 4) in the chess frame described in the
    module docstring, the 49 inner corners in pixels (7 x 7, row-major from the corner between
    a1, b1, a2 and b2 along the files), and the square size in metres."""

    cam_T_chess: np.ndarray
    corners_px: np.ndarray
    square_m: float
    reprojection_px: float

    def square_of(self, points_cam) -> list[str | None]:
        """Square names under camera-frame points (N, 3)."""
        return square_at(transform_points(invert(self.cam_T_chess), points_cam), self.square_m)

    def cam_T_square(self, name: str) -> np.ndarray:
        """Pose of a square's centre (chess-frame axes) in the camera frame."""
        return compose(self.cam_T_chess, make_pose(t=square_centre(name, self.square_m)))


# The eight ways a 7x7 grid of corners can be listed (4 turns, with and without a mirror).
def _grid_orders(n: int = 7) -> list[np.ndarray]:
    idx = np.arange(n * n).reshape(n, n)
    orders = []
    for mirrored in (False, True):
        g = idx.T if mirrored else idx
        for k in range(4):
            orders.append(np.rot90(g, k).ravel())
    return orders


def _square_brightness(gray, cam_T_chess, square_m, intrinsics) -> np.ndarray:
    """Median brightness (8, 8) [file, rank] sampled near each square's four corners, where a
    piece standing on the square's centre hides the board least."""
    out = np.full((8, 8), np.nan)
    h, w = gray.shape
    offsets = np.array([[0.12, 0.12], [0.88, 0.12], [0.12, 0.88], [0.88, 0.88]]) * square_m
    for f in range(8):
        for r in range(8):
            pts = np.column_stack([f * square_m + offsets[:, 0], r * square_m + offsets[:, 1],
                                   np.zeros(4)])
            cam = transform_points(cam_T_chess, pts)
            if np.any(cam[:, 2] <= 0):
                continue
            uv = np.rint(project(cam, intrinsics)).astype(int)
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
            if inside.any():
                out[f, r] = np.median(gray[uv[inside, 1], uv[inside, 0]])
    return out


# findChessboardCornersSB's flags help on some images and hurt on others (pieces on the board
# break the pattern's outer ring); measured on simulated boards under the lighting presets,
# no single setting found every board but trying these in turn did.
_SB_FLAG_SETS = (
    cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_NORMALIZE_IMAGE,
    cv2.CALIB_CB_EXHAUSTIVE,
    cv2.CALIB_CB_NORMALIZE_IMAGE,
    cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE,
)


def _inner_corner_candidates(gray):
    """Yield candidate 7 x 7 inner-corner sets (49, 2), pixels, from several detector settings.

    A candidate can be wrong (the board's dark frame read as a row of squares), so the caller
    validates each one against the checker pattern and keeps the first that fits.
    """
    for flags in _SB_FLAG_SETS:
        found, corners = cv2.findChessboardCornersSB(gray, (7, 7), flags=flags)
        if found:
            yield corners.reshape(-1, 2).astype(float)
    found, corners = cv2.findChessboardCorners(
        gray, (7, 7), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if found:
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
        yield cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)


# At most this many of the 49 inner corners may be dropped as outliers: a piece standing next
# to a corner can hide it or pull the detector's estimate of it off by several pixels (on a
# seeded random position a black rook beside a corner was measured 14 px and 22 px off, and
# one such corner alone lifted the whole fit's rms above 2 px). Kept below 7 so a grid shifted
# by one row (the board's dark frame read as squares: a whole row of 7 corners wrong) can
# never be made to fit by dropping that row.
_MAX_CORNER_OUTLIERS = 4


def _robust_board_pose(objp, img, intrinsics, max_rms_px: float = 1.0,
                       max_outliers: int = _MAX_CORNER_OUTLIERS):
    """PnP on the board's inner corners that drops bad corners one at a time (the worst
    residual first, then a refit) until the rest fit within ``max_rms_px`` rms.

    Returns ``(cam_T_chess, inlier mask (N,), rms px of the inliers)`` or None when more than
    ``max_outliers`` corners would have to go (the candidate is wrong, not occluded).
    """
    inliers = np.ones(len(objp), bool)
    for _ in range(max_outliers + 1):
        pose = _solve_pnp(objp[inliers], img[inliers], intrinsics)
        # In front of the camera, and the chess z axis (up) pointing towards the camera.
        if pose is None or pose[2, 3] <= 0 or pose[:3, 2] @ pose[:3, 3] >= 0:
            return None
        err = np.linalg.norm(project(transform_points(pose, objp), intrinsics) - img, axis=1)
        rms = float(np.sqrt(np.mean(err[inliers] ** 2)))
        if rms <= max_rms_px:
            return pose, inliers, rms
        worst = np.flatnonzero(inliers)[np.argmax(err[inliers])]
        inliers[worst] = False
    return None


def _consistent_poses(corners, objp, gray, square_m, intrinsics, max_outliers: int = 0):
    """The orderings of ``corners`` that give a pose that fits them (rms < 1 px over all but at
    most ``max_outliers`` corners), with the board's z axis towards the camera and a
    consistent checker pattern with a1 dark.

    Returns a list of (cam_T_chess, corners in object order, rms px); empty if none fit. An
    outlier corner is replaced by the fitted pose's projection of it.
    """
    parity = (np.add.outer(np.arange(8), np.arange(8)) % 2) == 0
    kept = []
    for order in _grid_orders():
        img = corners[np.argsort(order)]  # img[k] is the pixel of object point k
        fit = _robust_board_pose(objp, img, intrinsics, max_outliers=max_outliers)
        if fit is None:
            continue
        pose, inliers, rms = fit
        if not inliers.all():
            img = img.copy()
            img[~inliers] = project(transform_points(pose, objp[~inliers]), intrinsics)
        b = _square_brightness(gray, pose, square_m, intrinsics)
        valid = np.isfinite(b)
        if valid.sum() < 32:
            continue
        dark, light = np.median(b[parity & valid]), np.median(b[~parity & valid])
        # Every square must side with its own colour (pieces may hide a few samples).
        threshold = (dark + light) / 2
        agree = np.where(parity, b < threshold, b > threshold)[valid].mean()
        if dark < light and agree >= 0.9:
            kept.append((pose, img, rms))
    return kept


def _board_candidates(gray, objp, square_m, intrinsics):
    """The consistent poses (see :func:`_consistent_poses`) of the first corner candidate that
    fits whole, else of the first that fits once a few outlier corners are dropped."""
    tried = []
    for corners in _inner_corner_candidates(gray):
        tried.append(corners)
        kept = _consistent_poses(corners, objp, gray, square_m, intrinsics)
        if kept:
            return kept
    for corners in tried:
        kept = _consistent_poses(corners, objp, gray, square_m, intrinsics, _MAX_CORNER_OUTLIERS)
        if kept:
            return kept
    return []


def _pieces_painted_out(gray, depth, intrinsics, square_m: float,
                        min_height_m: float = 0.004):
    """``gray`` with everything standing more than ``min_height_m`` out of the surface around
    it in the depth image (the pieces on the board) inpainted from its surroundings, or None
    when the depth image holds too few measurements.

    No plane is fitted: a morphological closing of the depth image with a disc wider than a
    square (``across`` below) fills every patch nearer to the camera that the disc does not
    fit in (a piece, or two touching ones) with the depth around it, and leaves a flat or
    tilted surface as it is (a closing keeps a linear function). Its difference from the depth
    is how far a pixel stands out, along the ray. A 5 x 5 median first keeps depth noise of a
    few millimetres from standing out."""
    z = np.asarray(depth, dtype=np.float32)
    valid = np.isfinite(z) & (z > 0)
    if valid.sum() < 500:
        return None
    # The disc spans 1.5 squares at the median depth in view: wider than any piece, and
    # besides the pieces its closing fills at most the tips of the board's outer corners, a
    # square away from the inner corners the detectors look for.
    across = 1.5
    size = int(np.ceil(intrinsics.fx * across * square_m / float(np.median(z[valid])))) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    # Holes become depth 0, nearer than anything: the closing fills them from their rims
    # instead of spreading them over the board (and they are left out of the mask).
    surface = cv2.medianBlur(np.where(valid, z, 0.0).astype(np.float32), 5)
    closed = cv2.morphologyEx(surface, cv2.MORPH_CLOSE, disc, borderType=cv2.BORDER_REPLICATE)
    above = valid & (closed - surface > min_height_m)
    mask = cv2.dilate(above.astype(np.uint8), np.ones((3, 3), np.uint8))
    return cv2.inpaint(gray, mask, 3, cv2.INPAINT_TELEA)


def detect_chess_board(frame: Frame, intrinsics: Intrinsics, square_m: float,
                       white_side_cam=None) -> ChessBoardDetection | None:
    """Find a chess board (8 x 8 squares of ``square_m`` metres) and its pose, or None.

    Uses the 7 x 7 inner corners (pieces standing on square centres leave them visible from
    above). A square board's corners can be listed in eight orders; the pose is fixed by
    (1) the board lying in front of the camera with its z axis towards the camera, (2) a1
    being a DARK square (which rules out quarter turns) and (3) White's side: rank 1 is the
    rank nearest ``white_side_cam``, a point in the camera frame on White's side of the board
    (for a robot playing White, the robot base: ``invert(base_T_cam)[:3, 3]``). Without it,
    rank 1 is taken to be the rank nearest the bottom of the image (the view of a player
    sitting at White's side).

    Robust to pieces: a few inner corners that pieces hide or pull off are dropped from the
    fit, and with a depth image (``frame.depth``) everything standing on the board is painted
    out when the plain image shows no board.
    """
    if not square_m > 0:
        raise ValueError(f"square_m must be the square size in metres (> 0), got {square_m}")
    gray = _gray(frame)
    # Object points of the inner corners in the chess frame, row-major along the files.
    fi, ri = np.meshgrid(np.arange(1, 8), np.arange(1, 8))
    objp = np.column_stack([fi.ravel() * square_m, ri.ravel() * square_m, np.zeros(49)])
    # Every candidate must first fit whole; only when none does may a few corners that pieces
    # hide or pull off be dropped (a strict fit is never replaced by a looser one).
    kept = _board_candidates(gray, objp, square_m, intrinsics)
    if not kept and frame.depth is not None:
        # Pieces can break the pattern so that no detector finds all 49 corners (black pieces
        # on dark squares by a corner); with a depth image they can be painted out first.
        clean = _pieces_painted_out(gray, frame.depth, intrinsics, square_m)
        if clean is not None:
            kept = _board_candidates(clean, objp, square_m, intrinsics)
    if not kept:
        return None

    def rank1_distance(pose):
        rank1_mid = transform_points(pose, [[4 * square_m, 0.0, 0.0]])[0]
        rank8_mid = transform_points(pose, [[4 * square_m, 8 * square_m, 0.0]])[0]
        if white_side_cam is not None:
            p = _as_points(white_side_cam, 3, "white_side_cam")[0]
            return np.linalg.norm(rank1_mid - p) - np.linalg.norm(rank8_mid - p)
        uv = project(np.array([rank1_mid, rank8_mid]), intrinsics)
        return uv[0, 1] * -1.0 + uv[1, 1]  # rank 1 lower in the image (larger v) is better

    pose, img, rms = min(kept, key=lambda c: rank1_distance(c[0]))
    return ChessBoardDetection(pose, img, float(square_m), rms)
