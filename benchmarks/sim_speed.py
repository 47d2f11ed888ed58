"""How fast is each simulator engine? RGB-D frames per second, IK, a move, peak memory, labs.

Run:  python benchmarks/sim_speed.py [--arm ur5e] [--frames 20] [--seed 0] [--quick]
                                    [--lab lab4_stereo,lab5_depth | --lab none] [--repeats 5]

Measures both engines (MuJoCo and PyBullet) in one run, side by side, each in its own
process so that its peak memory (``ru_maxrss``) is its own. Per engine: ``capture()`` with
depth (RGB-D) at 640x480 and 1280x720 in both mounts (eye-to-hand: a fixed camera seeing the
whole arm; eye-in-hand: the camera on the flange above the board), the median IK solve (CPU
time of the solving thread), one 10 cm ``move_to`` and back, the time to build the cell, the
process's peak resident memory. Frames per second are 1 / mean frame time with a 95 %
bootstrap interval over the frames (2000 resamples); the MuJoCo/PyBullet ratio's interval
resamples both engines. Rendering is on the CPU here (PyBullet's TinyRenderer; MuJoCo's
OpenGL through Mesa's llvmpipe via EGL), so the numbers depend on the machine's cores and on
other load. The goal (issue 49): MuJoCo at least twice PyBullet's RGB-D frame rate.

Labs (``--lab``, comma-separated): each lab's source notebook, every code cell top to bottom
with its solutions and checks (IPython magics dropped), run in a fresh Python process per run
with ``COBOTLAB_SIM_ENGINE`` set, so the notebook's own ``connect("sim", ...)`` picks the
engine, as a student's would. ``--repeats`` runs per engine, interleaved (PyBullet, MuJoCo,
then MuJoCo, PyBullet, ...) so slow spells of a shared machine fall on both. Measured in CPU
seconds (the process's user + system time, every thread, and any process it waits for), not
wall time, which other users' load inflates; the MuJoCo / PyBullet ratio of the mean CPU
seconds has a 95 % bootstrap interval resampling each engine's runs. The goal: no lab slower.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

RESOLUTIONS = ((640, 480), (1280, 720))
MOUNTS = ("eye_to_hand", "eye_in_hand")
ENGINES = ("pybullet", "mujoco")
BOOTSTRAP = 2000


def frame_times(camera, n: int) -> list[float]:
    """Seconds per RGB-D ``capture()`` for n frames, after one warm-up frame."""
    camera.with_depth = True
    camera.capture()  # warm-up: the first render builds caches (and MuJoCo's GL context)
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        camera.capture()
        times.append(time.perf_counter() - t0)
    return times


def ik_and_move(cell, seed: int, n: int = 20) -> dict:
    """Median IK CPU ms over n poses near the start; wall and simulated s of a 10 cm move and
    back."""
    from robots.geometry import compose, pose_from_rpy

    robot, arm = cell.robot, cell.arm
    start = robot.flange_pose()
    rng = np.random.default_rng(seed)
    ik_ms = []
    for _ in range(n):
        offset = pose_from_rpy(*rng.uniform(-0.3, 0.3, 3), t=rng.uniform(-0.1, 0.1, 3))
        # CPU time of this thread: IK is single-threaded, and wall time carries other load.
        t0 = time.thread_time()
        try:
            arm.solve_ik(compose(start, offset))
        except Exception:  # noqa: BLE001  (an unreachable draw still costs its time)
            pass
        ik_ms.append(1e3 * (time.thread_time() - t0))
    t_sim, t0 = arm.motion_time, time.perf_counter()
    robot.move_to(compose(start, pose_from_rpy(0, 0, 0, t=[0.1, 0, 0])), speed=0.1)
    robot.move_to(start, speed=0.1)
    return {"ik_ms": float(np.median(ik_ms)), "move_s": time.perf_counter() - t0,
            "move_sim_s": arm.motion_time - t_sim}


def pick_and_place(engine: str, arm: str, seed: int) -> dict:
    """One staged pick and place e2 -> e4 (IBVS, the true wrist-camera calibration, 320x240):
    wall time, simulated time, and whether the pawn ended on e4."""
    from robots import connect
    from solutions import servoing

    t0 = time.perf_counter()
    with connect("sim", engine=engine, arm=arm, scene="chess", seed=seed, width=320,
                 height=240) as cell:
        before = cell.truth.pieces
        t_sim = cell.arm.motion_time
        servoing.pick_and_place(cell, "e2", "e4", method="ibvs",
                                flange_T_cam=cell.truth.flange_T_cam)
        after = cell.truth.pieces
        placed = "e4" in after and after["e4"].body_id == before["e2"].body_id
        return {"pick_s": time.perf_counter() - t0, "pick_sim_s": cell.arm.motion_time - t_sim,
                "pick_placed": bool(placed)}


def lab_cells_cpu_s(lab: str) -> float:
    """CPU seconds of this process (every thread, and what it waited for) to run the code
    cells of ``labs/<lab>/<lab>.ipynb`` top to bottom in one namespace, in the lab's folder,
    with their printed output swallowed. The engine is ``COBOTLAB_SIM_ENGINE``'s."""
    import contextlib
    import io
    import os
    from pathlib import Path

    import matplotlib
    import nbformat

    matplotlib.use("Agg")   # figures are drawn, never shown
    path = Path(__file__).resolve().parents[1] / "labs" / lab / f"{lab}.ipynb"
    nb = nbformat.read(path, as_version=4)
    os.chdir(path.parent)
    namespace = {"__name__": "__main__"}
    t0 = _cpu_s()
    with contextlib.redirect_stdout(io.StringIO()):
        for k, cell in enumerate(nb.cells):
            if cell.cell_type == "code":
                code = "\n".join(line for line in cell.source.splitlines()
                                 if not line.lstrip().startswith(("%", "!")))
                exec(compile(code, f"{lab} cell {k}", "exec"), namespace)  # noqa: S102
    return _cpu_s() - t0


