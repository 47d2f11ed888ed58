"""The chessboard's half-turn, resolved from the robot's motion rather than an image axis.

A plain chessboard (and a symmetric circle grid) looks the same turned half a turn, and OpenCV
may list its corners from either end; an image axis cannot tell the two orders apart for a
camera that rolls. The robot's motion can: between two views the flange turns by the same angle
as the camera sees the board turn (the angle of ``inv(base_T_flange_i) @ base_T_flange_j``
equals that of ``cam_T_target_i @ inv(cam_T_target_j)``, since AX = XB makes the two motions
conjugate), and reading one of the two views' corners in the reverse order adds a half-turn on
the camera's side. The angle is the same eye-in-hand and eye-to-hand (``R_i^T R_j`` and
``R_i R_j^T`` have the same trace), so the mount need not be known.
:func:`choose_consistent_poses` picks, per view, the candidate pose that agrees with the other
views; :func:`resolve_half_turns` applies it to a chessboard capture's corners and says which
views it turned, with the evidence (:class:`PoseChoice`). Only ``robots.geometry`` and ``robots.interfaces`` are imported, so the
capture and import code can use it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from robots import geometry as geo
from robots.interfaces import Intrinsics

__all__ = [
    "CLEAR_MARGIN_DEG",
    "PoseChoice",
    "choose_consistent_poses",
    "half_turn",
    "planar_pose",
    "resolve_capture_half_turns",
    "resolve_half_turns",
]

#: A pair's angle mismatch is capped here, so one bad robot pose cannot outvote the others.
_MISMATCH_CAP_DEG = 30.0
#: A view's choice is "clear" when its best alternative disagrees with the other views by at
#: least this many degrees more (median over the pairs) than the chosen candidate does; below,
#: the motion cannot tell them apart (e.g. a view that only turns about the optical axis).
CLEAR_MARGIN_DEG = 2.0


def planar_pose(object_points, pixels, intrinsics: Intrinsics) -> np.ndarray | None:
    """cam_T_target (4, 4, metres) of points ``object_points`` (N, 3) m seen at ``pixels``
    (N, 2) px, by SQPnP refined by Levenberg-Marquardt; None if OpenCV finds none.

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


def _robot_angles(F: np.ndarray) -> np.ndarray:
    """(n, n) angle (deg) of the robot's motion between views i and j (either mount)."""
    n = len(F)
    R = F[:, :3, :3]
    i, j = np.triu_indices(n, k=1)
    rel = np.swapaxes(R[i], 1, 2) @ R[j]
    out = np.zeros((n, n))
    out[i, j] = out[j, i] = geo.rotation_angle_deg(rel)
    return out


def _mismatch_table(F: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """M[i, j, a, b]: |robot angle - camera angle| between view i's candidate a and view j's
    candidate b, degrees (0 on the diagonal)."""
    n, k = candidates.shape[:2]
    robot = _robot_angles(F)
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


def choose_consistent_poses(base_T_flange, candidates) -> PoseChoice:
    """Per view, the candidate ``cam_T_target`` that agrees with the robot's motion.

    ``base_T_flange`` (n, 4, 4); ``candidates`` (n, k, 4, 4): k candidate target poses per view
    (candidate 0 is the detector's), e.g. a chessboard read in both orders; eye-in-hand or
    eye-to-hand alike. The choice minimises the summed angle mismatch
    over all pairs of views (each capped at 30 deg): every view is tried as the anchor, the
    others start at the candidate that best fits it and are then improved one at a time.
    Symmetric choices (every view turned) fit equally well; the one that keeps the most views
    as detected is returned. Needs n >= 3.
    """
    F = geo.as_poses(base_T_flange, "base_T_flange")
    C = np.asarray(candidates, dtype=float)
    if C.ndim != 4 or C.shape[0] != len(F) or C.shape[2:] != (4, 4) or C.shape[1] < 1:
        raise ValueError(f"candidates must have shape (n_views={len(F)}, k, 4, 4), got {C.shape}")
    if len(F) < 3:
        raise ValueError(f"choosing poses from the motion needs at least 3 views, got {len(F)}")
    geo.as_poses(C.reshape(-1, 4, 4), "candidates")
    raw = _mismatch_table(F, C)
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


def resolve_half_turns(base_T_flange, corners_px, object_points, intrinsics: Intrinsics):
    """Put every view's chessboard corners in the order that agrees with the robot's motion.

    ``base_T_flange`` (n, 4, 4); ``corners_px``: n arrays (N, 2) of pixels, each the full grid
    as a chessboard detector lists it; ``object_points``: the grid (N, 3), metres, row by row
    (one array for all views, or one per view); ``intrinsics`` the camera's. Eye-in-hand and
    eye-to-hand captures alike (the mount need not be known). Each view's pose is
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
        pose = planar_pose(grid, pixels, intrinsics)
        if pose is None:
            raise ValueError(f"view {k}: solvePnP found no pose for its corners")
        corners.append(pixels)
        candidates.append([pose, pose @ turn])
    choice = choose_consistent_poses(F, np.array(candidates))
    poses = np.array([c[a] for c, a in zip(candidates, choice.chosen)])
    corners = [c[::-1].copy() if a else c for c, a in zip(corners, choice.chosen)]
    return corners, poses, choice


def resolve_capture_half_turns(capture):
    """:func:`resolve_half_turns` on a chessboard :class:`~robots.capture.Capture`: returns a
    new Capture (corners reordered, ``cam_T_target`` re-solved) and the :class:`PoseChoice`."""
    corners, poses, choice = resolve_half_turns(capture.base_T_flange, capture.corners_px,
                                                capture.object_points, capture.intrinsics)
    return dataclasses.replace(capture, corners_px=corners, cam_T_target=poses), choice
