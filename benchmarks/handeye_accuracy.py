"""Hand-eye accuracy and speed: our reference solvers against every OpenCV method, same data.

Run:  .venv/bin/python benchmarks/handeye_accuracy.py [--trials 100] [--workers 2] [--quick]

Scenarios (each trial draws a fresh seeded problem; every method sees the very same data):
  opencv-test   OpenCV's own calibrateHandEye accuracy-test generator: 10 poses, noise
                N(0, 0.002 rad) / N(0, 5 mm) on target2cam and N(0, 0.001 rad) / N(0, 1 mm) on
                gripper2base.
  one-bad-pose  10 careful poses, camera pose noise 0.1 deg / 0.5 mm, one view 5 deg / 50 mm off
                (a mis-detected board); also counts how often our default names the bad pose.
  small-motion  10 poses whose consecutive motions rotate only 1-8 degrees.
  pose-noise    camera pose noise (deg, mm per axis) in {0, (0.1, 0.5), (0.5, 2), (1, 5)},
                robot poses exact, n in {5, 10, 20, 40}.
  pixel-noise   corner pixel noise {0.2, 0.5, 1.0} px (poses from solvePnP, as on a real rig)
                with robot noise 0.02 deg / 0.1 mm, n in {5, 10, 20, 40}.
Rows with corner pixels also run ``calibrate_from_corners``, the default for captures with
corners (its noise model chosen by held-out views; see benchmarks/handeye_real.py).
Each row: median and 95th percentile of the rotation error (deg) and translation error (mm)
of X against the truth, and the median CPU time per call (ms; process CPU time, so other load
on the machine does not skew the comparison with OpenCV).

On the pose-noise rows two more rows show the statistical limit:
  oracle ML    the exact maximum-likelihood fit that knows the truth's noise model: camera pose
               noise isotropic with the row's true standard deviations, robot poses exact,
               started at the true X and Y, no robust stage
               (``refine_hand_eye(..., X0=X_true, Y0=Y_true, sigma=true, robust=False)``);
  Cramer-Rao bound  the errors of an efficient unbiased estimator, drawn (200 per trial) from
               the bound's covariance at the true poses (``solutions.mle.cramer_rao_covariance``).

Targets on the camera-pose-noise rows (issue 17): the default's median rotation and translation
errors are each at most 1.05 x the oracle's and at least 5 % below OpenCV's best (the best of
its seven methods for that number); where the oracle itself is at least 20 % below OpenCV's
best, the default is at least 15 % below. Each ratio is printed with a paired-bootstrap 95 %
interval (trials resampled, the same trials for both methods), and each row's verdict says
whether a miss is real (the whole interval is past the target) or within sampling noise.
Pixel-noise rows keep the earlier target (15 % better than OpenCV's best). Speed: on 20 poses
the default takes at most 5 x OpenCV PARK's time on every row. The table's ms/call is one call
per trial, in among the other methods; the speed verdict is measured apart, because single
calls swing by +-20 % with the machine's state (PARK alone moved between 3.1 and 4.9 ms from
row to row in one run): on each trial the default and PARK run alternately SPEED_REPEATS
times, each keeps its fastest run, and the row's ratio is the median over trials of
default / PARK, with a bootstrap 95 % interval over the trials.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

# One thread per worker process: trials already run in parallel, and a call's CPU time must
# not include BLAS or OpenCV helper threads spinning (they made OpenCV's ANDREFF look 40x slower).
for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import cv2  # noqa: E402 - after the thread settings above
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from autograder.synthetic import NoiseModel, make_hand_eye, make_opencv_scenario  # noqa: E402
from robots import geometry as geo  # noqa: E402
from solutions.catalog import DEFAULT_METHOD, hand_eye_methods  # noqa: E402
from solutions.mle import (  # noqa: E402
    calibrate_from_corners,
    cramer_rao_covariance,
    refine_hand_eye,
)

MOUNTS = ("eye_in_hand", "eye_to_hand")
BOUND_LABEL = "Cramer-Rao bound (efficient estimator)"
ORACLE_LABEL = "oracle ML (true noise, started at the truth)"
CORNER_LABEL = "calibrate_from_corners (corner default)"
BOUND_DRAWS = 200
BOOTSTRAP = 2000
ORACLE_SLACK = 1.05
OPENCV_GAIN = 0.95
OPENCV_GAIN_WHERE_POSSIBLE = 0.85
SPEED_LIMIT = 5.0
SPEED_REPEATS = 5
SPEED_KEY = "speed: fastest of alternating runs (default ms, PARK ms)"


@dataclass(frozen=True)
class Scenario:
    name: str
    mount: str
    n_poses: int
    kind: str  # "opencv" or "careful"
    noise: NoiseModel | None = None
    motion_deg: tuple[float, float] = (15.0, 45.0)

    def problem(self, seed: int):
        if self.kind == "opencv":
            return make_opencv_scenario(seed, self.mount, n_poses=self.n_poses)
        return make_hand_eye(seed, self.mount, n_poses=self.n_poses, noise=self.noise,
                             motion_deg=self.motion_deg)


def scenarios(quick: bool) -> list[Scenario]:
    ns = (10, 20) if quick else (5, 10, 20, 40)
    out = []
    for mount in MOUNTS:
        out.append(Scenario("opencv-test", mount, 10, "opencv"))
        out.append(Scenario("one-bad-pose", mount, 10, "careful",
                            NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5, n_outliers=1)))
        out.append(Scenario("small-motion", mount, 10, "careful",
                            NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5), motion_deg=(1.0, 8.0)))
    pose_levels = ((0.0, 0.0), (0.1, 0.5), (0.5, 2.0), (1.0, 5.0))
    pixel_levels = (0.2, 0.5, 1.0)
    for mount in MOUNTS:
        for deg, mm in pose_levels:
            for n in ns:
                out.append(Scenario(f"pose-noise {deg:g} deg/{mm:g} mm", mount, n, "careful",
                                    NoiseModel(cam_rot_deg=deg, cam_trans_mm=mm)))
        for px in pixel_levels:
            for n in ns:
                out.append(Scenario(f"pixel-noise {px:g} px", mount, n, "careful",
                                    NoiseModel(pixel_px=px, robot_rot_deg=0.02, robot_trans_mm=0.1)))
    return out


def _pose_noise_only(scenario: Scenario) -> bool:
    """Whether the only noise is isotropic camera pose noise (the bound's and oracle's model)."""
    noise = scenario.noise
    return not (scenario.kind != "careful" or noise is None or noise.cam_rot_deg <= 0
                or noise.cam_trans_mm <= 0 or noise.pixel_px or noise.robot_rot_deg
                or noise.robot_trans_mm or noise.n_outliers)


def oracle_fit(scenario: Scenario, problem):
    """X of the exact ML fit given the true noise model, started at the truth (or None)."""
    if not _pose_noise_only(scenario):
        return None
    noise = scenario.noise
    return refine_hand_eye(problem.base_T_flange, problem.cam_T_target, problem.mount,
                           X0=problem.X_true, Y0=problem.Y_true, robust=False,
                           sigma=(np.radians(noise.cam_rot_deg), noise.cam_trans_mm / 1000)).X


def bound_errors(scenario: Scenario, problem, seed: int):
    """Rotation (deg) and translation (mm) errors of an efficient unbiased estimator on this
    problem, BOUND_DRAWS draws from the Cramer-Rao covariance at the truth; None unless the
    only noise is isotropic camera pose noise (the model the bound is computed for)."""
    noise = scenario.noise
    if not _pose_noise_only(scenario):
        return None
    cov = cramer_rao_covariance(problem.X_true, problem.Y_true, problem.true_base_T_flange,
                                problem.mount, rotation_sigma_rad=np.radians(noise.cam_rot_deg),
                                translation_sigma_m=noise.cam_trans_mm / 1000)
    draws = np.random.default_rng(seed).multivariate_normal(np.zeros(6), cov, size=BOUND_DRAWS)
    return (np.degrees(np.linalg.norm(draws[:, :3], axis=1)),
            1000 * np.linalg.norm(draws[:, 3:], axis=1))


def run_trial(args):
    """Per method: errors (deg, mm), time (ms), and the poses it flagged with the true outliers."""
    scenario, seed = args
    # Dropping sub-degree motions is expected on OpenCV's generator; the warning is for users.
    warnings.simplefilter("ignore", UserWarning)
    # OpenCV logs "calibrateHandEyeTsai failed" and returns identity; the table shows the error.
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    cv2.setNumThreads(1)
    problem = scenario.problem(seed)
    results = {}
    methods = hand_eye_methods(problem, include_opencv=True)
    if problem.pixels is not None and problem.noise.pixel_px > 0:
        # The default for captures with corners (benchmarks/handeye_real.py): its noise model
        # chosen by held-out views, here on data whose noise model is the textbook one.
        methods.append((CORNER_LABEL, lambda: calibrate_from_corners(
            problem.board.object_points(), problem.pixels, problem.camera.K, problem.camera.dist,
            problem.base_T_flange, problem.mount, problem.cam_T_target)[0]))
    for label, solve in methods:
        start = time.process_time()
        try:
            out = solve()
        except Exception:  # noqa: BLE001 - a refusal is recorded as a failure of that method
            results[label] = (np.nan, np.nan, np.nan, None)
            continue
        ms = (time.process_time() - start) * 1000
        X = out.X if hasattr(out, "X") else out
        flagged = getattr(out, "outlier_pose_indices", None)
        results[label] = (geo.rotation_error_deg(X, problem.X_true),
                          geo.translation_error(X, problem.X_true) * 1000, ms,
                          None if flagged is None else (tuple(flagged), problem.outlier_indices))
    if scenario.n_poses == 20:
        solvers = dict(methods)
        results[SPEED_KEY] = _fastest_runs(solvers[DEFAULT_METHOD], solvers["opencv PARK"])
    start = time.process_time()
    X_oracle = oracle_fit(scenario, problem)
    if X_oracle is not None:
        results[ORACLE_LABEL] = (geo.rotation_error_deg(X_oracle, problem.X_true),
                                 geo.translation_error(X_oracle, problem.X_true) * 1000,
                                 (time.process_time() - start) * 1000, None)
    bound = bound_errors(scenario, problem, seed)
    if bound is not None:
        results[BOUND_LABEL] = (*bound, np.nan, None)
    return results


def _fastest_runs(*solvers) -> tuple[float, ...]:
    """Each solver's fastest of SPEED_REPEATS runs (CPU ms), the solvers taking turns, so a
    change in the machine's speed weighs on all of them alike."""
    best = [np.inf] * len(solvers)
    for _ in range(SPEED_REPEATS):
        for k, solve in enumerate(solvers):
            start = time.process_time()
            try:
                solve()
            except Exception:  # noqa: BLE001 - a refusal costs its time like an answer
                pass
            best[k] = min(best[k], (time.process_time() - start) * 1000)
    return tuple(best)


