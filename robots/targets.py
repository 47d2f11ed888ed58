"""Calibration targets besides the plain chessboard: markers, ChArUco boards, circle grids.

Every detector here is built by a factory and called as ``detect(frame, intrinsics) ->
Detection`` like :func:`robots.capture.chessboard_detector`. A view that is refused comes back
as a ``Detection`` with ``ok=False`` and a ``reason`` that states the rule (how many points were
found, how many are needed), never as a bare None:

- :func:`chessboard_with_reasons`: :func:`robots.capture.chessboard_detector` with a reason
  when the board is not found (that one returns None, which its callers expect);
- :func:`aruco_detector`: one ArUco or AprilTag marker, or a grid of them (``cv2.aruco``);
- :func:`charuco_detector`: a ChArUco board (chessboard corners identified by markers);
- :func:`circle_grid_detector`: a symmetric or asymmetric circle grid.

A target frame's origin and axes follow OpenCV's board classes: for markers and ChArUco the
x axis runs along the board's first row and the points lie at z = 0, metres.

A plain chessboard or a symmetric circle grid may come half a turn round: resolve its order
from the robot's motion with :mod:`robots.half_turn`.
"""

from __future__ import annotations

import numpy as np

from robots.capture import Detection, chessboard_detector
from robots.half_turn import planar_pose
from robots.interfaces import Frame, Intrinsics

__all__ = [
    "MIN_POINTS",
    "aruco_detector",
    "chessboard_with_reasons",
    "charuco_detector",
    "circle_grid_detector",
]

#: solvePnP on a planar target with known intrinsics needs 4 points, not all on one line.
MIN_POINTS = 4


# --------------------------------------------------------------------------- pose from points


def _refused(reason: str) -> Detection:
    return Detection(None, np.zeros((0, 2)), np.zeros((0, 3)), ok=False, reason=reason)


def _detection(object_points, pixels, intrinsics: Intrinsics, what: str) -> Detection:
    """A Detection with its PnP pose, or a refusal naming the rule."""
    object_points = np.asarray(object_points, float).reshape(-1, 3)
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    if len(pixels) < MIN_POINTS:
        return _refused(f"{what}: found {len(pixels)} points, at least {MIN_POINTS} are needed "
                        "for a pose (solvePnP on a planar target)")
    # Points on one line fix no pose: the second singular value of the centred points is ~0.
    spread = np.linalg.svd(object_points[:, :2] - object_points[:, :2].mean(axis=0),
                           compute_uv=False)
    if spread[1] < 1e-6 * max(spread[0], 1e-12):
        return _refused(f"{what}: the {len(pixels)} points found lie on one line; a pose needs "
                        f"at least {MIN_POINTS} points not all on one line")
    pose = planar_pose(object_points, pixels, intrinsics)
    if pose is None:
        return _refused(f"{what}: solvePnP found no pose for the {len(pixels)} points")
    return Detection(pose, pixels, object_points)


def _gray(frame: Frame) -> np.ndarray:
    import cv2

    rgb = np.asarray(frame.rgb)
    return rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def _dictionary(name: str):
    import cv2

    if not isinstance(name, str) or not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise ValueError(f"dictionary must be a cv2.aruco dictionary name such as "
                         f"'DICT_APRILTAG_36h11' or 'DICT_4X4_50', got {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def _positive(value, name: str, unit: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number of {unit}, got {value!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number of {unit}, got {value}")
    if unit == "metres" and value > 5.0:
        raise ValueError(f"{name} = {value} m is larger than any printed target; give it in "
                         "metres (e.g. 0.048 for a 48 mm tag), not millimetres")
    return value