def _cpu_s() -> float:
    self, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                           resource.RUSAGE_CHILDREN))
    return self.ru_utime + self.ru_stime + children.ru_utime + children.ru_stime


def lab_runs(labs, repeats: int) -> dict:
    """{lab: {engine: [CPU s per run]}}: ``repeats`` fresh-process runs per engine and lab,
    the engines' order alternating from one repeat to the next."""
    import os

    runs = {lab: {engine: [] for engine in ENGINES} for lab in labs}
    for r in range(repeats):
        for lab in labs:
            for engine in (ENGINES if r % 2 == 0 else ENGINES[::-1]):
                env = dict(os.environ, COBOTLAB_SIM_ENGINE=engine)
                done = subprocess.run([sys.executable, __file__, "--run-lab", lab], env=env,
                                      capture_output=True, text=True, check=False)
                if done.returncode != 0:
                    raise RuntimeError(f"{lab} failed on {engine}: "
                                       f"{done.stderr.strip().splitlines()[-1]}")
                runs[lab][engine].append(float(done.stdout.strip().splitlines()[-1]))
    return runs


def measure(engine: str, arm: str, frames: int, seed: int, resolutions) -> dict:
    """Everything for one engine (run in its own process: see ``main``)."""
    from robots import connect

    out = {"engine": engine, "frames": {}, "build_s": []}
    for width, height in resolutions:
        for mount in MOUNTS:
            t0 = time.perf_counter()
            with connect("sim", engine=engine, arm=arm, mount=mount, seed=seed, width=width,
                         height=height) as cell:
                out["build_s"].append(time.perf_counter() - t0)
                out["frames"][f"{width}x{height} {mount}"] = frame_times(cell.camera, frames)
    with connect("sim", engine=engine, arm=arm, seed=seed, width=320, height=240) as cell:
        out.update(ik_and_move(cell, seed))
    out.update(pick_and_place(engine, arm, seed))
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def fps_interval(times, rng) -> tuple[float, float, float]:
    """Frames per second (1 / mean time) and its 95 % bootstrap interval."""
    t = np.asarray(times)
    means = rng.choice(t, size=(BOOTSTRAP, t.size)).mean(axis=1)
    lo, hi = np.percentile(1.0 / means, [2.5, 97.5])
    return 1.0 / t.mean(), lo, hi


def ratio_interval(times_a, times_b, rng) -> tuple[float, float, float]:
    """fps(a) / fps(b) = mean(b) / mean(a), with both engines' frames resampled."""
    a, b = np.asarray(times_a), np.asarray(times_b)
    ma = rng.choice(a, size=(BOOTSTRAP, a.size)).mean(axis=1)
    mb = rng.choice(b, size=(BOOTSTRAP, b.size)).mean(axis=1)
    lo, hi = np.percentile(mb / ma, [2.5, 97.5])
    return b.mean() / a.mean(), lo, hi