def speed_target(scenario: Scenario, trials: list[dict], file=sys.stdout) -> list[str]:
    """The speed target on a 20-pose row, printed with its bootstrap interval; returns the
    line of a miss (real or within noise)."""
    if SPEED_KEY not in trials[0]:
        return []
    ms = np.array([t[SPEED_KEY] for t in trials], float)
    ratios = ms[:, 0] / ms[:, 1]
    idx = np.random.default_rng(2).integers(0, len(ratios), size=(BOOTSTRAP, len(ratios)))
    lo, hi = np.percentile(np.median(ratios[idx], axis=1), [2.5, 97.5])
    ratio = float(np.median(ratios))
    verdict = _verdict(ratio, lo, hi, SPEED_LIMIT)
    text = (f"default/PARK {ratio:.2f} [{lo:.2f}, {hi:.2f}] <= {SPEED_LIMIT:g} (fastest of "
            f"{SPEED_REPEATS} alternating runs per trial: median {np.median(ms[:, 0]):.2f} ms "
            f"against {np.median(ms[:, 1]):.2f} ms)")
    print(f"- speed: {text}: {verdict}", file=file)
    if verdict.startswith("met"):
        return []
    return [f"speed {scenario.name} {scenario.mount} n=20: {text}: {verdict}"]