def _count(value, name: str, minimum: int) -> int:
    if isinstance(value, (bool, np.bool_)) or int(value) != value or int(value) < minimum:
        raise ValueError(f"{name} must be a whole number >= {minimum}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- chessboards


def chessboard_with_reasons(inner_cols: int, inner_rows: int, square_m: float):
    """Return ``detect(frame, intrinsics) -> Detection`` for a plain chessboard of
    ``inner_cols`` x ``inner_rows`` inner corners, ``square_m`` metres: the detection of
    :func:`robots.capture.chessboard_detector`, or a refusal with its rule (OpenCV finds a
    chessboard whole or not at all, so every inner corner is needed)."""
    square_m = _positive(square_m, "square_m", "metres")
    detect_board = chessboard_detector(inner_cols, inner_rows, square_m)
    needed = inner_cols * inner_rows

    def detect(frame: Frame, intrinsics: Intrinsics) -> Detection:
        found = detect_board(frame, intrinsics)
        if found is None:
            return _refused(f"{inner_cols} x {inner_rows} chessboard: not found whole; all "
                            f"{needed} inner corners are needed (count inner corners, not "
                            "squares: a board of 10 x 7 squares has 9 x 6; keep it fully in view)")
        return found

    return detect


# --------------------------------------------------------------------------- markers


def aruco_detector(dictionary: str, marker_m: float, ids=None, grid=None, separation_m=None):
    """Return ``detect(frame, intrinsics) -> Detection`` for ArUco or AprilTag markers.

    ``dictionary``: a ``cv2.aruco`` dictionary name, e.g. ``"DICT_APRILTAG_36h11"``;
    ``marker_m``: the black square's side, metres. One marker: ``ids`` = (its id,) or None
    (any one marker of the dictionary; refused when several are seen). A grid: ``grid`` =
    (columns, rows) and ``separation_m`` the gap between markers, metres; ``ids`` the grid's
    ids in row order (default 0, 1, ...). Each marker gives its 4 corners (OpenCV's order:
    top-left, top-right, bottom-right, bottom-left of the marker as printed); the pose comes
    from SQPnP on all corners found. The single marker's frame is centred on it, x to its
    right, y up as printed, z out of it towards the camera (OpenCV's marker convention).
    """
    import cv2

    aruco_dict = _dictionary(dictionary)
    marker_m = _positive(marker_m, "marker_m", "metres")
    if grid is None:
        if ids is not None and len(tuple(ids)) != 1:
            raise ValueError(f"ids of a single marker must hold one id, got {ids!r}; "
                             "give grid=(columns, rows) for several markers")
        half = marker_m / 2.0
        corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0],
                            [-half, -half, 0]], np.float32)
        wanted = None if ids is None else [int(tuple(ids)[0])]
        board = None
        what = f"{dictionary} marker" + ("" if wanted is None else f" id {wanted[0]}")
    else:
        cols, rows = (_count(v, f"grid[{k}]", 1) for k, v in enumerate(grid))
        gap = _positive(separation_m, "separation_m", "metres")
        grid_ids = None if ids is None else np.asarray(ids, np.int32)
        board = cv2.aruco.GridBoard((cols, rows), marker_m, gap, aruco_dict, grid_ids)
        wanted = [int(v) for v in board.getIds().ravel()]
        what = f"{cols} x {rows} grid of {dictionary} markers"
    params = cv2.aruco.DetectorParameters()
    # Without refinement the corners are whole pixels, a 0.3 px error per corner for nothing.
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dict, params)

    def detect(frame: Frame, intrinsics: Intrinsics) -> Detection:
        found, found_ids, _ = detector.detectMarkers(_gray(frame))
        found_ids = [] if found_ids is None else [int(v) for v in found_ids.ravel()]
        keep = [k for k, v in enumerate(found_ids) if wanted is None or v in wanted]
        if board is None:
            if len(keep) != 1:
                many = f"{len(keep)} markers (ids {[found_ids[k] for k in keep]})" if keep \
                    else "no marker"
                return _refused(f"{what}: found {many}; exactly 1 is needed (give its id with "
                                "ids=(id,) when several are in view)")
            return _detection(corners, found[keep[0]].reshape(4, 2), intrinsics, what)
        if not keep:
            return _refused(f"{what}: found no marker of the grid (ids {wanted[0]}-"
                            f"{wanted[-1]}); at least 1 marker (4 corners) is needed")
        obj, img = board.matchImagePoints([found[k] for k in keep],
                                          np.array([found_ids[k] for k in keep], np.int32))
        return _detection(obj, img, intrinsics, f"{what} ({len(keep)} markers found)")

    return detect


