"""What the input checks of issue 50 (Required 7) cost: the validated functions against their
versions before the checks, side by side in one run.

    .venv/bin/python benchmarks/validation_cost.py            # 40 blocks per arm
    .venv/bin/python benchmarks/validation_cost.py --quick    # 10 blocks per arm

"Before" is the code of commit ``BASELINE_COMMIT`` (the parent of the change), read with
``git show`` and loaded as separate modules, its own ``robots.geometry`` standing in for the
current one while the old servoing and perception modules load, so every baseline call runs
the old checks all the way down. "Now" is the working tree. Both arms get the same valid,
realistic inputs (a 200-pose stack as in a 20-view calibration's motions, 100 board points, a
4-point IBVS target, a 320 x 240 depth image) and must return the same numbers; the script
refuses to time them otherwise.

Timing: CPU seconds of this process (``time.process_time``: other processes on a shared
machine do not count; one BLAS thread), in blocks that alternate the arms (before-now, now-before, ...), each
block as many calls as fill about 10 ms. Per function the table gives the median time per
call of each arm, the added time and the ratio, with 95 % bootstrap intervals of the medians
(2000 resamples). Needs git and the project's history (a source checkout).
"""

from __future__ import annotations

import argparse
import functools
import os
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

# One BLAS thread: CPU time counts every thread's, and a pool spinning on 3 x 3 products
# (scipy's expm in integrate_twist) would bill its waiting to the call.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from robots import geometry as geo  # noqa: E402
from sim_backends.world import default_intrinsics  # noqa: E402
from solutions import perception as SP  # noqa: E402
from solutions import servoing as S  # noqa: E402

#: The commit before issue 50's checks: the baseline's source.
BASELINE_COMMIT = "6d4f97451a95973f683b9fdc4323742a83a2b3b4"


def _load_previous(path: str, name: str, swaps: dict) -> types.ModuleType:
    """The module at ``path`` as it was in ``BASELINE_COMMIT``, loaded under ``name`` with the
    modules in ``swaps`` (import name -> module) standing in for the current ones."""
    try:
        source = subprocess.run(["git", "show", f"{BASELINE_COMMIT}:{path}"], cwd=ROOT,
                                check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError) as err:
        raise SystemExit(f"cannot read {path} at {BASELINE_COMMIT[:10]} with git ({err}); this "
                         "benchmark needs a source checkout with its history") from None
    module = types.ModuleType(name)
    module.__file__ = str(ROOT / path)  # warn_caller attributes warnings by file location
    sys.modules[name] = module  # dataclasses look their module up there
    saved = {key: sys.modules.get(key) for key in swaps}
    sys.modules.update(swaps)
    try:
        exec(compile(source, f"{BASELINE_COMMIT[:10]}:{path}", "exec"), module.__dict__)
    finally:
        for key, value in saved.items():
            if value is None:
                sys.modules.pop(key, None)
            else:
                sys.modules[key] = value
    return module


def _previous_modules():
    old_geo = _load_previous("robots/geometry.py", "previous_geometry", {})
    swaps = {"robots.geometry": old_geo}
    return (old_geo, _load_previous("solutions/servoing.py", "previous_servoing", swaps),
            _load_previous("solutions/perception.py", "previous_perception", swaps))


def _flange_depth(intr) -> np.ndarray:
    """A 320 x 240 depth image (m) of a table 0.6 m away with a 63 mm flange face 0.35 m
    away, a little tilted: the scene of tests/test_perception.py's flange test."""
    from robots.perception import point_cloud

    rays = point_cloud(np.ones((intr.height, intr.width)), intr)
    normal = geo.rotation_from_rotvec([0.3, 0.2, 0.0])[:, 2]
    centre = np.array([0.02, -0.01, 0.35])
    t = (centre @ normal) / (rays @ normal)  # where each ray meets the flange's plane
    hit = rays * t[..., None]
    on_face = np.linalg.norm(hit - centre, axis=-1) < 0.0315
    return np.where(on_face, t * rays[..., 2], 0.6)


