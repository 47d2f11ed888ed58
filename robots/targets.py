"""Calibration targets besides the plain chessboard, and the chessboard's half-turn resolved.

Every detector here is built by a factory and called as ``detect(frame, intrinsics) ->
Detection`` like :func:`robots.capture.chessboard_detector`. A view that is refused comes back
as a ``Detection`` with ``ok=False`` and a ``reason`` that states the rule (how many points were
found, how many are needed), never as a bare None:

- :func:`aruco_detector`: one ArUco or AprilTag marker, or a grid of them (``cv2.aruco``);
- :func:`charuco_detector`: a ChArUco board (chessboard corners identified by markers);
- :func:`circle_grid_detector`: a symmetric or asymmetric circle grid.

A target frame's origin and axes follow OpenCV's board classes: for markers and ChArUco the
x axis runs along the board's first row and the points lie at z = 0, metres.

**The chessboard's half-turn.** A plain chessboard (and a symmetric circle grid) looks the same
turned half a turn, and OpenCV may list its corners from either end; an image axis cannot tell
the two orders apart for a camera that rolls. The robot's motion can: for an eye-in-hand pair
of views, the flange turns by the same angle as the camera sees the board turn (the angle of
``inv(base_T_flange_i) @ base_T_flange_j`` equals that of ``cam_T_target_i @
inv(cam_T_target_j)``; eye-to-hand, ``base_T_flange_i @ inv(base_T_flange_j)``), and reading one
of the two views' corners in the reverse order adds a half-turn to the camera's side.
:func:`choose_consistent_poses` picks, per view, the candidate pose that agrees with the other
views; :func:`resolve_half_turns` applies it to a chessboard capture's corners and says which
views it turned, with the evidence (:class:`PoseChoice`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robots import geometry as geo
from robots.capture import Capture, Detection
from robots.interfaces import Frame, Intrinsics

__all__ = [
    "MIN_POINTS",
    "PoseChoice",
    "aruco_detector",
    "charuco_detector",
    "choose_consistent_poses",
    "circle_grid_detector",
    "half_turn",
    "resolve_half_turns",
]

#: solvePnP on a planar target with known intrinsics needs 4 points, not all on one line.
MIN_POINTS = 4

#: A pair's angle mismatch is capped here, so one bad robot pose cannot outvote the others.
_MISMATCH_CAP_DEG = 30.0
#: A view's choice is "clear" when its best alternative disagrees with the other views by at
#: least this many degrees more (median over the pairs) than the chosen candidate does; below,
#: the motion cannot tell them apart (e.g. a view that only turns about the optical axis).
CLEAR_MARGIN_DEG = 2.0


# --------------------------------------------------------------------------- pose from points


def _refused(reason: str) -> Detection:
    return Detection(None, np.zeros((0, 2)), np.zeros((0, 3)), ok=False, reason=reason)


def _planar_pose(object_points, pixels, intrinsics: Intrinsics) -> np.ndarray | None:
    """cam_T_target by SQPnP refined by Levenberg-Marquardt, or None.

    SQPnP finds the global minimum; IPPE, made for planar targets, returned a pose 7 degrees
    off with 1.2 px of error for a noise-free fronto-parallel tag (its known weak case)."""
    import cv2

    obj = np.asarray(object_points, np.float64)
    img = np.asarray(pixels, np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, intrinsics.K, intrinsics.dist,
                                  flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, intrinsics.K, intrinsics.dist, rvec, tvec)
    return geo.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())


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
    pose = _planar_pose(object_points, pixels, intrinsics)
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
    ambiguity: pass the capture through :func:`resolve_half_turns`.
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


# --------------------------------------------------------------------------- the half-turn


def half_turn(object_points) -> np.ndarray:
    """The (4, 4) half-turn about z through the centre of a planar grid of points, metres.

    For a full chessboard (or symmetric circle) grid listed row by row it maps point k onto
    point N-1-k, so reading a view's corners in reverse order moves its pose from
    ``cam_T_target`` to ``cam_T_target @ half_turn(points)``. ``ValueError`` if the points
    are not symmetric that way (then the order cannot flip).
    """
    P = np.asarray(object_points, float).reshape(-1, 3)
    centre = P.mean(axis=0)
    F = geo.make_pose(np.diag([-1.0, -1.0, 1.0]), [2 * centre[0], 2 * centre[1], 0.0])
    if not np.allclose(P @ F[:3, :3].T + F[:3, 3], P[::-1], atol=1e-9 + 1e-6 * np.ptp(P)):
        raise ValueError("object_points are not a grid that a half-turn maps onto itself in "
                         "reverse order (k -> N-1-k); only full chessboard or symmetric "
                         "circle grids have that ambiguity")
    return F


def _quarter_symmetric(points: np.ndarray) -> bool:
    """Whether a quarter turn about the centre maps the point set onto itself (square grids)."""
    centred = points[:, :2] - points[:, :2].mean(axis=0)
    turned = centred @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    gaps = np.linalg.norm(turned[:, None, :] - centred[None, :, :], axis=2).min(axis=1)
    return bool(np.all(gaps < 1e-6 * max(np.ptp(centred), 1e-12)))


@dataclass(frozen=True)
class PoseChoice:
    """Which candidate target pose of each view agrees with the robot's motion.

    ``chosen`` (n,) int: the candidate kept per view (0 = as detected). ``mismatch_deg`` (n,):
    the median, over the other views, of ``|angle(robot motion) - angle(camera motion)|`` with
    the chosen candidates, degrees (both are one rotation seen from two frames, so a consistent
    view is near the noise, a fraction of a degree). ``alternative_deg`` (n,): the same for the
    best other candidate of that view, the others kept. ``changed``: views whose kept
    candidate is not the detected one. ``unclear``: views whose alternative is within
    ``CLEAR_MARGIN_DEG`` of the choice, so the motion does not decide them.
    """

    chosen: np.ndarray
    mismatch_deg: np.ndarray
    alternative_deg: np.ndarray
    changed: tuple[int, ...]
    unclear: tuple[int, ...]

    def summary(self) -> str:
        """One line for a person: what was turned and on what evidence."""
        if not self.changed:
            text = "every view kept its detected corner order"
        else:
            lo = min(self.alternative_deg[k] for k in self.changed)
            hi = max(self.alternative_deg[k] for k in self.changed)
            spread = f"{lo:.1f}" if hi - lo < 0.05 else f"{lo:.1f}-{hi:.1f}"
            text = (f"views {list(self.changed)} were read half a turn round: with the detected "
                    f"order they disagree with the robot's motion by a median {spread} deg, "
                    f"turned by {max(self.mismatch_deg[k] for k in self.changed):.2f} deg at most")
        if self.unclear:
            text += f"; views {list(self.unclear)} are not decided by the motion (distrust them)"
        return text


def _robot_angles(F: np.ndarray, mount: str) -> np.ndarray:
    """(n, n) angle (deg) of the robot's motion between views i and j, as X sees it."""
    n = len(F)
    R = F[:, :3, :3]
    i, j = np.triu_indices(n, k=1)
    rel = (np.swapaxes(R[i], 1, 2) @ R[j] if mount == "eye_in_hand"
           else R[i] @ np.swapaxes(R[j], 1, 2))
    out = np.zeros((n, n))
    out[i, j] = out[j, i] = geo.rotation_angle_deg(rel)
    return out


