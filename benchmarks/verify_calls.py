"""`labs verify`'s reference calls: one round trip per problem against one per draw.

``cobotlab labs verify`` scores the lab's reference notebook in the grader's sandboxed worker
on thousands of hidden draws. Each draw has a dozen problems or more per function; since
issue 40 the runner sends a draw's problems in one request (``NotebookRunner(batch_calls=
True)``, the worker's ``calls`` request), where before it sent one request per problem.

For each draw, both ways run on the same problems in the same worker, in alternating order
(so neither always goes first); the table gives the seconds per draw (median, bootstrap 95 %
interval over draws), the paired ratio batched / single with its paired-bootstrap interval,
and whether every outcome was the same both ways (values equal, errors equal).

    .venv/bin/python benchmarks/verify_calls.py                      # lab 0, 300 draws
    .venv/bin/python benchmarks/verify_calls.py --labs lab0_frames,lab2_handeye --draws 100
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

from handeye_accuracy import paired_ratio  # noqa: E402
from handeye_real import bootstrap_stats  # noqa: E402

from autograder import checks, fairness  # noqa: E402
from autograder.pipeline.problems import problem_rng  # noqa: E402
from autograder.pipeline.worker import Limits  # noqa: E402
from autograder.registry import find_lab  # noqa: E402
from cobotlab.verify import SandboxedReference  # noqa: E402

SECRET = "verify-calls-benchmark"


def _same(a: checks.TrialOutcome, b: checks.TrialOutcome) -> bool:
    if (a.error, a.failure) != (b.error, b.failure):
        return False
    try:
        return bool(np.array_equal(np.asarray(a.value, dtype=float),
                                   np.asarray(b.value, dtype=float), equal_nan=True))
    except (TypeError, ValueError):
        return repr(a.value) == repr(b.value)


def measure(lab: str, draws: int) -> list[dict]:
    """Per graded function of ``lab``: seconds per draw both ways, and outcomes compared."""
    import course_kit as kit

    notebook = find_lab(lab).notebook or kit.source_notebook(lab)
    reference = SandboxedReference(notebook, Limits())
    rows = []
    try:
        for spec in checks.SPECS[lab]:
            if spec.drive is not None:   # a closed loop calls back and forth: never batched
                continue
            seconds = {False: [], True: []}
            same = True
            for k in range(draws):
                rng = problem_rng(SECRET, None, lab, fairness.student_id(k), spec.name)
                trials = checks.make_trials(spec, rng)
                outcomes = {}
                for batch in ((False, True) if k % 2 == 0 else (True, False)):
                    reference.runner.batch_calls = batch
                    started = time.perf_counter()
                    outcomes[batch] = reference.many(spec, trials)
                    seconds[batch].append(time.perf_counter() - started)
                same = same and all(map(_same, outcomes[False], outcomes[True]))
            rows.append({"lab": lab, "function": spec.name, "problems": spec.n_trials,
                         "single": np.array(seconds[False]), "batched": np.array(seconds[True]),
                         "same": same})
    finally:
        reference.close()
    return rows


def _ms(x: np.ndarray, rng) -> str:
    (med, lo, hi), _, _ = bootstrap_stats(x * 1e3, rng)
    return f"{med:.1f} [{lo:.1f}, {hi:.1f}]"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--labs", default="lab0_frames")
    parser.add_argument("--draws", type=int, default=300)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    print("| function | problems | ms/draw, one call each | ms/draw, batched | "
          "batched / single [95 % CI] | same outcomes |\n|---|---|---|---|---|---|")
    all_same = True
    for lab in args.labs.split(","):
        for row in measure(lab, args.draws):
            ratio, lo, hi = paired_ratio(row["batched"], row["single"], rng)
            all_same &= row["same"]
            print(f"| {lab}.{row['function']} | {row['problems']} | {_ms(row['single'], rng)} "
                  f"| {_ms(row['batched'], rng)} | {ratio:.2f} [{lo:.2f}, {hi:.2f}] | "
                  f"{'yes' if row['same'] else 'NO'} |", flush=True)
    return 0 if all_same else 1


if __name__ == "__main__":
    sys.exit(main())