def _cases(old_geo, old_S, old_SP):
    """(name, call with the current modules, call with the previous ones) for each row."""
    rng = np.random.default_rng(50)
    T = geo.pose_from_rotvec([0.3, -0.2, 0.1], [0.1, 0.2, 0.5])
    T2 = geo.pose_from_rotvec([-0.1, 0.4, 0.2], [0.3, -0.1, 0.2])
    stack = np.stack([geo.pose_from_rotvec(rng.normal(0, 1, 3), rng.normal(0, 0.3, 3))
                      for _ in range(200)])
    stack2 = stack[::-1].copy()
    pts = rng.uniform(-0.2, 0.2, (100, 3))
    cam_pts = pts + [0.0, 0.0, 0.8]
    xy = rng.uniform(-0.3, 0.3, (1000, 2))
    plane = np.c_[xy, 0.6 + 0.1 * xy[:, 0] + rng.normal(0, 0.001, 1000)]  # a table, 1 mm noise
    twist = np.array([0.05, -0.02, 0.03, 0.2, -0.1, 0.3])
    features, desired = np.array([0.05, -0.02, 0.011, 0.3]), np.array([0.0, 0.0, 0.012, 0.1])
    intr = default_intrinsics(320, 240)
    depth = _flange_depth(intr)
    both = [
        ("invert(T), one pose", lambda g, s, p: g.invert(T)),
        ("invert(stack), 200 poses", lambda g, s, p: g.invert(stack)),
        ("compose(T, T2)", lambda g, s, p: g.compose(T, T2)),
        ("compose(stack, T), 200 poses", lambda g, s, p: g.compose(stack, T)),
        ("relative(T, T2)", lambda g, s, p: g.relative(T, T2)),
        ("transform_points(T, points), 100 points", lambda g, s, p: g.transform_points(T, pts)),
        ("make_pose(R, t)", lambda g, s, p: g.make_pose(T[:3, :3], T[:3, 3])),
        ("rotation_error_deg(T, T2)", lambda g, s, p: g.rotation_error_deg(T, T2)),
        ("rotation_error_deg(stack, stack2), 200", lambda g, s, p: g.rotation_error_deg(stack,
                                                                                         stack2)),
        ("translation_error(stack, stack2), 200", lambda g, s, p: g.translation_error(stack,
                                                                                       stack2)),
        ("rotvec_from_rotation(R)", lambda g, s, p: g.rotvec_from_rotation(T[:3, :3])),
        ("skew(v)", lambda g, s, p: g.skew(twist[:3])),
        ("integrate_twist(T, twist, 0.1)", lambda g, s, p: s.integrate_twist(T, twist, 0.1)),
        ("cam_twist_to_flange(twist, T)", lambda g, s, p: s.cam_twist_to_flange(twist, T)),
        ("decoupled_velocity", lambda g, s, p: s.decoupled_velocity(features, desired, 0.4)),
        ("normalised_projection, 100 points", lambda g, s, p: s.normalised_projection(cam_pts)),
        ("interaction_matrix, 100 points", lambda g, s, p: s.interaction_matrix(
            cam_pts[:, :2] / cam_pts[:, 2:], cam_pts[:, 2])),
        ("fit_plane_ransac, 1000 points", lambda g, s, p: p.fit_plane_ransac(
            plane, 0.002, np.random.default_rng(0))),
        ("fit_flange, 320 x 240", lambda g, s, p: p.fit_flange(depth, intr, radius_m=0.0315)),
    ]
    return [(name, functools.partial(call, geo, S, SP),
             functools.partial(call, old_geo, old_S, old_SP)) for name, call in both]


def _same(a, b) -> bool:
    if hasattr(a, "__dataclass_fields__"):
        return all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, tuple):
        return all(_same(x, y) for x, y in zip(a, b))
    return np.array_equal(np.asarray(a), np.asarray(b))