def _mismatch_table(F: np.ndarray, candidates: np.ndarray, mount: str) -> np.ndarray:
    """M[i, j, a, b]: |robot angle - camera angle| between view i's candidate a and view j's
    candidate b, degrees (0 on the diagonal)."""
    n, k = candidates.shape[:2]
    robot = _robot_angles(F, mount)
    Rc = candidates[:, :, :3, :3]
    M = np.zeros((n, n, k, k))
    i, j = np.triu_indices(n, k=1)
    for a in range(k):
        for b in range(k):
            cam = geo.rotation_angle_deg(Rc[i, a] @ np.swapaxes(Rc[j, b], 1, 2))
            M[i, j, a, b] = np.abs(robot[i, j] - cam)
            M[j, i, b, a] = M[i, j, a, b]
    return M


def _view_costs(M: np.ndarray, labels: np.ndarray, view: int) -> np.ndarray:
    """Median mismatch of each candidate of ``view`` against the others' current labels."""
    others = np.array([j for j in range(len(labels)) if j != view])
    return np.median(M[view, others, :, labels[others]], axis=0)


def _polish(M: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Change one view at a time to its best candidate until none improves (a few sweeps)."""
    labels = labels.copy()
    for _ in range(10):
        moved = False
        for v in range(len(labels)):
            costs = _view_costs(M, labels, v)
            best = int(np.argmin(costs))
            if costs[best] < costs[labels[v]] - 1e-9:
                labels[v], moved = best, True
        if not moved:
            break
    return labels


def _total(M: np.ndarray, labels: np.ndarray) -> float:
    n = len(labels)
    return float(sum(M[i, j, labels[i], labels[j]] for i in range(n) for j in range(i + 1, n)))


def choose_consistent_poses(base_T_flange, candidates, mount: str = "eye_in_hand") -> PoseChoice:
    """Per view, the candidate ``cam_T_target`` that agrees with the robot's motion.

    ``base_T_flange`` (n, 4, 4); ``candidates`` (n, k, 4, 4): k candidate target poses per view
    (candidate 0 is the detector's), e.g. a chessboard read in both orders. ``mount``:
    ``"eye_in_hand"`` or ``"eye_to_hand"``. The choice minimises the summed angle mismatch
    over all pairs of views (each capped at 30 deg): every view is tried as the anchor, the
    others start at the candidate that best fits it and are then improved one at a time.
    Symmetric choices (every view turned) fit equally well; the one that keeps the most views
    as detected is returned. Needs n >= 3.
    """
    if mount not in ("eye_in_hand", "eye_to_hand"):
        raise ValueError(f"mount must be 'eye_in_hand' or 'eye_to_hand', got {mount!r}")
    F = geo.as_poses(base_T_flange, "base_T_flange")
    C = np.asarray(candidates, dtype=float)
    if C.ndim != 4 or C.shape[0] != len(F) or C.shape[2:] != (4, 4) or C.shape[1] < 1:
        raise ValueError(f"candidates must have shape (n_views={len(F)}, k, 4, 4), got {C.shape}")
    if len(F) < 3:
        raise ValueError(f"choosing poses from the motion needs at least 3 views, got {len(F)}")
    geo.as_poses(C.reshape(-1, 4, 4), "candidates")
    raw = _mismatch_table(F, C, mount)
    M = np.minimum(raw, _MISMATCH_CAP_DEG)
    best, best_cost = None, np.inf
    for anchor in range(len(F)):
        start = np.argmin(M[anchor, :, 0, :], axis=1)
        start[anchor] = 0
        labels = _polish(M, start)
        cost = _total(M, labels)
        if cost < best_cost - 1e-9 or (abs(cost - best_cost) <= 1e-9
                                       and np.sum(labels != 0) < np.sum(best != 0)):
            best, best_cost = labels, cost
    mismatch = np.array([_view_costs(raw, best, v)[best[v]] for v in range(len(F))])
    alternative = np.array([np.min(np.delete(_view_costs(raw, best, v), best[v]))
                            if C.shape[1] > 1 else np.inf for v in range(len(F))])
    return PoseChoice(
        chosen=best, mismatch_deg=mismatch, alternative_deg=alternative,
        changed=tuple(int(v) for v in np.flatnonzero(best != 0)),
        unclear=tuple(int(v) for v in np.flatnonzero(alternative - mismatch < CLEAR_MARGIN_DEG)))


def resolve_half_turns(base_T_flange, corners_px, object_points, intrinsics: Intrinsics,
                       mount: str = "eye_in_hand"):
    """Put every view's chessboard corners in the order that agrees with the robot's motion.

    ``base_T_flange`` (n, 4, 4); ``corners_px``: n arrays (N, 2) of pixels, each the full grid
    as a chessboard detector lists it; ``object_points``: the grid (N, 3), metres, row by row
    (one array for all views, or one per view); ``intrinsics`` the camera's. Each view's pose is
    solved for its detected order and for the reverse order, and
    :func:`choose_consistent_poses` keeps the one that fits the other views' motions.

    Returns ``(corners, cam_T_target, choice)``: the corners per view (reversed where turned),
    the matching (n, 4, 4) poses, and the :class:`PoseChoice` with the evidence.
    """
    F = geo.as_poses(base_T_flange, "base_T_flange")
    if len(corners_px) != len(F):
        raise ValueError(f"corners_px has {len(corners_px)} views but base_T_flange {len(F)} "
                         "poses; give one full set of corners per view")
    grids = (list(object_points) if isinstance(object_points, (list, tuple))
             else [object_points] * len(F))
    corners, candidates = [], []
    for k, (pixels, grid) in enumerate(zip(corners_px, grids)):
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        grid = np.asarray(grid, float).reshape(-1, 3)
        if len(pixels) != len(grid):
            raise ValueError(f"view {k}: {len(pixels)} corners for {len(grid)} grid points; the "
                             "half-turn needs the full grid in every view")
        turn = half_turn(grid)
        if _quarter_symmetric(grid):
            raise ValueError(f"view {k}: the grid is square ({len(grid)} points), so its corners "
                             "may also be listed a quarter turn round, which this does not "
                             "resolve; use a board with different corner counts across and down")
        pose = _planar_pose(grid, pixels, intrinsics)
        if pose is None:
            raise ValueError(f"view {k}: solvePnP found no pose for its corners")
        corners.append(pixels)
        candidates.append([pose, pose @ turn])
    choice = choose_consistent_poses(F, np.array(candidates), mount)
    poses = np.array([c[a] for c, a in zip(candidates, choice.chosen)])
    corners = [c[::-1].copy() if a else c for c, a in zip(corners, choice.chosen)]
    return corners, poses, choice


def resolve_capture_half_turns(capture: Capture, mount: str = "eye_in_hand"):
    """:func:`resolve_half_turns` on a chessboard :class:`~robots.capture.Capture`: returns a
    new Capture (corners reordered, ``cam_T_target`` re-solved) and the :class:`PoseChoice`."""
    import dataclasses

    corners, poses, choice = resolve_half_turns(capture.base_T_flange, capture.corners_px,
                                                capture.object_points, capture.intrinsics, mount)
    return dataclasses.replace(capture, corners_px=corners, cam_T_target=poses), choice
