"""The demo's report: ``out/report.html`` with its figures as PNG files beside it.

Figures (matplotlib, Agg backend, no display needed): the frames in 3-D, the residual of each
view, the accuracy of each hand-eye method, the servo error curves, and the board as the wrist
camera saw it before and after the pick-and-place.
"""

from __future__ import annotations

import html
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from autograder.page_policy import POLICY_META
from robots import geometry as geo


def _figure(*args, **kwargs):
    import matplotlib

    matplotlib.use("Agg")  # files only: never open a window, even with a display
    import matplotlib.pyplot as plt

    return plt.figure(*args, **kwargs)


def _save(fig, path: Path) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path.name


def _triad(ax, T, length, label=None, alpha=1.0, style="-"):
    """Draw a frame's x, y, z axes (red, green, blue), metres."""
    o = T[:3, 3]
    for k, colour in enumerate("rgb"):
        tip = o + length * T[:3, k]
        ax.plot(*zip(o, tip), style, color=colour, alpha=alpha, lw=1.5)
    if label:
        ax.text(*o, f" {label}", fontsize=8)


def _equal_axes(ax, points):
    points = np.asarray(points)
    centre = (points.max(axis=0) + points.min(axis=0)) / 2
    half = max(np.ptp(points, axis=0).max() / 2, 0.1)
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")


def frames_figure(flange, eye, path: Path) -> str:
    """Left: the fixed camera (found vs true) and the board centres it saw. Right: the wrist
    camera at each view (found = flange pose x calibration; true) and the board."""
    fig = _figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    _triad(ax, np.eye(4), 0.15, "base")
    _triad(ax, flange.true_base_T_cam, 0.12, alpha=0.4, style="--")
    _triad(ax, flange.base_T_cam, 0.12, "camera (found; dashed: true)")
    m = flange.marker_base
    ax.scatter(*m.T, s=12, c="k", label="board centre per view")
    _equal_axes(ax, np.vstack([m, [[0, 0, 0]], flange.true_base_T_cam[None, :3, 3]]))
    ax.set_title("1. eye-on-base: fixed camera and flange board")
    ax.legend(loc="upper left", fontsize=8)

    ax = fig.add_subplot(1, 2, 2, projection="3d")
    _triad(ax, np.eye(4), 0.15, "base")
    _triad(ax, eye.true_base_T_board, 0.1, "board")
    found = eye.base_T_flange @ eye.default.X
    true = eye.base_T_flange @ eye.true_flange_T_cam  # (as read back; encoder errors included)
    for k, (a, b) in enumerate(zip(found, true)):
        _triad(ax, a, 0.05)
        ax.plot(*zip(a[:3, 3], eye.true_base_T_board[:3, 3]), ":", color="0.6", lw=0.7)
    ax.scatter(*true[:, :3, 3].T, s=25, facecolors="none", edgecolors="m",
               label="camera (true mount)")
    ax.scatter(*eye.base_T_flange[:, :3, 3].T, s=8, c="k", label="flange")
    _equal_axes(ax, np.vstack([found[:, :3, 3], [[0, 0, 0]], eye.true_base_T_board[None, :3, 3]]))
    ax.set_title("2. eye-in-hand: camera at each view")
    ax.legend(loc="upper left", fontsize=8)
    return _save(fig, path)


def residuals_figure(flange, eye, path: Path) -> str:
    fig = _figure(figsize=(11, 3.8))
    ax = fig.add_subplot(1, 2, 1)
    ax.bar([str(i) for i in flange.pose_indices], flange.residuals_m * 1e3, color="tab:blue")
    ax.set_xlabel("view (commanded pose index)")
    ax.set_ylabel("residual (mm)")
    ax.set_title("1. flange fit: |base_T_cam c_i - flange point_i|")
    ax = fig.add_subplot(1, 2, 2)
    labels = [str(i) for i in eye.pose_indices]
    colours = ["tab:red" if i in eye.flagged else "tab:orange" for i in eye.pose_indices]
    ax.bar(labels, eye.residual_mm, color=colours)
    ax.set_xlabel("view (commanded pose index; red = flagged)")
    ax.set_ylabel("board position residual (mm)")
    ax2 = ax.twinx()
    ax2.plot(labels, eye.residual_deg, "k.-", lw=0.8)
    ax2.set_ylabel("board rotation residual (deg)")
    ax.set_title(f"2. eye-in-hand ({eye.default.label}): each view's board vs the mean")
    return _save(fig, path)


def methods_figure(eye, path: Path) -> str:
    rows = [r for r in eye.rows if r.X is not None]
    labels = [r.label for r in rows]
    fig = _figure(figsize=(11, 0.3 * len(rows) + 1.6))
    for k, (values, unit) in enumerate(((
            [r.rotation_deg for r in rows], "rotation error (deg)"),
            ([r.translation_mm for r in rows], "translation error (mm)"))):
        ax = fig.add_subplot(1, 2, k + 1)
        colours = ["tab:green" if r is eye.default else
                   ("tab:gray" if r.label.startswith("opencv") else "tab:blue") for r in rows]
        ax.barh(labels, values, color=colours)
        ax.invert_yaxis()
        ax.set_xlabel(unit)
        if k:
            ax.set_yticklabels([])
    fig.suptitle("accuracy of flange_T_cam by method against the truth "
                 "(green: default, grey: OpenCV)", fontsize=10)
    return _save(fig, path)


