"""Lab 5's numbers: a fixed depth camera calibrated from the bare flange against lab 2's board.

Run:  .venv/bin/python benchmarks/depth_calibration.py [--seeds 20] [--arm ur5e] [--workers 2]
          [--json docs/benchmarks/depth_calibration.json] [--lab-json
          labs/lab5_depth/depth_vs_board.json] [--figure docs/img/lab5_depth_vs_board.png]
          [--also-arm panda] [--smoke]

Issue 26 item 3. For each seed, the same simulated eye-to-hand workcell (``robots.connect(
"sim", arm=ARM, mount="eye_to_hand", seed=SEED, ...)``: real PyBullet, DIRECT, TinyRenderer;
the camera mounted with a random 3 mm / 1.5 deg error, joint encoders off by N(0, 0.01 deg)
each, RGB noise 2 grey levels: the ``cobotlab demo`` "low" noise) is calibrated twice, each
from the same number of flange poses drawn the same way (the demo's: +-6 cm and +-12 deg about
the pose where the flange faces the camera, reachable ones only), and ``base_T_cam`` is
compared with ``cell.truth.base_T_cam``:

* **markerless** (lab 5): ``flange_target=False, tool=None, depth_model="d435"``: the bare
  ISO 9409 flange seen in a RealSense D4xx depth image. Per pose, the flange centre in the
  camera frame exactly as the lab finds it: ``robots.labkit.lab5.measure_flange`` with the
  notebook's own reference functions (its solution cells: ``backproject``, the nearest plane
  by ``fit_plane_ransac``, the rim, ``fit_flange_circle`` with the data-sheet radius); a view
  the lab's pipeline skips is skipped here too. Then ``base_T_cam`` from the notebook's
  ``base_T_cam_from_flanges`` (SVD registration of the centres against the translations of
  ``base_T_flange``).
* **board** (lab 2): the same cell with the default flange board (``flange_target=True``),
  ``robots.capture.capture_pose_pairs`` with the project's chessboard detector (solvePnP on the
  RGB image), and ``solutions.handeye.calibrate_eye_to_hand`` (AX = XB, the course's default
  "nonlinear": best closed form refined robustly). The AX = YB answer
  (``solutions.robot_world.solve_ax_yb(..., "nonlinear")``, Y = base_T_cam) is recorded too.

Each view of the markerless cell is rendered once (exact depth, ``camera.render()``) and the
D4xx model is applied to it with a seeded generator, which is exactly what
``camera.capture()`` does; the same rendered views then give the two sweeps of the markerless
method: the depth-noise sweep scales ``RealSenseDepthModel.subpixel`` (the RMS disparity error
behind sigma_z = subpixel z^2 / (f B); 0.08 px on a D435) by 0, 0.5, 1, 2 and 4, keeping the
dropouts and the 1 mm steps, at the main number of poses; the poses sweep takes the first n of
the views (4 ... 24) at the D435's own noise. The board's error at the same n is recorded too.

Reported: per seed, translation (mm) and rotation (deg) error; medians with bootstrap 95 %
intervals over seeds (``benchmarks/handeye_real.bootstrap_stats``); the median ratio
markerless / board with its paired-bootstrap interval (``benchmarks/handeye_accuracy.
paired_ratio``: the same resampled seeds for both). ``--smoke``: 2 seeds, 6 poses, small
images, no figure unless asked: a fast check of the whole path.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone

for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, HERE)

from handeye_accuracy import paired_ratio  # noqa: E402
from handeye_real import bootstrap_stats  # noqa: E402

from robots import connect  # noqa: E402
from robots import geometry as geo  # noqa: E402
from robots.interfaces import UnreachableError  # noqa: E402
from sim_backends.depth_noise import RealSenseDepthModel  # noqa: E402

BOOTSTRAP = 2000
# The cell's noise: ``cobotlab demo``'s "low" level (pixel noise, encoder offsets per joint)
# and its camera mounting error (mm, deg).
PIXEL_NOISE = 2.0
ENCODER_NOISE_DEG = 0.01
MOUNT_ERROR = (3.0, 1.5)
NOISE_SCALES = (0.0, 0.5, 1.0, 2.0, 4.0)
POSE_COUNTS = (4, 6, 8, 12, 16, 24)
N_MAIN = 12
SIZE = (640, 480)
INLIER_M = 0.003   # the notebook's INLIER_M: lab 5's RANSAC band


# --------------------------------------------------------------------------- markerless


_LAB = {}


def lab_functions() -> dict:
    """The lab's own functions: the notebook's solution cells (``backproject``,
    ``fit_plane_ransac``, ``fit_flange_circle``, ``base_T_cam_from_flanges``), loaded once per
    process, so the benchmark measures exactly the pipeline students build."""
    if not _LAB:
        from grading_fairness import notebook_solutions

        _LAB.update(notebook_solutions("lab5_depth"))
    return _LAB


def flange_centre(depth, intrinsics, radius, depth_scale):
    """The flange face's centre (3,), camera frame, m, from a depth image (H, W) m (NaN = no
    data), as lab 5 finds it: the Z16 image (``robots.labkit.lab5.to_z16``) through
    ``lab5.measure_flange`` with the notebook's reference functions and its inlier band
    (``INLIER_M``). Raises ValueError where the lab's pipeline skips the view."""
    from robots.labkit import lab5

    f = lab_functions()
    view = lab5.measure_flange(lab5.to_z16(depth, depth_scale), intrinsics.K, depth_scale,
                               radius, f["backproject"], f["fit_plane_ransac"],
                               f["fit_flange_circle"], inlier_m=INLIER_M)
    return view.centre


