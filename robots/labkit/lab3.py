"""Lab 3 plumbing: the overview, the piece tops, the servo figures and the closed loop's moves.

Helpers that need the student's ``piece_position`` take it as an argument.
"""

from __future__ import annotations

import cv2
import numpy as np

from robots import geometry as geo
from robots import perception as P

__all__ = ["OVERVIEW", "disturbed", "go_overview", "show_overview", "find_tops",
           "top_errors_mm", "show_tops", "to_pixels", "plot_servo_runs", "tcp_down_over",
           "locate", "tcp_error_mm", "top_near"]

# base_T_cam of the overview: 0.63 m above the board's middle, looking straight down.
OVERVIEW = geo.make_pose(np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]]), [0.48, 0.0, 0.63])


def disturbed(T, mm: float, deg: float, rng: np.random.Generator) -> np.ndarray:
    """``T`` followed by a rotation of ``deg`` degrees and a shift of ``mm`` millimetres, each
    in a random direction drawn from ``rng`` (in T's child frame)."""
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    return T @ geo.pose_from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis),
                                    mm * 1e-3 * direction / np.linalg.norm(direction))


def go_overview(robot, flange_T_cam, base_T_cam=OVERVIEW, speed: float = 0.25) -> None:
    """Move so that the camera (as ``flange_T_cam`` says it is mounted) is at ``base_T_cam``,
    in two straight segments: the safety layer caps the length of a single move."""
    target = base_T_cam @ geo.invert(flange_T_cam)
    mid = target.copy()
    mid[:3, 3] = 0.5 * (robot.flange_pose()[:3, 3] + target[:3, 3])
    robot.move_to(mid, speed=speed)
    robot.move_to(target, speed=speed)


def show_overview(frame, board, intrinsics) -> None:
    """The overview image with the board's inner corners and its x (red) and y (green) axes,
    beside the aligned depth image (m)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    axes[0].imshow(frame.rgb)
    axes[0].plot(*board.corners_px.T, "c.", ms=3)
    a1 = P.project(geo.transform_points(board.cam_T_chess, [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]),
                   intrinsics)
    axes[0].annotate("", a1[1], a1[0], arrowprops=dict(color="r", arrowstyle="->"))
    axes[0].annotate("", a1[2], a1[0], arrowprops=dict(color="g", arrowstyle="->"))
    axes[0].set_title("overview: inner corners, chess x (red) and y (green)")
    im = axes[1].imshow(frame.depth, cmap="viridis")
    fig.colorbar(im, ax=axes[1], label="depth Z (m)")
    axes[1].set_title("aligned depth image")
    plt.show()


def find_tops(depth, cam_T_chess, intrinsics, min_height: float = 0.008,
              top_band: float = 0.004) -> np.ndarray:
    """Pixels (N, 2) as (u, v) of the tops of the pieces standing on the board.

    Every pixel's height above the board is the chess-frame z of its 3-D point; pixels more
    than ``min_height`` m above it, in connected groups of at least 8, are pieces, and each
    piece's top is the mean pixel within ``top_band`` m of its highest point.
    """
    cloud = P.point_cloud(depth, intrinsics)
    chess_T_cam = geo.invert(cam_T_chess)
    height = cloud @ chess_T_cam[2, :3] + chess_T_cam[2, 3]
    mask = (np.nan_to_num(height, nan=-1.0) > min_height).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    vv, uu = np.indices(depth.shape)
    tops = []
    for k in range(1, count):
        if stats[k, cv2.CC_STAT_AREA] < 8:
            continue  # a speck of noise
        blob = labels == k
        top = blob & (height > np.nanmax(height[blob]) - top_band)
        tops.append([uu[top].mean(), vv[top].mean()])
    return np.array(tops).reshape(-1, 2)


def top_errors_mm(squares, tops_base, pieces) -> dict[str, float]:
    """Simulator truth: horizontal distance (mm) of each found top (base frame, m) from the
    axis of the piece on its square, for the squares that hold a piece."""
    return {sq: 1000 * float(np.linalg.norm(p[:2] - pieces[sq].base_T_piece[:2, 3]))
            for sq, p in zip(squares, tops_base) if sq in pieces}


def show_tops(rgb, squares, tops_uv) -> None:
    """The image with each found top marked and named by its square."""
    import matplotlib.pyplot as plt

    plt.figure(figsize=(5, 4))
    plt.imshow(rgb)
    for sq, uv in zip(squares, tops_uv):
        plt.plot(*uv, "m+", ms=6)
        plt.text(uv[0] + 3, uv[1] - 3, sq, color="yellow", fontsize=6)
    plt.title("piece tops and their squares")
    plt.show()


def to_pixels(s, K, name: str = "s") -> np.ndarray:
    """Pixels (..., 2) of normalised image coordinates ``s`` (..., 2) under intrinsics K.

    ``s`` that are already pixels (beyond +-10) or transposed, (2, N), raise ``ValueError``
    naming ``name`` (``robots.perception.check_normalised``)."""
    s = P.check_normalised(s, name)
    K = np.asarray(K, dtype=float)
    return s @ K[:2, :2].T + K[:2, 2]


def plot_servo_runs(runs, s_star, K, image_size, dt: float) -> None:
    """The servo runs as in Corke's toolbox: per law, the feature tracks in the image (pixels,
    image frame: u right, v down, origin at the top-left corner) beside the camera velocity;
    then the feature error of every run over time.

    ``runs`` maps a name to ``(tracks (steps, n, 2) normalised, errors (steps,), final pose,
    twists (steps, 6) in m/s and rad/s, camera frame)``; ``s_star`` (n, 2) is the goal.
    """
    import matplotlib.pyplot as plt

    width, height = image_size
    laws = [name for name in runs if "flipped" not in name]
    fig, axes = plt.subplots(len(laws), 3, figsize=(14, 3.6 * len(laws)), squeeze=False)
    goal_px = to_pixels(s_star, K, "s_star")
    for row, name in zip(axes, laws):
        tracks, _, _, twists = runs[name]
        uv = to_pixels(tracks, K, f"the tracks of runs[{name!r}]")
        ax = row[0]
        for k in range(uv.shape[1]):
            ax.plot(uv[:, k, 0], uv[:, k, 1], "-", lw=1.2)
        ax.plot(*uv[0].T, "ko", ms=4, label="start")
        ax.plot(*goal_px.T, "r*", ms=10, label="goal s*")
        ax.add_patch(plt.Rectangle((0, 0), width, height, fill=False, color="0.5", lw=1))
        ax.set_xlim(-0.05 * width, 1.05 * width)
        ax.set_ylim(1.05 * height, -0.05 * height)   # image frame: v grows downwards
        ax.set_aspect("equal")
        ax.set_xlabel("u (pixels)")
        ax.set_ylabel("v (pixels)")
        ax.set_title(f"{name}: feature tracks in the image")
        ax.legend(fontsize=8, loc="lower right")
        t = dt * np.arange(len(twists))
        for ax, columns, unit, labels in ((row[1], slice(0, 3), "m/s", ("vx", "vy", "vz")),
                                          (row[2], slice(3, 6), "rad/s", ("wx", "wy", "wz"))):
            for values, label in zip(np.asarray(twists)[:, columns].T, labels):
                ax.plot(t, values, label=label)
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"camera velocity ({unit})")
            ax.set_title(f"{name}: {'translational' if unit == 'm/s' else 'angular'} velocity")
            ax.legend(fontsize=8)
    fig.tight_layout()
    plt.show()

    fig, ax = plt.subplots(figsize=(6, 3.4))
    for name, (_, errors, _, _) in runs.items():
        ax.semilogy(dt * np.arange(len(errors)), errors, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("rms feature error (normalised)")
    ax.set_title("feature error over time")
    ax.legend(fontsize=8)
    fig.tight_layout()
    plt.show()


def tcp_down_over(robot, point_base, above: float) -> np.ndarray:
    """Flange pose that puts the tool tip ``above`` m over a base-frame point, pointing straight
    down, with the flange's x axis kept as close to its current heading as possible."""
    x = robot.flange_pose()[:3, 0].copy()
    x[2] = 0.0
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross([0, 0, -1.0], x), [0, 0, -1.0]])
    return geo.make_pose(R, np.asarray(point_base) + [0, 0, above]) @ geo.invert(
        robot.tool.flange_T_tcp)