def run_engine(engine: str, args) -> dict:
    cmd = [sys.executable, __file__, "--engine", engine, "--arm", args.arm, "--frames",
           str(args.frames), "--seed", str(args.seed)] + (["--quick"] if args.quick else [])
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return {"engine": engine, "error": done.stderr.strip().splitlines()[-1]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def report(results: dict, args) -> None:
    rng = np.random.default_rng(0)
    ok = {e: r for e, r in results.items() if "error" not in r}
    for engine, r in results.items():
        if "error" in r:
            print(f"{engine}: not measured ({r['error']})\n")
    print(f"Simulator speed, {args.arm}, RGB-D capture(), {args.frames} frames per cell, "
          "95 % bootstrap intervals\n")
    print("| image | mount | " + " | ".join(f"{e} frames/s" for e in ok)
          + (" | MuJoCo / PyBullet |" if len(ok) == 2 else " |"))
    print("|---|---|" + "---:|" * (len(ok) + (len(ok) == 2)))
    keys = next(iter(ok.values()))["frames"].keys() if ok else []
    for key in keys:
        res, mount = key.split(" ")
        cells = []
        for r in ok.values():
            f, lo, hi = fps_interval(r["frames"][key], rng)
            cells.append(f"{f:.1f} [{lo:.1f}, {hi:.1f}]")
        if len(ok) == 2:
            q, lo, hi = ratio_interval(ok["mujoco"]["frames"][key], ok["pybullet"]["frames"][key],
                                       rng)
            cells.append(f"{q:.2f} [{lo:.2f}, {hi:.2f}]")
        print(f"| {res} | {mount} | " + " | ".join(cells) + " |")
    print()
    print("| | " + " | ".join(ok) + " |")
    print("|---|" + "---:|" * len(ok))
    rows = [("build a cell (median, s)", lambda r: f"{np.median(r['build_s']):.2f}"),
            ("IK solve (median of 20, CPU ms)", lambda r: f"{r['ik_ms']:.1f}"),
            ("move_to 10 cm and back, wall (s)", lambda r: f"{r['move_s']:.3f}"),
            ("the same, simulated (s)", lambda r: f"{r['move_sim_s']:.3f}"),
            ("pick and place e2 -> e4, wall incl. building the cell (s)",
             lambda r: f"{r['pick_s']:.1f} ({'placed' if r['pick_placed'] else 'NOT placed'})"),
            ("the same, simulated (s)", lambda r: f"{r['pick_sim_s']:.1f}"),
            ("peak memory of the process (MB)", lambda r: f"{r['peak_mb']:.0f}")]
    for label, cell in rows:
        print(f"| {label} | " + " | ".join(cell(r) for r in ok.values()) + " |")
    if len(ok) == 2:
        ratios = [ratio_interval(ok["mujoco"]["frames"][k], ok["pybullet"]["frames"][k], rng)
                  for k in keys]
        worst = min(ratios, key=lambda r: r[1])
        verdict = "meets" if worst[1] >= 2.0 else "does NOT meet"
        print(f"\nSlowest MuJoCo/PyBullet ratio: {worst[0]:.2f} (95 % lower bound "
              f"{worst[1]:.2f}); MuJoCo {verdict} the 2x goal in every cell.")


def report_labs(runs: dict, repeats: int) -> None:
    """The labs' table: mean CPU seconds per engine and the MuJoCo / PyBullet ratio."""
    rng = np.random.default_rng(1)
    print(f"\nLabs' source notebooks top to bottom, CPU seconds, mean of {repeats} interleaved "
          "runs per engine [95 % bootstrap interval]\n")
    print("| lab | pybullet CPU s | mujoco CPU s | MuJoCo / PyBullet |")
    print("|---|---:|---:|---:|")
    for lab, by_engine in runs.items():
        cells = []
        for engine in ENGINES:
            t = np.asarray(by_engine[engine])
            means = rng.choice(t, size=(BOOTSTRAP, t.size)).mean(axis=1)
            lo, hi = np.percentile(means, [2.5, 97.5])
            cells.append(f"{t.mean():.2f} [{lo:.2f}, {hi:.2f}]")
        q, lo, hi = ratio_interval(by_engine["pybullet"], by_engine["mujoco"], rng)
        verdict = "slower" if lo > 1 else ("faster" if hi < 1 else "no difference shown")
        print(f"| {lab} | " + " | ".join(cells) + f" | {q:.2f} [{lo:.2f}, {hi:.2f}] ({verdict}) |")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", default="ur5e", help="an arm both engines build")
    parser.add_argument("--frames", type=int, default=20, help="frames per measurement")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="640x480 only (a smoke run)")
    parser.add_argument("--lab", default="lab4_stereo,lab5_depth",
                        help="labs (comma-separated) whose source notebooks are timed per "
                             "engine, or 'none'")
    parser.add_argument("--repeats", type=int, default=5, help="runs per engine and lab")
    parser.add_argument("--engine", choices=ENGINES, help=argparse.SUPPRESS)  # one child run
    parser.add_argument("--run-lab", help=argparse.SUPPRESS)  # one lab run (a child)
    args = parser.parse_args(argv)
    if args.run_lab:
        print(lab_cells_cpu_s(args.run_lab))
        return
    resolutions = RESOLUTIONS[:1] if args.quick else RESOLUTIONS
    if args.engine:
        print(json.dumps(measure(args.engine, args.arm, args.frames, args.seed, resolutions)))
        return
    if args.repeats < 2:
        parser.error("--repeats must be at least 2 (an interval needs more than one run)")
    report({engine: run_engine(engine, args) for engine in ENGINES}, args)
    labs = [] if args.lab == "none" else [lab for lab in args.lab.split(",") if lab]
    if labs:
        report_labs(lab_runs(labs, args.repeats), args.repeats)


if __name__ == "__main__":
    main()