def _cell(arm, seed, size, markerless: bool):
    # The published numbers (docs/benchmarks/depth_calibration.md, lab 5's plot) are PyBullet's;
    # COBOTLAB_SIM_ENGINE=mujoco measures the other engine. Since lab 5's rim search stopped
    # taking a lost housing ring's outer edge for the rim, MuJoCo's smoke run keeps every view,
    # but its flange centres at 320 x 240 stay further off than PyBullet's (0.39 against
    # 0.14 mm, median over the 12 views: its thinner housing ring lets the D4xx dropouts eat
    # into the face), so the two do not agree within their noise and the default stays
    # PyBullet (docs/simulation.md, "Depth at silhouettes").
    options = dict(engine=os.environ.get("COBOTLAB_SIM_ENGINE", "pybullet"),
                   arm=arm, mount="eye_to_hand", seed=seed, width=size[0], height=size[1],
                   tool=None, pixel_noise=PIXEL_NOISE, encoder_noise_deg=ENCODER_NOISE_DEG,
                   mount_error=MOUNT_ERROR)
    if markerless:
        options.update(flange_target=False, depth_model="d435")
    return connect("sim", **options)


def _candidate_poses(cell, seed, n):
    """The demo's flange poses around the start pose (its rng seeded by ``seed``), first n
    reachable ones."""
    from cobotlab.demo import _flange_poses, _reachable

    start = cell.robot.flange_pose()
    rng = np.random.default_rng(seed)
    reachable = (T for T in _flange_poses(start, rng, 4 * n, cell.robot.safety)
                 if _reachable(cell.robot, T))
    return list(itertools.islice(reachable, n))


def _errors(base_T_cam, truth):
    return (1000.0 * geo.translation_error(base_T_cam, truth),
            geo.rotation_error_deg(base_T_cam, truth))


def _markerless_fit(centres, flanges):
    if len(centres) < 3:
        raise ValueError(f"only {len(centres)} flange centres: a registration needs 3")
    return lab_functions()["base_T_cam_from_flanges"](np.asarray(centres), np.asarray(flanges))


def _try(solve, truth, failures: list, label: str):
    """(translation mm, rotation deg) of ``solve()`` against the truth; NaN, NaN (and the
    reason in ``failures``) when the solver refuses its input."""
    try:
        return _errors(solve(), truth)
    except (ValueError, np.linalg.LinAlgError) as exc:
        failures.append(f"{label}: {str(exc)[:200]}")
        return (float("nan"), float("nan"))