def locate(robot, camera, flange_T_cam, square: str, piece_position, square_m: float):
    """From the overview: the top of the piece on ``square`` (base frame, m) and
    ``base_T_chess``, measured with the student's ``piece_position`` through ``flange_T_cam``."""
    intrinsics = camera.intrinsics
    go_overview(robot, flange_T_cam)
    frame = camera.capture()
    base_T_cam = robot.flange_pose() @ flange_T_cam
    board = P.detect_chess_board(frame, intrinsics, square_m,
                                 white_side_cam=geo.invert(base_T_cam)[:3, 3])
    tops = np.array([piece_position(frame.depth, uv, intrinsics.K)
                     for uv in find_tops(frame.depth, board.cam_T_chess, intrinsics)])
    squares = board.square_of(tops)
    if square not in squares:
        raise ValueError(f"no piece found on {square} from the overview (found: "
                         f"{', '.join(s for s in squares if s)})")
    k = squares.index(square)
    return geo.transform_points(base_T_cam, tops[k:k + 1])[0], base_T_cam @ board.cam_T_chess


def tcp_error_mm(robot, truth, square: str) -> float:
    """Simulator truth: horizontal distance (mm) from the tool tip to the axis of the piece on
    ``square``."""
    return 1000 * float(np.linalg.norm(robot.tcp_pose()[:2, 3]
                                       - truth.pieces[square].base_T_piece[:2, 3]))


def top_near(frame, uv_guess, radius: int = 22) -> np.ndarray:
    """Pixel (u, v) of the nearest surface within ``radius`` px of a guess (a pawn's top, seen
    from above): the centroid of the pixels within 4 mm of the smallest depth there."""
    u0, v0 = np.rint(uv_guess).astype(int)
    window = np.full(frame.depth.shape, np.nan)
    rows, cols = slice(max(v0 - radius, 0), v0 + radius), slice(max(u0 - radius, 0), u0 + radius)
    window[rows, cols] = frame.depth[rows, cols]
    vv, uu = np.nonzero(np.nan_to_num(window, nan=np.inf) < np.nanmin(window) + 0.004)
    return np.array([uu.mean(), vv.mean()])