def servo_figure(picks, path: Path) -> str:
    fig = _figure(figsize=(6.5, 3.8))
    ax = fig.add_subplot(1, 1, 1)
    for r in picks.picks:
        if r.servo_errors_mm:
            ax.plot(range(len(r.servo_errors_mm)), r.servo_errors_mm, "o-",
                    label=f"{r.kind} {r.from_square}-{r.to_square}")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("servo iteration (one camera frame each)")
    ax.set_ylabel("true horizontal TCP-to-piece error (mm)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=8)
    ax.set_title("IBVS over each piece before the grasp")
    return _save(fig, path)


def _image(rgb, path: Path) -> str | None:
    if rgb is None:
        return None
    import cv2

    cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    return path.name


def _table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _err_cells(X, truth):
    return f"{geo.rotation_error_deg(X, truth):.3f}", f"{geo.translation_error(X, truth) * 1e3:.2f}"


def write_report(settings, flange, eye, picks, elapsed_s: float) -> Path:
    """Write ``settings.out/report.html`` and its PNG figures; returns the HTML path."""
    out = Path(settings.out)
    out.mkdir(parents=True, exist_ok=True)
    figs = {
        "frames": frames_figure(flange, eye, out / "frames_3d.png"),
        "residuals": residuals_figure(flange, eye, out / "residuals.png"),
        "methods": methods_figure(eye, out / "methods.png"),
        "servo": servo_figure(picks, out / "servo_errors.png"),
        "view": _image(eye.view_image, out / "eye_in_hand_view.png"),
        "before": _image(picks.before, out / "board_before.png"),
        "after": _image(picks.after, out / "board_after.png"),
    }
    flange_rows = [(label, *_err_cells(X, flange.true_base_T_cam)) for label, X in (
        ("calibrate_flange_with_offset", flange.base_T_cam),
        ("calibrate_flange (offset ignored)", flange.naive_base_T_cam),
        ("hand-eye eye_to_hand, nonlinear", flange.handeye_base_T_cam))]
    method_rows = [("(design mount, no calibration)",
                    *_err_cells(eye.nominal_flange_T_cam, eye.true_flange_T_cam), "")]
    for r in eye.rows:
        method_rows.append((r.label + (" (default, saved)" if r is eye.default else ""),
                            *((f"{r.rotation_deg:.3f}", f"{r.translation_mm:.2f}",
                               f"{r.time_ms:.1f}") if r.X is not None
                              else (f"failed: {r.error}", "", ""))))
    pick_rows = [(f"{r.from_square}-{r.to_square}", r.kind, "yes" if r.placed else "NO",
                  f"{r.grasp_error_mm:.2f}", f"{r.place_error_mm:.2f}", r.iterations,
                  r.error or "") for r in picks.picks]

    def img(key, alt, width=None):
        if figs[key] is None:
            return f"<p><em>{html.escape(alt)}: no image</em></p>"
        w = f' width="{width}"' if width else ""
        return (f'<figure><img src="{figs[key]}" alt="{html.escape(alt)}"{w}>'
                f"<figcaption>{html.escape(alt)}</figcaption></figure>")

    s = settings
    when = datetime.now(timezone.utc).isoformat(timespec="seconds")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">{POLICY_META}<title>cobotlab demo report</title>
<style>
body {{ font-family: sans-serif; max-width: 1150px; margin: 1em auto; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 2px 8px; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }}
figure {{ display: inline-block; margin: 0.5em; vertical-align: top; }}
figcaption {{ font-size: 0.85em; color: #555; }}
img {{ max-width: 100%; border: 1px solid #ddd; }}
.note {{ color: #555; font-size: 0.9em; }}
</style></head><body>
<h1>cobotlab demo: calibrate, then pick and place, in simulation</h1>
<p>Arm <b>{s.robot}</b>, seed {s.seed}, noise <b>{s.noise}</b>, wrist camera mounted
off its design pose; calibration images {s.calib_size[0]}x{s.calib_size[1]}, servo images
{s.pick_size[0]}x{s.pick_size[1]}. Ran in {elapsed_s:.1f} s on {when}. All errors are against
the simulator's ground truth, which the demo reads only to score its results.</p>

<h2>1. Flange calibration (eye-on-base)</h2>
<p>A fixed camera sees a small chessboard on the flange in {len(flange.residuals_m)} of
{flange.n_commanded} poses. Error of <code>base_T_cam</code>:</p>
{_table(("method", "rotation (deg)", "translation (mm)"), flange_rows)}
<p class="note">The board centre lies {np.linalg.norm(flange.true_flange_p_marker) * 1e3:.1f} mm off the
flange centre; ignoring that offset while the flange turns costs the plain point fit its accuracy.</p>

<h2>2. Eye-in-hand calibration</h2>
<p>{len(eye.base_T_flange)} of {eye.n_commanded} views of the table board; views planned from one
first look with the design mount. Error of <code>flange_T_cam</code> by method; the default
result is saved to <code>{html.escape(eye.yaml_path.name)}</code>. Flagged views:
{list(eye.flagged) or "none"}.</p>
{_table(("method", "rotation (deg)", "translation (mm)", "time (ms)"), method_rows)}
{img("methods", "accuracy of each method")}
{img("view", "one eye-in-hand view with the detected corners", 420)}

<h2>Frames and residuals</h2>
{img("frames", "frames in 3-D (x red, y green, z blue; dashed = truth)")}
{img("residuals", "residual of each view")}

<h2>3. Pick and place with the saved calibration</h2>
{_table(("move", "piece", "placed", "grasp error (mm)", "placement error (mm)",
         "servo iterations", "failure"), pick_rows)}
<p class="note">Grasp error: true horizontal distance between the suction cup and the piece's axis
when the vacuum engaged. Placement error: the piece's distance from its square's centre.</p>
{img("servo", "servo error curves")}
{img("before", "the board before (wrist camera, overview pose)", 420)}
{img("after", "the board after", 420)}
</body></html>
"""
    path = out / "report.html"
    path.write_text(page)
    return path