def summarise(trials: list[dict]) -> list[tuple]:
    rows = []
    for label in trials[0]:
        if label == SPEED_KEY:
            continue
        # np.hstack: the bound row holds many draws per trial, a method one error per trial.
        r = np.hstack([t[label][0] for t in trials]).astype(float)
        t = np.hstack([t[label][1] for t in trials]).astype(float)
        ms = np.array([tr[label][2] for tr in trials], float)
        flags = [tr[label][3] for tr in trials if tr[label][3] is not None]
        failed = int(np.isnan(r).sum())
        ok = ~np.isnan(r)
        if not ok.any():
            rows.append((label, np.nan, np.nan, np.nan, np.nan, np.nan, failed, flags))
            continue
        timed = ms[~np.isnan(ms)]
        rows.append((label, np.median(r[ok]), np.percentile(r[ok], 95), np.median(t[ok]),
                     np.percentile(t[ok], 95), np.median(timed) if timed.size else np.nan,
                     failed, flags))
    return rows


def print_table(scenario: Scenario, rows, trials: int, file=sys.stdout):
    print(f"\n### {scenario.name}, {scenario.mount}, n={scenario.n_poses}, {trials} trials", file=file)
    print("| method | rot median (deg) | rot p95 (deg) | trans median (mm) | trans p95 (mm) "
          "| ms/call | failed |", file=file)
    print("|---|---:|---:|---:|---:|---:|---:|", file=file)
    for label, rm, rp, tm, tp, ms, failed, flags in rows:
        note = ""
        with_outliers = [(got, true) for got, true in flags if true]
        if with_outliers:
            named = sum(set(true) <= set(got) for got, true in with_outliers)
            note = f" (bad pose named in {named}/{len(with_outliers)})"
        false_flags = sum(bool(set(got) - set(true)) for got, true in flags)
        if false_flags:
            note += f" (good poses flagged in {false_flags}/{len(flags)})"
        time_ms = "-" if np.isnan(ms) else f"{ms:.2f}"
        print(f"| {label}{note} | {rm:.4f} | {rp:.4f} | {tm:.3f} | {tp:.3f} | {time_ms} "
              f"| {failed} |", file=file)