def _time(now, before, blocks: int, block_s: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """CPU seconds per call of each arm, ``blocks`` blocks each, alternating which goes
    first, each block as many calls as fill about ``block_s``."""
    clock = time.process_time
    t0, n = clock(), 0
    while clock() - t0 < block_s / 2:
        now()
        n += 1
    calls = max(1, 2 * n)
    times = {"now": [], "before": []}
    for b in range(blocks):
        order = (("before", before), ("now", now))
        for arm, fn in (order if b % 2 == 0 else order[::-1]):
            t0 = clock()
            for _ in range(calls):
                fn()
            times[arm].append((clock() - t0) / calls)
    return np.array(times["before"]), np.array(times["now"])


def _medians(x: np.ndarray, rng, n_boot: int = 2000) -> np.ndarray:
    return np.median(x[rng.integers(0, len(x), (n_boot, len(x)))], axis=1)


def _row(name: str, before: np.ndarray, now: np.ndarray, rng, scale: float) -> str:
    """A table row: the median time per call of each arm (seconds times ``scale``), the
    added time and the ratio, each with the 95 % bootstrap interval of its median."""
    b_before, b_now = _medians(before, rng), _medians(now, rng)

    def ci(b, factor=scale, digits=".3g"):
        lo, hi = np.percentile(b * factor, [2.5, 97.5])
        return f"[{lo:{digits}}, {hi:{digits}}]"

    m_before, m_now = np.median(before), np.median(now)
    return (f"| {name} | {m_before * scale:.3g} {ci(b_before)} | {m_now * scale:.3g} "
            f"{ci(b_now)} | {(m_now - m_before) * scale:+.2g} {ci(b_now - b_before, scale, '+.2g')}"
            f" | {m_now / m_before:.3f} {ci(b_now / b_before, 1.0, '.3f')} |")


def table(blocks: int) -> list[str]:
    old_geo, old_S, old_SP = _previous_modules()
    rng = np.random.default_rng(7)
    lines = [f"Before: {BASELINE_COMMIT[:10]} (before issue 50's checks); now: the working tree. "
             f"CPU time per call, median over {blocks} blocks per arm [95 % bootstrap interval].",
             "",
             "| function, input | before (us) | now (us) | added (us) | ratio |",
             "|---|---|---|---|---|"]
    for name, now, before in _cases(old_geo, old_S, old_SP):
        if not _same(now(), before()):
            raise SystemExit(f"{name}: the current and the previous versions disagree on a "
                             "valid input; the cost comparison would be meaningless")
        lines.append(_row(name, *_time(now, before, blocks), rng, 1e6))
    return lines


def _previous_checks(old_geo):
    """Put the previous fast-path check in place of the current ones (the previous code had
    no rotation check): the bodies as they were checked before, to time the checks inside
    whole solves, where the previous modules cannot stand in (a solver reaches the pose math
    through many modules). Returns the function that restores the current checks."""
    saved = geo._refuse_non_rigid, geo._refuse_non_rotation
    geo._refuse_non_rigid = old_geo._refuse_non_rigid
    geo._refuse_non_rotation = lambda R, label: None

    def restore():
        geo._refuse_non_rigid, geo._refuse_non_rotation = saved
    return restore


def _solver_cases():
    """Whole solves on valid data: a 20-view eye-in-hand calibration (1 mm / 0.1 deg noise)
    and 4 kinematic IBVS runs."""
    from solutions.handeye import calibrate_eye_in_hand

    rng = np.random.default_rng(51)
    X = geo.pose_from_rotvec([0.1, -0.2, 0.3], [0.05, 0.0, 0.08])
    base_T_target = geo.make_pose(t=[0.6, 0.0, 0.0])
    flanges, targets = [], []
    for _ in range(20):
        flange = geo.pose_from_rotvec(rng.normal(0, 0.4, 3), [0.4, 0.0, 0.4] + rng.normal(0, 0.1, 3))
        noise = geo.pose_from_rotvec(rng.normal(0, np.radians(0.1), 3), rng.normal(0, 0.001, 3))
        flanges.append(flange)
        targets.append(geo.invert(X) @ geo.invert(flange) @ base_T_target @ noise)
    flanges, targets = np.stack(flanges), np.stack(targets)
    goal = geo.make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5])
    square = np.array([[-.04, -.04, 0], [.04, -.04, 0], [.04, .04, 0], [-.04, .04, 0]])
    starts = [S.offset_start(goal, [0, 0, 0], 0.10, 20.0, np.random.default_rng(k))
              for k in range(4)]
    return [
        ("calibrate_eye_in_hand, 20 views (nonlinear)",
         lambda: calibrate_eye_in_hand(flanges, targets)),
        ("simulate_servo IBVS, 4 runs (kinematic)",
         lambda: [S.simulate_servo("ibvs", st, goal, square).final_pose for st in starts]),
    ]


def solver_table(blocks: int) -> list[str]:
    old_geo = _load_previous("robots/geometry.py", "previous_geometry", {})
    rng = np.random.default_rng(8)
    lines = ["", "Inside whole solves: the current code with the fast paths' checks as before "
             "(the previous _refuse_non_rigid, no _refuse_non_rotation) and as now.", "",
             "| solve | before (ms) | now (ms) | added (ms) | ratio |", "|---|---|---|---|---|"]
    for name, call in _solver_cases():
        restore = _previous_checks(old_geo)
        try:
            off = call()
        finally:
            restore()
        if not _same(off, call()):
            raise SystemExit(f"{name}: the checks changed a result on valid data")

        def switched(fn=call):
            restore = _previous_checks(old_geo)
            try:
                return fn()
            finally:
                restore()

        lines.append(_row(name, *_time(call, switched, blocks, block_s=0.0), rng, 1e3))
    return lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="10 blocks per arm instead of 40")
    args = ap.parse_args(argv)
    blocks = 10 if args.quick else 40
    print("\n".join(table(blocks) + solver_table(max(6, blocks // 2))))


if __name__ == "__main__":
    main()