def run_seed(job):
    """Everything measured on one (arm, seed): a dict of plain floats and lists."""
    arm, seed, n_max, n_main, scales, counts, size, sweeps = job
    # Small sweeps drop sub-degree motions with a warning meant for users; the table shows it.
    warnings.simplefilter("ignore", UserWarning)
    from solutions.handeye import calibrate_eye_to_hand
    from solutions.robot_world import solve_ax_yb

    out = {"arm": arm, "seed": seed}
    started = time.perf_counter()
    # ---- markerless
    with _cell(arm, seed, size, markerless=True) as cell:
        truth = cell.truth.base_T_cam.copy()
        radius = cell.truth.flange.radius
        intr = cell.camera.intrinsics
        poses = _candidate_poses(cell, seed, n_max)
        models = {s: RealSenseDepthModel(subpixel=0.08 * s) for s in scales}
        assert models[1.0] == cell.camera.depth_model  # scale 1 is the cell's own D435
        rng_noise = np.random.default_rng([seed, 1])
        # Per noise level, the views the lab's pipeline kept: at 4 x a D435's noise it skips
        # some that it keeps at 1 x, and a view skipped at one level stays in at the others.
        flanges = {s: [] for s in scales}
        centres, centre_err = {s: [] for s in scales}, {s: [] for s in scales}
        failures = {s: 0 for s in scales}
        for T in poses:
            try:
                cell.robot.move_to(T, speed=0.25)
            except UnreachableError:
                for s in scales:
                    failures[s] += 1
                continue
            F = cell.robot.flange_pose()  # what the controller reports (encoder offsets in)
            cam_T_flange = geo.compose(geo.invert(truth), cell.truth.base_T_flange())
            exact = cell.camera.render()[1]
            for s in scales:
                depth = models[s].apply(exact, intr.K, rng_noise)
                try:
                    centre = flange_centre(depth, intr, radius, cell.camera.depth_scale)
                except ValueError:
                    failures[s] += 1
                    continue
                flanges[s].append(F)
                centres[s].append(centre)
                centre_err[s].append(1000 * float(np.linalg.norm(centre - cam_T_flange[:3, 3])))
        out["markerless_views"] = len(flanges[1.0])
        out["markerless_failed_views"] = failures[1.0]
        out["failed_views_per_noise"] = {str(s): failures[s] for s in scales}
        out["centre_error_mm"] = {str(s): centre_err[s] for s in scales}
        out["camera_distance_m"] = float(np.linalg.norm(truth[:3, 3] - poses[0][:3, 3]))
        n = min(n_main, len(flanges[1.0]))
        refused = out["refused"] = []
        out["markerless"] = _try(lambda: _markerless_fit(centres[1.0][:n], flanges[1.0][:n]),
                                 truth, refused, "markerless")
        if sweeps:
            out["noise_sweep"] = {str(s): _try(
                lambda s=s: _markerless_fit(centres[s][:n], flanges[s][:n]), truth, refused,
                f"noise {s}") for s in scales}
            out["poses_sweep"] = {str(k): _try(
                lambda k=k: _markerless_fit(centres[1.0][:k], flanges[1.0][:k]), truth,
                refused, f"poses {k}") for k in counts if k <= len(flanges[1.0])}
    # ---- board
    from cobotlab.demo import _board_detector
    from robots.capture import capture_pose_pairs

    with _cell(arm, seed, size, markerless=False) as cell:
        truth_b = cell.truth.base_T_cam
        assert np.allclose(truth_b, truth)  # the same camera mount in both cells
        poses = _candidate_poses(cell, seed, n_max)
        capture = capture_pose_pairs(cell.robot, cell.camera, poses,
                                     _board_detector(cell.truth.flange_target), progress=False,
                                     speed=0.25, settle_s=0.0)
        F, C = capture.pose_pairs()
        out["board_views"] = len(F)
        out["board_failed_views"] = len(capture.failed_indices)
        n = min(n_main, len(F))
        out["board"] = _try(lambda: calibrate_eye_to_hand(F[:n], C[:n]), truth, refused,
                            "board")
        out["board_ax_yb"] = _try(lambda: solve_ax_yb(F[:n], C[:n], "nonlinear")[1], truth,
                                  refused, "board AX=YB")
        if sweeps:
            out["board_poses_sweep"] = {str(k): _try(lambda k=k: calibrate_eye_to_hand(
                F[:k], C[:k]), truth, refused, f"board poses {k}") for k in counts if k <= len(F)}
    out["seconds"] = time.perf_counter() - started
    return out


# --------------------------------------------------------------------------- summary