def paired_ratio(ours: np.ndarray, theirs: np.ndarray, rng, draws: int = BOOTSTRAP):
    """median(ours) / median(theirs) and its paired-bootstrap 95 % interval (same trials)."""
    idx = rng.integers(0, len(ours), size=(draws, len(ours)))
    boot = np.median(ours[idx], axis=1) / np.median(theirs[idx], axis=1)
    return float(np.median(ours) / np.median(theirs)), *np.percentile(boot, [2.5, 97.5])


def _verdict(ratio: float, lo: float, hi: float, limit: float) -> str:
    if ratio <= limit:
        return "met" if hi <= limit else "met (within noise)"
    return "MISSED (real: whole interval above)" if lo > limit else "missed (within noise)"


def limit_targets(scenario: Scenario, trials: list[dict], file=sys.stdout) -> list[str]:
    """Issue 17's camera-pose-noise targets, printed with paired-bootstrap intervals; returns
    the lines of the targets missed (real or within noise)."""
    if not _pose_noise_only(scenario) or ORACLE_LABEL not in trials[0]:
        return []
    rng = np.random.default_rng(1)

    def errors(label, k):
        return np.array([t[label][k] for t in trials], float)

    opencv = [lab for lab in trials[0] if lab.startswith("opencv")]
    missed = []
    print(f"\nTargets, {len(trials)} paired trials (ratio of medians [paired-bootstrap 95 % CI]):",
          file=file)
    for k, what in ((0, "rotation"), (1, "translation")):
        ours, oracle = errors(DEFAULT_METHOD, k), errors(ORACLE_LABEL, k)
        best = min(opencv, key=lambda lab: np.nanmedian(errors(lab, k)))
        theirs = np.nan_to_num(errors(best, k), nan=np.inf)
        to_oracle = paired_ratio(ours, oracle, rng)
        to_opencv = paired_ratio(ours, theirs, rng)
        oracle_gain = float(np.median(oracle) / np.median(theirs))
        gain = OPENCV_GAIN_WHERE_POSSIBLE if oracle_gain <= 0.80 else OPENCV_GAIN
        checks = ((f"default/oracle {to_oracle[0]:.3f} [{to_oracle[1]:.3f}, {to_oracle[2]:.3f}]"
                   f" <= {ORACLE_SLACK:.2f}", _verdict(*to_oracle, ORACLE_SLACK)),
                  (f"default/{best} {to_opencv[0]:.3f} [{to_opencv[1]:.3f}, {to_opencv[2]:.3f}]"
                   f" <= {gain:.2f} (oracle/{best} {oracle_gain:.3f})",
                   _verdict(*to_opencv, gain)))
        for text, verdict in checks:
            print(f"- {what}: {text}: {verdict}", file=file)
            if not verdict.startswith("met"):
                missed.append(f"{scenario.name} {scenario.mount} n={scenario.n_poses} {what}: "
                              f"{text}: {verdict}")
    return missed


