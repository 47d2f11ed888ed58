"""How fast is the simulator? Frames per second, IK solve time and move time.

Run:  python benchmarks/sim_speed.py [--arm panda] [--frames 20] [--seed 0]

Prints a Markdown table (paste it into the README). Rendering is PyBullet's TinyRenderer on
the CPU, single-threaded, so the numbers are per core. Each resolution is measured in both
mounts: eye-to-hand (a fixed camera that sees the whole arm, the heavier scene) and
eye-in-hand (the camera on the flange looking down at the board). RGB means ``capture()``
with ``with_depth=False``; RGB-D adds the metric depth image. The target is at least 7
frames/s at 640x480 RGB-D.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from robots import connect
from robots.geometry import compose, pose_from_rpy

RESOLUTIONS = ((320, 240), (640, 480), (1280, 720))


def frames_per_second(camera, n: int, with_depth: bool) -> float:
    camera.with_depth = with_depth
    camera.capture()  # warm-up: first render builds TinyRenderer's caches
    start = time.perf_counter()
    for _ in range(n):
        camera.capture()
    return n / (time.perf_counter() - start)


def ik_and_move_times(arm: str, seed: int, n: int = 20) -> tuple[float, float, float]:
    """(median IK solve ms, median wall s of a 10 cm move, simulated s of that move)."""
    with connect("sim", arm=arm, mount="eye_in_hand", seed=seed, width=320, height=240) as cell:
        robot, sim_arm = cell.robot, cell.arm
        start = robot.flange_pose()
        rng = np.random.default_rng(seed)
        ik_ms = []
        for _ in range(n):
            offset = pose_from_rpy(*rng.uniform(-0.3, 0.3, 3), t=rng.uniform(-0.1, 0.1, 3))
            t0 = time.perf_counter()
            sim_arm.solve_ik(compose(start, offset))
            ik_ms.append(1e3 * (time.perf_counter() - t0))
        move_s, sim_s = [], []
        for k in range(4):
            target = compose(start, pose_from_rpy(0, 0, 0, t=[0.1 * (-1) ** k, 0, 0]))
            t_sim = sim_arm.motion_time
            t0 = time.perf_counter()
            robot.move_to(target, speed=0.1)
            move_s.append(time.perf_counter() - t0)
            sim_s.append(sim_arm.motion_time - t_sim)
            start = robot.flange_pose()
    return float(np.median(ik_ms)), float(np.median(move_s)), float(np.median(sim_s))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", default="panda")
    parser.add_argument("--frames", type=int, default=20, help="frames per measurement")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rows = []
    for width, height in RESOLUTIONS:
        for mount in ("eye_to_hand", "eye_in_hand"):
            with connect("sim", arm=args.arm, mount=mount, seed=args.seed, width=width,
                         height=height) as cell:
                rgb = frames_per_second(cell.camera, args.frames, with_depth=False)
                rgbd = frames_per_second(cell.camera, args.frames, with_depth=True)
            rows.append((f"{width}x{height}", mount, rgb, rgbd))
    ik_ms, move_s, sim_s = ik_and_move_times(args.arm, args.seed)

    print(f"Simulator speed ({args.arm}, TinyRenderer, one core)\n")
    print("| resolution | mount | RGB frames/s | RGB-D frames/s |")
    print("|---|---|---:|---:|")
    for res, mount, rgb, rgbd in rows:
        print(f"| {res} | {mount} | {rgb:.1f} | {rgbd:.1f} |")
    print()
    print("| operation | time |")
    print("|---|---:|")
    print(f"| IK solve (median of 20 poses within 10 cm / 17 deg) | {ik_ms:.1f} ms |")
    print(f"| move_to, 10 cm at 0.1 m/s (wall clock) | {move_s:.3f} s |")
    print(f"| the same move in simulated time | {sim_s:.3f} s |")
    target = [r for r in rows if r[0] == "640x480"]
    worst = min(r[3] for r in target)
    verdict = "meets" if worst >= 7 else "MISSES"
    print(f"\n640x480 RGB-D: {worst:.1f} frames/s in the heavier mount, {verdict} the "
          "7 frames/s target.")


if __name__ == "__main__":
    main()