def charuco_detector(squares_x: int, squares_y: int, square_m: float, marker_m: float,
                     dictionary: str = "DICT_4X4_50", legacy: bool = False):
    """Return ``detect(frame, intrinsics) -> Detection`` for a ChArUco board.

    ``squares_x`` x ``squares_y`` squares of ``square_m`` metres, markers of ``marker_m``
    metres from ``dictionary`` (ids 0, 1, ... in row order). ``legacy=True`` for boards made
    before OpenCV 4.6, whose even-row pattern starts with a black square. The corners are the
    inner chessboard corners that the markers identify, so the order never flips; a view needs
    at least ``MIN_POINTS`` of them.
    """
    import cv2

    sx, sy = _count(squares_x, "squares_x", 2), _count(squares_y, "squares_y", 2)
    square_m = _positive(square_m, "square_m", "metres")
    marker_m = _positive(marker_m, "marker_m", "metres")
    if marker_m >= square_m:
        raise ValueError(f"marker_m ({marker_m} m) must be smaller than square_m ({square_m} m)")
    board = cv2.aruco.CharucoBoard((sx, sy), square_m, marker_m, _dictionary(dictionary))
    board.setLegacyPattern(bool(legacy))
    detector = cv2.aruco.CharucoDetector(board)
    chessboard = board.getChessboardCorners()
    what = f"{sx} x {sy} ChArUco board ({dictionary})"

    def detect(frame: Frame, intrinsics: Intrinsics) -> Detection:
        corners, corner_ids, _, marker_ids = detector.detectBoard(_gray(frame))
        if corner_ids is None or len(corner_ids) == 0:
            markers = 0 if marker_ids is None else len(marker_ids)
            return _refused(f"{what}: found {markers} markers and no identified corner; at "
                            f"least {MIN_POINTS} corners are needed (check the dictionary, the "
                            "square count and legacy=)")
        return _detection(chessboard[corner_ids.ravel()], corners.reshape(-1, 2), intrinsics,
                          what)

    return detect


def circle_grid_detector(cols: int, rows: int, spacing_m: float, asymmetric: bool = False):
    """Return ``detect(frame, intrinsics) -> Detection`` for a grid of circles.

    ``cols`` x ``rows`` circle centres (OpenCV's pattern size), ``spacing_m`` metres between
    neighbouring centres of a row (asymmetric grids: the rows are offset by half of it, OpenCV's
    layout). The whole grid must be found. A symmetric grid has the chessboard's half-turn
    ambiguity: pass the capture through :func:`robots.half_turn.resolve_half_turns`.
    """
    import cv2

    cols, rows = _count(cols, "cols", 2), _count(rows, "rows", 2)
    spacing_m = _positive(spacing_m, "spacing_m", "metres")
    i, j = np.mgrid[0:rows, 0:cols]
    if asymmetric:
        x, y = (2 * j + i % 2) * spacing_m / 2.0, i * spacing_m / 2.0
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID
    else:
        x, y = j * spacing_m, i * spacing_m
        flags = cv2.CALIB_CB_SYMMETRIC_GRID
    grid = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    what = f"{cols} x {rows} {'asymmetric ' if asymmetric else ''}circle grid"

    def detect(frame: Frame, intrinsics: Intrinsics) -> Detection:
        found, centres = cv2.findCirclesGrid(_gray(frame), (cols, rows), flags=flags)
        if not found:
            return _refused(f"{what}: not found whole; all {cols * rows} circles are needed "
                            "(check cols x rows and that the grid is fully in view)")
        return _detection(grid, centres.reshape(-1, 2), intrinsics, what)

    return detect
