"""Lab 2's hidden solver problems: how their conditioning sets the tolerances, before and after
the redraw of ill-conditioned motion sets (issue 52).

``tsai_lenz`` and ``axes_ls`` share one generator (autograder/specs/lab2_handeye.py). Each
problem's full-credit tolerance is its pose noise times a *gain* of its motions' geometry:
``rotation_gain = max(1 / sqrt(lambda_min(H)), AXES_K / ROT_K / sqrt(lambda_min(S)))`` (rad of
R_X per rad of noise) and ``translation_gain = 1 / sqrt(lambda_min(G))`` (see the spec's
docstring for H, S, G). A set of motions whose axes are nearly parallel (or coplanar, for the
axes fit) or whose angles are small has a small lambda_min: the tolerance swells until a
constant answer, the identity, is within it.

On the same random streams (stream k: ``numpy.random.default_rng([SEED, k])``) this prints,
side by side,

* ``as drawn``: :func:`draw_solver_problem`, every problem kept (the baseline);
* ``graded``: ``_trial_solver``, the hidden problems now, ill-conditioned sets drawn again;

per column the 50th, 90th, 99th, 99.9th percentile and the maximum, with bootstrap 95 %
intervals on the percentiles, of: both tolerances, both gains, the condition number
lambda_max / lambda_min of the stacked rotation system (H) and translation system (G), the
smallest motion angle and the largest angle between a motion's axis and the mean axis
direction (how spread the axes are). Then the identity pose's credit per problem (the
grader's own scoring), the reference solvers' error / tolerance, and where the tail comes
from: the same quantities on the 1 % of problems with the largest rotation tolerance.

    .venv/bin/python benchmarks/lab2_conditioning.py --problems 300     # ~1 min, a check
    .venv/bin/python benchmarks/lab2_conditioning.py --problems 2000    # the issue's table
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: the machine is shared

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from autograder import checks  # noqa: E402
from autograder.outcomes import TrialOutcome  # noqa: E402
from autograder.specs import lab2_handeye as lab2  # noqa: E402
from robots import geometry as geo  # noqa: E402
from solutions import handeye as he  # noqa: E402

SEED = 52
BOOTSTRAP = 1000
PERCENTILES = (50.0, 90.0, 99.0, 99.9)


def _matrices(base_T_flange: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """(H, G, the consecutive motions' rotation vectors) of a problem's robot poses."""
    H, G, alphas = np.zeros((3, 3)), np.zeros((3, 3)), []
    for i in range(len(base_T_flange) - 1):
        motion = geo.invert(base_T_flange[i]) @ base_T_flange[i + 1]
        R, alpha = motion[:3, :3], geo.rotvec_from_pose(motion)[0]
        H += float(alpha @ alpha) * np.eye(3) - np.outer(alpha, alpha)
        G += (R - np.eye(3)).T @ (R - np.eye(3))
        alphas.append(alpha)
    return H, G, alphas


def _axis_spread_deg(alphas: list[np.ndarray]) -> float:
    """The largest angle between a motion's axis (sign-free) and the principal axis direction:
    near 0 when every motion turns about nearly the same axis."""
    axes = np.array([a / np.linalg.norm(a) for a in alphas])
    principal = np.linalg.eigh(axes.T @ axes)[1][:, -1]
    return float(np.degrees(np.max(np.arccos(np.clip(np.abs(axes @ principal), 0, 1)))))


def _identity_credit(trial) -> float:
    """Share of the function's points the identity pose earns on this one problem."""
    result = checks.score_function(lab2.TSAI_LENZ, [trial], [TrialOutcome(value=np.eye(4))],
                                   hints=False)
    return result.points / result.max_points


def _reference_margin(trial) -> float:
    """The reference solvers' largest error / tolerance on the problem (below 1: full credit)."""
    worst = 0.0
    for solve in (he.solve_tsai, he.solve_axes_ls):
        X = solve(*trial.args)
        worst = max(worst,
                    float(geo.rotation_error_deg(X, trial.truth)) / trial.tol["rotation"],
                    1000.0 * float(np.linalg.norm(X[:3, 3] - trial.truth[:3, 3]))
                    / trial.tol["translation"])
    return worst


def measure(trial, problem) -> dict[str, float]:
    """Every column of the table for one solver problem."""
    H, G, alphas = _matrices(problem.base_T_flange)
    info = lab2.motion_information(problem.base_T_flange)
    eig_h, eig_g = np.linalg.eigvalsh(H), np.linalg.eigvalsh(G)
    return {
        "rotation tol (deg)": trial.tol["rotation"],
        "translation tol (mm)": trial.tol["translation"],
        "rotation gain": info.rotation_gain,
        "translation gain": info.translation_gain,
        "cond H (rotation)": float(eig_h[-1] / max(eig_h[0], 1e-300)),
        "cond G (translation)": float(eig_g[-1] / max(eig_g[0], 1e-300)),
        "smallest motion (deg)": float(min(np.degrees(np.linalg.norm(a)) for a in alphas)),
        "axis spread (deg)": _axis_spread_deg(alphas),
        "X angle (deg)": float(geo.rotation_angle_deg(trial.truth)),
        "X angle / rot tol": float(geo.rotation_angle_deg(trial.truth)) / trial.tol["rotation"],
        "identity credit": _identity_credit(trial),
        "reference err / tol": _reference_margin(trial),
    }


def graded_problem(rng) -> tuple:
    """``_trial_solver``'s loop, keeping the problem for the columns and counting redraws."""
    drawn = 0
    while True:
        trial, problem = lab2.draw_solver_problem(rng)
        drawn += 1
        if lab2.tests_the_solver(trial, problem):
            return trial, problem, drawn


def _percentile_row(values: np.ndarray, rng) -> list[str]:
    boot = values[rng.integers(0, len(values), size=(BOOTSTRAP, len(values)))]
    cells = []
    for q in PERCENTILES:
        low, high = np.percentile(np.percentile(boot, q, axis=1), [2.5, 97.5])
        cells.append(f"{np.percentile(values, q):.3g} [{low:.3g}, {high:.3g}]")
    return cells + [f"{values.max():.3g}"]


def print_table(title: str, columns: dict[str, dict[str, np.ndarray]], out=sys.stdout) -> None:
    rng = np.random.default_rng(0)
    print(f"\n### {title}", file=out)
    head = " | ".join(f"p{q:g} [95 % CI]" for q in PERCENTILES)
    print(f"| quantity | set | n | {head} | max |", file=out)
    print("|---|---|---:|" + "---:|" * (len(PERCENTILES) + 1), file=out)
    names = next(iter(columns.values())).keys()
    for name in names:
        for label, cols in columns.items():
            values = cols[name]
            print(f"| {name} | {label} | {len(values)} | "
                  + " | ".join(_percentile_row(values, rng)) + " |", file=out)


def _stack(rows: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.array([r[k] for r in rows]) for k in rows[0]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problems", type=int, default=2000)
    args = parser.parse_args(argv)
    started = time.process_time()
    before, after, drawn = [], [], 0
    for k in range(args.problems):
        trial, problem = lab2.draw_solver_problem(np.random.default_rng([SEED, k]))
        before.append(measure(trial, problem))
        trial, problem, n = graded_problem(np.random.default_rng([SEED, k]))
        after.append(measure(trial, problem))
        drawn += n
    b, a = _stack(before), _stack(after)
    print(f"lab 2 solver problems: {args.problems} per set, seed {SEED}; graded: "
          f"{drawn - args.problems} of {drawn} drawn sets redrawn "
          f"({(drawn - args.problems) / drawn:.1%}); limits rotation gain <= "
          f"{lab2.MAX_ROTATION_GAIN}, translation gain <= {lab2.MAX_TRANSLATION_GAIN}, "
          f"X's angle >= {lab2.IDENTITY_CLEARANCE} x the rotation tolerance")
    print_table("all problems", {"as drawn": b, "graded": a})
    for label, cols in (("as drawn", b), ("graded", a)):
        credit = cols["identity credit"]
        print(f"{label}: identity earns credit on {np.count_nonzero(credit)} of {len(credit)} "
              f"problems (mean share {credit.mean():.2%}); reference worst err / tol "
              f"{cols['reference err / tol'].max():.3f}")
    cut = np.percentile(b["rotation tol (deg)"], 99)
    tail = [r for r in before if r["rotation tol (deg)"] >= cut]
    if len(tail) >= 2:
        print_table(f"where the tail comes from: the as-drawn problems with a rotation "
                    f"tolerance >= {cut:.3g} deg (top 1 %) against all",
                    {"top 1 %": _stack(tail), "all": b})
    print(f"\n{time.process_time() - started:.0f} CPU s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