def _median_ci(x, rng):
    """Median and bootstrap 95 % interval over the finite values (a refused fit is NaN and is
    counted in the table's notes, not here)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return float("nan"), float("nan"), float("nan")
    (med, lo, hi), _, _ = bootstrap_stats(x, rng, BOOTSTRAP)
    return float(med), float(lo), float(hi)


def _fmt(m):
    return f"{m[0]:.3f} [{m[1]:.3f}, {m[2]:.3f}]"


def summarise(results, n_main):
    """Table rows (markdown lines) and a dict of the summary numbers for one arm."""
    rng = np.random.default_rng(0)
    arm = results[0]["arm"]
    summary = {"arm": arm, "seeds": len(results), "n_poses": n_main}
    lines = [f"\n### {arm}: {len(results)} seeds, {n_main} poses each, medians [bootstrap 95 % CI]",
             "| method | translation (mm) | rotation (deg) |", "|---|---:|---:|"]
    labels = (("markerless", "markerless: bare flange in D435 depth, SVD registration"),
              ("board", "board: flange chessboard in RGB, AX = XB (calibrate_eye_to_hand)"),
              ("board_ax_yb", "board: the same views, AX = YB (solve_ax_yb nonlinear)"))
    for key, label in labels:
        t = [r[key][0] for r in results]
        d = [r[key][1] for r in results]
        summary[key] = {"translation_mm": _median_ci(t, rng), "rotation_deg": _median_ci(d, rng)}
        lines.append(f"| {label} | {_fmt(summary[key]['translation_mm'])} "
                     f"| {_fmt(summary[key]['rotation_deg'])} |")
    for k, what in ((0, "translation"), (1, "rotation")):
        a = np.array([r["markerless"][k] for r in results])
        b = np.array([r["board"][k] for r in results])
        both = np.isfinite(a) & np.isfinite(b)
        a, b = a[both], b[both]
        ratio = paired_ratio(a, b, np.random.default_rng(1 + k))
        summary[f"ratio_{what}"] = [float(x) for x in ratio]
        lines.append(f"| ratio markerless / board, {what} (paired bootstrap) | "
                     f"{ratio[0]:.2f} [{ratio[1]:.2f}, {ratio[2]:.2f}] | |")
    refused = [f"seed {r['seed']}: {why}" for r in results for why in r["refused"]]
    summary["refused"] = refused
    if refused:
        lines.append(f"\nRefused fits (NaN, left out of the medians): {len(refused)}: "
                     + "; ".join(refused[:6]) + (" ..." if len(refused) > 6 else ""))
    ce = np.concatenate([r["centre_error_mm"]["1.0"] for r in results])
    summary["centre_error_mm_median"] = float(np.median(ce))
    summary["centre_error_mm_p95"] = float(np.percentile(ce, 95))
    lines.append(f"\nFlange centre per view (D435 noise): median {np.median(ce):.2f} mm, "
                 f"p95 {np.percentile(ce, 95):.2f} mm from the truth over {len(ce)} views; "
                 f"camera to flange {np.median([r['camera_distance_m'] for r in results]):.2f} m;"
                 f" views kept: markerless {sum(r['markerless_views'] for r in results)}, "
                 f"failed {sum(r['markerless_failed_views'] for r in results)}; board "
                 f"{sum(r['board_views'] for r in results)}, failed "
                 f"{sum(r['board_failed_views'] for r in results)}.")
    if "noise_sweep" in results[0]:
        lines += ["\nMarkerless error vs depth noise (RealSenseDepthModel.subpixel x scale; "
                  f"{n_main} poses):",
                  "| noise scale | sigma_z at the flange (mm) | translation (mm) | rotation (deg) "
                  "| centre per view (mm) |", "|---:|---:|---:|---:|---:|"]
        summary["noise_sweep"] = []
        z = np.median([r["camera_distance_m"] for r in results])
        for s in results[0]["noise_sweep"]:
            t = [r["noise_sweep"][s][0] for r in results]
            d = [r["noise_sweep"][s][1] for r in results]
            ce = np.concatenate([r["centre_error_mm"][s] for r in results])
            row = {"depth_noise_scale": float(s), "translation_mm": _median_ci(t, rng),
                   "rotation_deg": _median_ci(d, rng), "centre_mm": float(np.median(ce))}
            summary["noise_sweep"].append(row)
            sigma = 1000 * RealSenseDepthModel(subpixel=0.08 * float(s)).sigma_z(z)
            lines.append(f"| {float(s):g} | {sigma:.2f} | {_fmt(row['translation_mm'])} | "
                         f"{_fmt(row['rotation_deg'])} | {row['centre_mm']:.2f} |")
        lines += ["\nError vs the number of poses (D435 noise; board: the same cell's board "
                  "views, AX = XB):",
                  "| poses | markerless translation (mm) | markerless rotation (deg) "
                  "| board translation (mm) | board rotation (deg) |", "|---:|---:|---:|---:|---:|"]
        summary["poses_sweep"] = []
        for k in results[0]["poses_sweep"]:
            have = [r for r in results if k in r["poses_sweep"] and k in r["board_poses_sweep"]]
            row = {"n_poses": int(k), "seeds": len(have)}
            for key, name in (("poses_sweep", "markerless"), ("board_poses_sweep", "board")):
                row[name] = {"translation_mm": _median_ci([r[key][k][0] for r in have], rng),
                             "rotation_deg": _median_ci([r[key][k][1] for r in have], rng)}
            summary["poses_sweep"].append(row)
            lines.append(f"| {k} | {_fmt(row['markerless']['translation_mm'])} | "
                         f"{_fmt(row['markerless']['rotation_deg'])} | "
                         f"{_fmt(row['board']['translation_mm'])} | "
                         f"{_fmt(row['board']['rotation_deg'])} |")
    return lines, summary


def lab_json(results, n_main, command, date):
    """The small file the lab 5 notebook plots (schema in the lab's design)."""
    def per_seed(key, k):
        return [round(float(r[key][k]), 4) for r in results]

    def sweep(key, name, cast):
        return [{name: cast(s),
                 "translation_mm": [round(float(r[key][s][0]), 4) for r in results
                                    if s in r[key]],
                 "rotation_deg": [round(float(r[key][s][1]), 4) for r in results
                                  if s in r[key]]}
                for s in results[0][key]]

    return {"arm": results[0]["arm"], "seeds": len(results), "n_poses": n_main,
            "command": command, "date": date,
            "methods": {"markerless": {"translation_mm": per_seed("markerless", 0),
                                       "rotation_deg": per_seed("markerless", 1)},
                        "board": {"translation_mm": per_seed("board", 0),
                                  "rotation_deg": per_seed("board", 1)}},
            "noise_sweep": sweep("noise_sweep", "depth_noise_scale", float),
            "poses_sweep": sweep("poses_sweep", "n_poses", int)}


def figure(results, summary, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    ax = axes[0]
    for key, label, colour in (("markerless", "markerless (bare flange, D435 depth)", "C0"),
                               ("board", "board (flange chessboard, AX = XB)", "C1")):
        t = [r[key][0] for r in results]
        d = [r[key][1] for r in results]
        ax.scatter(t, d, label=label, color=colour, alpha=0.8)
        ax.scatter([np.median(t)], [np.median(d)], marker="X", s=160, color=colour,
                   edgecolor="k")
    ax.set_xlabel("translation error of base_T_cam (mm)")
    ax.set_ylabel("rotation error (deg)")
    ax.set_title(f"{summary['arm']}: {len(results)} seeds, {summary['n_poses']} poses "
                 "(X = median)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)

    def band(ax, xs, rows, key, colour, label, ls="-o"):
        med = [r[key][0] for r in rows]
        lo = [r[key][1] for r in rows]
        hi = [r[key][2] for r in rows]
        ax.plot(xs, med, ls, color=colour, label=label)
        ax.fill_between(xs, lo, hi, color=colour, alpha=0.2)

    ax = axes[1]
    rows = summary["noise_sweep"]
    xs = [r["depth_noise_scale"] for r in rows]
    band(ax, xs, rows, "translation_mm", "C0", "translation (mm)")
    ax2 = ax.twinx()
    band(ax2, xs, rows, "rotation_deg", "C2", "rotation (deg)", "--s")
    ax.set_xlabel("depth noise scale (x a D435's subpixel 0.08 px)")
    ax.set_ylabel("translation error (mm)", color="C0")
    ax2.set_ylabel("rotation error (deg)", color="C2")
    ax.set_title(f"markerless vs depth noise ({summary['n_poses']} poses; median, 95 % CI)")
    ax.grid(alpha=0.3)

    ax = axes[2]
    rows = summary["poses_sweep"]
    xs = [r["n_poses"] for r in rows]
    band(ax, xs, [r["markerless"] for r in rows], "translation_mm", "C0", "markerless")
    band(ax, xs, [r["board"] for r in rows], "translation_mm", "C1", "board (AX = XB)")
    ax.set_xlabel("number of poses")
    ax.set_ylabel("translation error (mm)")
    ax.set_yscale("log")
    ax.set_title("error vs poses (median, 95 % CI)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--arm", default="ur5e")
    parser.add_argument("--also-arm", default="",
                        help="a second arm, main comparison only (no sweeps), e.g. panda")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--smoke", action="store_true",
                        help="2 seeds, 6 poses, 320 x 240 images: a fast check of the path")
    parser.add_argument("--json", default="", help="write every sample here")
    parser.add_argument("--lab-json", default="",
                        help="write the lab's small file here (labs/lab5_depth/depth_vs_board.json)")
    parser.add_argument("--figure", default="", help="write the figure here")
    parser.add_argument("--from-json", default="",
                        help="measure nothing: summarise, plot and write the lab file from the "
                             "samples of an earlier --json")
    args = parser.parse_args(argv)
    if args.from_json:
        with open(args.from_json) as f:
            saved = json.load(f)
        results, n_main = saved["samples"], saved["n_poses"]
        arm = args.arm if args.arm in results else next(iter(results))
        for rs in results.values():
            print("\n".join(summarise(rs, n_main)[0]))
        _write_outputs(args, results, arm, n_main, saved["command"], saved["date"])
        return 0

    seeds, n_main, counts, size = args.seeds, N_MAIN, POSE_COUNTS, SIZE
    if args.smoke:
        seeds, n_main, counts, size = min(seeds, 2), 6, (4, 6), (320, 240)
    n_max = max(max(counts), n_main)
    command = "python benchmarks/depth_calibration.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    print(f"# Depth (markerless flange) vs board calibration of a fixed camera: {args.arm}, "
          f"{seeds} seeds, {n_main} poses, {size[0]} x {size[1]}, {args.workers} workers",
          flush=True)
    started = time.perf_counter()
    jobs = [(args.arm, s, n_max, n_main, NOISE_SCALES, counts, size, True) for s in range(seeds)]
    if args.also_arm:
        jobs += [(args.also_arm, s, n_main, n_main, (1.0,), (), size, False)
                 for s in range(seeds)]
    results = {}
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for r in pool.map(run_seed, jobs):
            results.setdefault(r["arm"], []).append(r)
            print(f"{r['arm']} seed {r['seed']:2d}: markerless {r['markerless'][0]:7.3f} mm "
                  f"{r['markerless'][1]:6.3f} deg ({r['markerless_views']} views) | board "
                  f"{r['board'][0]:7.3f} mm {r['board'][1]:6.3f} deg ({r['board_views']} views)"
                  f" | {r['seconds']:.0f} s", flush=True)
    wall = time.perf_counter() - started
    summaries = {}
    for arm, rs in results.items():
        lines, summaries[arm] = summarise(rs, n_main)
        print("\n".join(lines))
    print(f"\nTotal {wall:.0f} s wall with {args.workers} workers.")
    if args.json:
        blob = {"command": command, "date": date, "machine": f"{platform.node()} "
                f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
                "wall_s": wall, "workers": args.workers, "image_size": list(size),
                "n_poses": n_main, "noise_scales": list(NOISE_SCALES), "pose_counts": list(counts),
                "cell": {"mount": "eye_to_hand", "pixel_noise": PIXEL_NOISE,
                         "encoder_noise_deg": ENCODER_NOISE_DEG, "mount_error": MOUNT_ERROR},
                "summary": summaries, "samples": results}
        with open(args.json, "w") as f:
            json.dump(blob, f, indent=1)
    _write_outputs(args, results, args.arm, n_main, command, date)
    return 0


def _write_outputs(args, results, arm, n_main, command, date):
    if args.lab_json:
        os.makedirs(os.path.dirname(os.path.abspath(args.lab_json)), exist_ok=True)
        with open(args.lab_json, "w") as f:
            json.dump(lab_json(results[arm], n_main, command, date), f, indent=1)
            f.write("\n")
    if args.figure:
        os.makedirs(os.path.dirname(os.path.abspath(args.figure)), exist_ok=True)
        figure(results[arm], summarise(results[arm], n_main)[1], args.figure)


if __name__ == "__main__":
    sys.exit(main())