def check_targets(scenario: Scenario, rows) -> list[str]:
    """The accuracy targets other than the pose-noise limit targets; returns the ones missed."""
    by_label = {r[0]: r for r in rows}
    ours = by_label[DEFAULT_METHOD]
    opencv = [r for r in rows if r[0].startswith("opencv")]
    best_rot = min(r[1] for r in opencv)
    best_trans = min(r[3] for r in opencv)
    missed = []
    noisy = scenario.name.startswith("pixel-noise") and best_rot > 1e-6
    if noisy and not (ours[1] <= 0.85 * best_rot and ours[3] <= 0.85 * best_trans):
        line = (f"{scenario.name} {scenario.mount} n={scenario.n_poses}: default "
                f"{ours[1]:.4f} deg / {ours[3]:.3f} mm vs best OpenCV "
                f"{best_rot:.4f} deg / {best_trans:.3f} mm (target: 15 % better)")
        bound = by_label.get(BOUND_LABEL)
        if bound is not None:
            line += (f"; Cramer-Rao bound {bound[1]:.4f} deg / {bound[3]:.3f} mm = "
                     f"{100 * (1 - bound[1] / best_rot):.0f} % / "
                     f"{100 * (1 - bound[3] / best_trans):.0f} % below OpenCV's best")
        missed.append(line)
    beats_opencv = (ours[1] < best_rot and ours[2] < min(r[2] for r in opencv)
                    and ours[3] < best_trans and ours[4] < min(r[4] for r in opencv))
    if scenario.name == "opencv-test" and not beats_opencv:
        missed.append(f"opencv-test {scenario.mount}: default does not beat OpenCV's best")
    if scenario.name == "one-bad-pose" and not (ours[1] <= 0.3 and ours[3] <= 20):
        missed.append(f"one-bad-pose {scenario.mount}: default median {ours[1]:.3f} deg / "
                      f"{ours[3]:.2f} mm (target <= 0.3 deg / 20 mm)")
    return missed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--quick", action="store_true", help="n in {10, 20} and 20 trials")
    parser.add_argument("--only", default="", help="run scenarios whose name contains this")
    parser.add_argument("--poses", type=int, default=0,
                        help="run only the scenarios with this many poses (default: all)")
    args = parser.parse_args(argv)
    trials = 20 if args.quick and args.trials == 100 else args.trials

    print(f"# Hand-eye accuracy: {trials} seeded trials per scenario, default method "
          f"'{DEFAULT_METHOD}'")
    missed = []
    started = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for scenario in scenarios(args.quick):
            if (args.only and args.only not in scenario.name
                    or args.poses and scenario.n_poses != args.poses):
                continue
            results = list(pool.map(run_trial, [(scenario, seed) for seed in range(trials)]))
            rows = summarise(results)
            print_table(scenario, rows, trials)
            missed += limit_targets(scenario, results)
            missed += speed_target(scenario, results)
            missed += check_targets(scenario, rows)
            sys.stdout.flush()
    print(f"\nTotal time {time.perf_counter() - started:.0f} s with {args.workers} workers.")
    if missed:
        print("\nTargets missed:")
        for line in missed:
            print(f"- {line}")
    else:
        print("\nAll accuracy targets met.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
