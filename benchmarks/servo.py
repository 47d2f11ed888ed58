"""Visual-servoing benchmark: convergence of PBVS / IBVS and pick-and-place under calibration error.

    .venv/bin/python benchmarks/servo.py            # 100 seeded trials per cell
    .venv/bin/python benchmarks/servo.py --quick    # 10 trials per cell

Part 1 (convergence): from seeded 10 cm / 20 degree offsets (rotation about the target centre),
servo back to a goal 0.5 m (kinematic) / 0.45 m (PyBullet, ChArUco board, 640x480) from the
target. Final error = camera position error to the goal (truth). Target: IBVS <= 1 mm within
50 iterations.

Part 2 (pick-and-place e2 -> e4, eye-in-hand RGB-D camera, suction cup, 320x240): for open
loop (look-then-move), PBVS and IBVS, with the calibration the controller uses off the true
mount by 0, (2 mm, 1 deg) and (5 mm, 2 deg) in seeded random directions. Success = the pawn
ends on e4. Grasp error = horizontal distance (truth) between the suction tip and the pawn's
axis when the vacuum engages. Iterations and simulated seconds are those of the servo stage.
PBVS and IBVS raise the flange 8 cm along its axis and back before the descent and correct
it by the tool-axis tilt the camera sees; one more row, at (5 mm, 2 deg), descends without
that check, as before it existed. Target: success >= 98 % with (5 mm, 2 deg). With --overview the search and the coarse stage
use a fixed camera over the board instead of the wrist camera's overview poses, its
calibration off by the same amount as the wrist camera's; the arm is parked aside while it
looks. Where the fixed camera's estimate cannot single out the piece from the hover pose (it
is about as near a neighbour), the wrist camera looks again from its overview poses; the
row name counts those trials. Prints markdown tables.
See also benchmarks/servo_endpoint.py (endpoint open against closed loop, fixed camera).

    .venv/bin/python benchmarks/servo.py --check-cost   # only the cost of the input checks

--check-cost (issue 38): what the checks that name a student's mistake cost where they sit,
in ``invert`` / ``compose`` / ``transform_points`` (a non-rigid pose) and in the servo laws
(pixels for normalised coordinates, deg/s): each case runs with the checks and with them
switched off (the previous fast path: the same code with ``_refuse_non_rigid``,
``check_normalised`` and ``check_angular_speed`` replaced by no-ops), in alternating blocks
in one process so that a busy machine slows both alike, timed in CPU seconds of this process
(``time.process_time``: the other processes on a shared machine do not count), with 95 %
bootstrap intervals of the medians and of their difference. The last rows are whole kinematic servo runs, where the
cost must be negligible.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

if "--check-cost" in sys.argv:
    # One BLAS thread: idle BLAS threads spin and their CPU time, counted by process_time,
    # swamped a servo run's own (0.54 s instead of 0.04 s for 8 runs on a busy machine). Set
    # before numpy loads its BLAS.
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np
from tqdm.auto import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from robots import geometry as geo
from robots import perception as P
from robots.geometry import (
    compose,
    invert,
    make_pose,
    transform_points,
    translation_error,
)
from solutions import servoing as S
from solutions.endpoint import perturbed_calibration

CAL_ERRORS = [(0.0, 0.0), (2.0, 1.0), (5.0, 2.0)]


def _row(name, ok, err_mm, its, time_s, n):
    e = np.array(err_mm) if err_mm else np.array([np.nan])
    i = np.array(its) if its else np.array([np.nan])
    t = np.array(time_s) if time_s else np.array([np.nan])
    return (f"| {name} | {100 * ok / n:.0f} % ({ok}/{n}) | {np.nanmedian(e):.2f} | "
            f"{np.nanpercentile(e, 95):.2f} | {np.nanmedian(i):.0f} | {np.nanmax(i):.0f} | "
            f"{np.nanmedian(t):.2f} |")


# At 320x240 IBVS stalls near 0.12 px of image error, about 1.2 mm at 0.45 m; at 640x480 the
# same law ends near 0.4 mm, inside the 1 mm target (measured: 5 seeds, 0.37 mm median).
CONVERGENCE_SIZE = (640, 480)


def convergence(trials: int) -> list[str]:
    from sim_backends.world import create_workcell, default_intrinsics

    lines = [("| servo (10 cm / 20 deg offsets) | converged | final error median (mm) | "
             "p95 (mm) | iterations median | max | sim time median (s) |"),
             "|---|---|---|---|---|---|---|"]
    intr = default_intrinsics(320, 240)
    square = np.array([[-.04, -.04, 0], [.04, -.04, 0], [.04, .04, 0], [-.04, .04, 0]])
    goal = make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5])
    for method in ("ibvs", "pbvs"):
        rng = np.random.default_rng(0)
        ok, err, its, tt = 0, [], [], []
        for _ in tqdm(range(trials), desc=f"kinematic {method}", leave=False):
            start = S.offset_start(goal, [0, 0, 0], 0.10, 20.0, rng)
            try:
                r = S.simulate_servo(method, start, goal, square, intr)
            except S.ServoError:
                continue
            ok += 1
            err.append(r.position_error_m * 1e3)
            its.append(r.iterations)
            tt.append(r.time_s)
        lines.append(_row(f"{method.upper()}, pure kinematics", ok, err, its, tt, trials))
    for method in ("ibvs", "pbvs"):
        ok, err, its, tt = 0, [], [], []
        n = trials
        for seed in tqdm(range(n), desc=f"pybullet {method}", leave=False):
            with create_workcell(arm="panda", target="charuco", seed=seed,
                                 width=CONVERGENCE_SIZE[0], height=CONVERGENCE_SIZE[1]) as cell:
                truth, board = cell.truth, cell.truth.board
                centre = board.centre
                camd_T_board = compose(make_pose(t=[0, 0, 0.45]), make_pose(t=-centre))
                base_T_camd = compose(truth.base_T_board, invert(camd_T_board))
                start = S.offset_start(base_T_camd, transform_points(truth.base_T_board,
                                                                     [centre])[0],
                                       0.10, 20.0, np.random.default_rng(seed))
                try:
                    S.move_in_steps(cell.robot, start @ invert(truth.flange_T_cam))
                except (RuntimeError, ValueError):
                    n -= 1  # the arm cannot reach this start: not a servo failure
                    continue
                intr_c = cell.camera.intrinsics

                def detect(frame, intrinsics=intr_c, board=board):
                    return P.detect_charuco(frame, intrinsics, board.board)

                make = S.ibvs_step if method == "ibvs" else S.pbvs_step
                try:
                    r = S.run_servo(cell.robot, cell.camera, truth.nominal_flange_T_cam,
                                    make(detect, camd_T_board, intr_c, margin_px=None),
                                    tolerance=5e-4 if method == "ibvs" else 2e-3,
                                    max_iterations=50)
                except S.ServoError:
                    continue
                ok += 1
                err.append(translation_error(truth.base_T_cam_now(), base_T_camd) * 1e3)
                its.append(r.iterations)
                tt.append(r.time_s)
        size = "x".join(map(str, CONVERGENCE_SIZE))
        lines.append(_row(f"{method.upper()}, PyBullet ChArUco {size}", ok, err, its, tt, n))
    return lines


def pick_trials(arm: str, trials: int, overview: bool = False) -> list[str]:
    from sim_backends.world import create_workcell

    where = " + fixed overview camera" if overview else ""
    lines = [(f"| {arm}{where}: method, calibration error | pick success | grasp error median (mm) | "
             "p95 (mm) | servo iterations median | max | servo sim time median (s) |"),
             "|---|---|---|---|---|---|---|"]
    for mm, deg in CAL_ERRORS:
        variants = [("open_loop", True), ("pbvs", True), ("ibvs", True)]
        if (mm, deg) == CAL_ERRORS[-1]:
            variants.append(("pbvs", False))  # the descent before the tool-axis check
        for method, check_axis in variants:
            ok, err, its, tt, looked_again = 0, [], [], [], 0
            for seed in tqdm(range(trials), desc=f"{arm} {method} {mm}mm/{deg}deg", leave=False):
                with create_workcell(arm=arm, scene="chess", seed=seed, width=320,
                                     height=240, overview_camera=overview) as cell:
                    truth = cell.truth
                    cal = perturbed_calibration(truth.flange_T_cam, mm, deg,
                                                np.random.default_rng(1000 + seed))
                    extra = {}
                    if overview:  # the fixed camera's calibration is off by as much
                        extra["base_T_overview_cam"] = perturbed_calibration(
                            truth.base_T_overview_cam, mm, deg, np.random.default_rng(5000 + seed))
                    grasp_err = []

                    def on_stage(stage, ctl, truth=truth, grasp_err=grasp_err):
                        if stage == "lift":  # the vacuum just engaged
                            body = ctl.robot.tool.held_body
                            piece = next(t for t in truth.pieces.values() if t.body_id == body)
                            tip = ctl.robot.tool.flange_T_tcp
                            tcp = compose(truth.base_T_flange(), tip)[:3, 3]
                            grasp_err.append(np.linalg.norm(tcp[:2] - piece.base_T_piece[:2, 3]))

                    try:
                        r = S.pick_and_place(cell, "e2", "e4", method=method, flange_T_cam=cal,
                                             on_stage=on_stage, check_tool_axis=check_axis,
                                             **extra)
                    except (S.ServoError, RuntimeError, ValueError, StopIteration):
                        continue
                    after = truth.pieces
                    if "e4" in after and after["e4"].kind == "pawn" and "e2" not in after:
                        ok += 1
                    if grasp_err:
                        err.append(grasp_err[0] * 1e3)
                    its.append(r.iterations)
                    tt.append(r.time_s)
                    looked_again += sum(e.stage == "search" for e in r.log) > 1
            name = f"{method}, {mm:g} mm / {deg:g} deg"
            if not check_axis:
                name = f"{method} without the tool-axis check, {mm:g} mm / {deg:g} deg"
            if overview:
                name += f" (wrist camera looked again: {looked_again})"
            lines.append(_row(name, ok, err, its, tt, trials))
    return lines


@contextlib.contextmanager
def _checks(on: bool):
    """The input checks of issue 38 as they are (``on``) or replaced by no-ops: the previous
    fast path, with everything else identical."""
    saved = geo._refuse_non_rigid, S.check_normalised, S.check_angular_speed
    if not on:
        geo._refuse_non_rigid = lambda T, label: None
        S.check_normalised = lambda xy, name: xy
        S.check_angular_speed = lambda value, name: value
    try:
        yield
    finally:
        geo._refuse_non_rigid, S.check_normalised, S.check_angular_speed = saved


def _bootstrap_median(x: np.ndarray, rng, n_boot: int = 2000) -> np.ndarray:
    """Medians of ``n_boot`` resamples of ``x`` (with replacement)."""
    return np.median(x[rng.integers(0, len(x), (n_boot, len(x)))], axis=1)


def _time_blocks(fn, reps: int, block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """CPU seconds per call of ``fn`` with the checks off and on: ``reps`` blocks each, in
    alternating order (off-on, on-off, ...), each block as many calls as fill ``block_s``."""
    clock = time.process_time
    with _checks(True):
        fn()  # warm up; also proves the good input passes the checks
        t0, n = clock(), 0
        while clock() - t0 < block_s / 4:
            fn()
            n += 1
    number = max(1, int(4 * n))
    times = {False: [], True: []}
    for r in range(reps):
        for on in ((False, True) if r % 2 == 0 else (True, False)):
            with _checks(on):
                t0 = clock()
                for _ in range(number):
                    fn()
                times[on].append((clock() - t0) / number)
    return np.array(times[False]), np.array(times[True])


def check_cost(reps: int) -> list[str]:
    """The table of --check-cost: per case the median time per call without and with the
    checks, the added time and the ratio, each with a 95 % bootstrap interval."""
    from sim_backends.world import default_intrinsics

    rng = np.random.default_rng(38)
    T = S.offset_start(make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5]), [0, 0, 0], 0.1, 20.0,
                       rng)
    T2 = compose(T, make_pose(t=[0.01, 0.02, 0.03]))
    stack = np.stack([S.offset_start(T, [0, 0, 0], 0.1, 20.0, rng) for _ in range(200)])
    pts = rng.uniform(-0.2, 0.2, (100, 3))
    square = np.array([[-.04, -.04, 0], [.04, -.04, 0], [.04, .04, 0], [-.04, .04, 0]])
    s_star = S.normalised_projection(square + [0, 0, 0.5])
    s = s_star + rng.normal(0, 0.01, s_star.shape)
    z = np.full(4, 0.5)
    intr = default_intrinsics(320, 240)
    goal = make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5])
    starts = [S.offset_start(goal, [0, 0, 0], 0.10, 20.0, np.random.default_rng(k))
              for k in range(8)]
    twist = np.array([0.1, -0.05, 0.02, 0.3, -0.2, 0.1])

    def servo_runs(method):
        return lambda: [S.simulate_servo(method, st, goal, square, intr) for st in starts]

    cases = [
        ("invert(T), one pose", lambda: invert(T), 0.01),
        ("invert(stack), 200 poses", lambda: invert(stack), 0.01),
        ("compose(T, T2)", lambda: compose(T, T2), 0.01),
        ("compose(stack, T), 200 poses", lambda: compose(stack, T), 0.01),
        ("transform_points(T, points), 100 points", lambda: transform_points(T, pts), 0.01),
        ("ibvs_velocity, 4 points", lambda: S.ibvs_velocity(s, s_star, z, 1.0), 0.01),
        ("interaction_matrix, 4 points", lambda: S.interaction_matrix(s, z), 0.01),
        ("saturate(twist, 0.25, 1.0)", lambda: S.saturate(twist, 0.25, 1.0), 0.01),
        ("simulate_servo IBVS, 8 runs (kinematic)", servo_runs("ibvs"), 0.0),
        ("simulate_servo PBVS, 8 runs (kinematic)", servo_runs("pbvs"), 0.0),
    ]
    lines = ["| case | without the checks (us) | with (us) | added (us) | ratio |",
             "|---|---|---|---|---|"]
    for name, fn, block_s in tqdm(cases, desc="check cost", leave=False):
        n_reps = reps if block_s else max(10, reps // 5)  # 8 whole servo runs are one block
        off, on = _time_blocks(fn, n_reps, block_s)
        b_off, b_on = _bootstrap_median(off, rng), _bootstrap_median(on, rng)

        def ci(b, scale=1e6):
            lo, hi = np.percentile(b * scale, [2.5, 97.5])
            return f"[{lo:.3g}, {hi:.3g}]"

        added, ratio = b_on - b_off, b_on / b_off
        lines.append(
            f"| {name} | {np.median(off) * 1e6:.3g} {ci(b_off)} | {np.median(on) * 1e6:.3g} "
            f"{ci(b_on)} | {(np.median(on) - np.median(off)) * 1e6:+.3g} {ci(added)} | "
            f"{np.median(on) / np.median(off):.3f} {ci(ratio, 1.0)} |")
    lines.append(f"\n({n_reps} blocks per arm for the servo runs, {reps} for the rest; 95 % "
                 "bootstrap intervals of the medians, 2000 resamples)")
    return lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--quick", action="store_true", help="10 trials per cell")
    ap.add_argument("--arms", default="panda",
                    help="comma-separated arms for pick-and-place: panda, ur10e, aubo_i5, "
                         "cobotta (default: panda)")
    ap.add_argument("--overview", action="store_true",
                    help="search and coarse stage on a fixed overview camera (its calibration "
                         "off by the same error as the wrist camera's)")
    ap.add_argument("--skip-convergence", action="store_true")
    ap.add_argument("--skip-pick", action="store_true")
    ap.add_argument("--check-cost", action="store_true",
                    help="only measure what the input checks (non-rigid poses, pixels for "
                         "normalised coordinates, deg/s) cost, with and without them")
    ap.add_argument("--reps", type=int, default=100,
                    help="--check-cost: timed blocks of 10 ms per arm and case (default 100; "
                         "a fifth as many blocks of 8 whole servo runs)")
    args = ap.parse_args(argv)
    trials = 10 if args.quick else args.trials
    t0 = time.time()
    if args.check_cost:
        print("\n".join(check_cost(args.reps)))
        print(f"({time.time() - t0:.0f} s)")
        return
    if not args.skip_convergence:
        print("\n".join(convergence(trials)))
        print()
    if not args.skip_pick:
        for arm in args.arms.split(","):
            print("\n".join(pick_trials(arm.strip(), trials, args.overview)))
            print()
    print(f"({trials} trials per row, {time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
