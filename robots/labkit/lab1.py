"""Lab 1 plumbing: the intrinsics views and their capture with a live coverage map."""

from __future__ import annotations

import numpy as np

from robots import geometry as geo

__all__ = ["turned_about", "plan_views", "coverage_figure", "capture_board_views"]


def turned_about(point, rotvec_deg) -> np.ndarray:
    """(4, 4) rotation by ``rotvec_deg`` (rotation vector, degrees) about ``point`` (m): the
    pivot stays where it is. Right-multiplied onto a flange pose, both are in the flange frame."""
    R = geo.pose_from_rotvec(np.radians(rotvec_deg), np.zeros(3))[:3, :3]
    point = np.asarray(point, dtype=float)
    return geo.make_pose(R, point - R @ point)


def plan_views(home, tilts_deg, pans, board_ahead=(0.0, 0.0, 0.5), tilt_rise=0.15,
               pan_roll_deg=10.0) -> list[np.ndarray]:
    """``base_T_flange`` of every intrinsics view.

    ``tilts_deg``: (x, y) tilts in degrees, each a view ``tilt_rise`` m above ``home`` that
    pivots about ``board_ahead`` (the board centre in the flange frame, m), so the board stays
    in the middle of the image. ``pans``: (rise in m, (x, y) degrees), views from higher up
    turned about the camera itself, so the board lands near the image's edges and corners,
    each rolled by ``pan_roll_deg`` about the viewing axis.
    """
    views = [home @ geo.make_pose(t=[0, 0, -tilt_rise]) @ turned_about(board_ahead, [*tilt, 0])
             for tilt in tilts_deg]
    views += [home @ geo.make_pose(t=[0, 0, -rise]) @ turned_about(np.zeros(3),
                                                                    [*pan, pan_roll_deg])
              for rise, pan in pans]
    return views


def coverage_figure(all_corners, latest, width: int, height: int):
    """(figure, percent covered): where in the image the corners have been seen so far, as a
    16 x 12 grid of counts over the ``width`` x ``height`` image (pixels), with the newest
    view's corners ``latest`` (N, 2) in red."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    pts = np.vstack(all_corners) if len(all_corners) else np.zeros((0, 2))
    hist, _, _ = np.histogram2d(pts[:, 0], pts[:, 1], bins=(16, 12),
                                range=((0, width), (0, height)))
    ax.imshow(hist.T, extent=(0, width, height, 0), cmap="Greens", vmin=0,
              vmax=max(1, hist.max()))
    if latest is not None:
        ax.plot(latest[:, 0], latest[:, 1], "r.", ms=3, label="newest view")
        ax.legend(loc="upper right", fontsize=8)
    covered = 100.0 * np.count_nonzero(hist) / hist.size
    ax.set_title(f"coverage after {len(all_corners)} views: {covered:.0f} % of the image cells")
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    return fig, covered


def capture_board_views(robot, camera, views, find_board, speed: float = 0.25):
    """Visit every view, photograph the board and keep the views that see all of it.

    Returns ``(object_points, image_points, last_rgb, covered)``: per kept view the board
    points (N, 3, float32, m) and their pixels (N, 2, float32), the last kept image and the
    percentage of image cells covered. One figure, the coverage map, is redrawn after every
    view (in a notebook); views that miss part of the board are named and skipped.
    """
    import matplotlib.pyplot as plt
    from IPython.display import display

    image_points, object_points, shown, last_rgb, covered = [], [], None, None, 0.0
    width, height = camera.intrinsics.width, camera.intrinsics.height
    for i, base_T_flange in enumerate(views):
        robot.move_to(base_T_flange, speed=speed)
        frame = camera.capture()
        found = find_board(frame, camera.intrinsics)
        if found is None:
            print(f"view {i}: board not fully visible, skipped")
            continue
        image_points.append(found.corners_px.astype(np.float32))
        object_points.append(found.object_points.astype(np.float32))
        fig, covered = coverage_figure(image_points, found.corners_px, width, height)
        if shown is None:
            shown = display(fig, display_id=True)
        else:
            shown.update(fig)
        plt.close(fig)
        last_rgb = frame.rgb
    return object_points, image_points, last_rgb, covered
