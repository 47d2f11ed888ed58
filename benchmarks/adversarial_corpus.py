"""The adversarial corpus in every mode the suite repeats it in: the suite's slices beside
the full corpus, in one run.

``make test`` grades every lab 0 case once, forked from the template
(tests/test_corpus_batch_*.py), and repeats only slices of the corpus, the cases each
repetition can tell apart (tests/course_kit.full_corpus): started cold
(``REGRADED_COLD``), as an unprivileged user (tests/test_unprivileged.py's
``SANDBOX_CASES``), on labs 3, 4 and 5 (tests/test_adversarial_labs.py's ``LAB_SLICE``), on
a Dask cluster (tests/test_cluster.py's ``CLUSTER_CASES``). This script runs those same
tests twice, each test in a pytest process of its own: as the suite runs them, then with
``COBOTLAB_FULL_CORPUS=1``, where every case is repeated in every mode (each lab 0 case
cold, every notebook-layer case as the user, every case on every lab, ``reply_flood`` on
the cluster). A case that fails only in the full run is a hole the slice does not cover:
add it to the slice. (The cases that only burn their limits, ``BURNS_ITS_LIMITS``, are
graded at the short limits in both runs: what they test is that each loop is stopped.)
The row ``practice`` is a slice of the same kind, not of the corpus: tests/test_answer_free.py
compares check() on the practice file with the generators' scoring for every variant of the
fairness table on one public seed each in a suite run (taken in turn; the solution on every
seed), and every variant on every public seed in the full run.
docs/benchmarks/adversarial_corpus.md has a run's table.

Prints one row per test: its outcome, wall clock and machine CPU seconds (all the
machine's busy time while it ran, read from /proc/stat: run it on an otherwise idle
machine) for the slice and for the full corpus. With ``--repeat N`` each is run N times and
the CPU the slice saves is given with a bootstrap 95 % interval.

    .venv/bin/python benchmarks/adversarial_corpus.py             # ~14 min on 2 cores, as root
    .venv/bin/python benchmarks/adversarial_corpus.py --only full --tests batch_b
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TESTS = {
    "batch_a": "tests/test_corpus_batch_a.py",
    "batch_b": "tests/test_corpus_batch_b.py",
    "as_user": "tests/test_unprivileged.py::"
               "test_the_corpus_grades_as_for_root_under_bubblewraps_user_namespace",
    "lab3": "tests/test_adversarial_labs.py::"
            "test_adversarial_corpus_scores_no_more_than_the_blank[lab3_servoing]",
    "lab4": "tests/test_adversarial_labs.py::"
            "test_adversarial_corpus_scores_no_more_than_the_blank[lab4_stereo]",
    "lab5": "tests/test_adversarial_labs.py::"
            "test_adversarial_corpus_scores_no_more_than_the_blank[lab5_depth]",
    "cluster": "tests/test_cluster.py::"
               "test_a_tls_cluster_grades_as_locally_even_when_a_worker_dies",
    # not the adversarial corpus, but a slice of the same kind: check() on the practice
    # file against the generators, every variant of the fairness table on one public seed
    # in a suite run, on every public seed here
    "practice": "tests/test_answer_free.py::test_check_on_practice_data_gives_the_same_table",
}
BOOTSTRAP = 2000


def _busy_s() -> float:
    """CPU seconds the whole machine has been busy since boot (user, nice, system, irq)."""
    with open("/proc/stat") as f:
        fields = [int(v) for v in f.readline().split()[1:9]]
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def run_one(test: str, full: bool) -> dict:
    """One pytest process for ``test``; its outcome, wall clock and machine CPU seconds."""
    env = {k: v for k, v in os.environ.items() if k != "COBOTLAB_FULL_CORPUS"}
    if full:
        env["COBOTLAB_FULL_CORPUS"] = "1"
    busy, started = _busy_s(), time.monotonic()
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           test], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=3600, check=False)
    summary = (done.stdout.strip().splitlines() or ["no output"])[-1]
    return {"ok": done.returncode == 0, "summary": summary,
            "wall_s": time.monotonic() - started, "cpu_s": _busy_s() - busy,
            "tail": "" if done.returncode == 0 else done.stdout[-2000:] + done.stderr[-1000:]}


def _interval(saved: np.ndarray, rng: np.random.Generator) -> str:
    if len(saved) < 2:
        return f"{saved.mean():.0f}"
    means = rng.choice(saved, size=(BOOTSTRAP, len(saved))).mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return f"{saved.mean():.0f} [{lo:.0f}, {hi:.0f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tests", default=",".join(TESTS),
                        help=f"comma-separated, of {', '.join(TESTS)}")
    parser.add_argument("--only", choices=("slice", "full", "both"), default="both")
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    names = [n for n in args.tests.split(",") if n]
    unknown = sorted(set(names) - set(TESTS))
    if unknown:
        parser.error(f"unknown tests {unknown}: choose from {', '.join(TESTS)}")
    modes = {"slice": [False], "full": [True], "both": [False, True]}[args.only]
    results: dict[tuple[str, bool], list[dict]] = {}
    for _ in range(args.repeat):
        for name in names:
            for full in modes:
                result = run_one(TESTS[name], full)
                results.setdefault((name, full), []).append(result)
                print(f"{name:8s} {'full' if full else 'slice':5s} {result['summary']} "
                      f"({result['wall_s']:.0f} s, {result['cpu_s']:.0f} CPU-s)", flush=True)
                if not result["ok"]:
                    print(result["tail"], flush=True)
    rng = np.random.default_rng(0)
    print("\n| test | slice: outcome, wall s, CPU s | full corpus: outcome, wall s, CPU s "
          "| CPU s the slice saves (95 % CI) |\n|---|---|---|---|")
    failed = False
    for name in names:
        cells = []
        for full in (False, True):
            runs = results.get((name, full), [])
            failed |= any(not r["ok"] for r in runs)
            cells.append("-" if not runs else (
                f"{sum(r['ok'] for r in runs)}/{len(runs)} passed, "
                f"{np.mean([r['wall_s'] for r in runs]):.0f}, "
                f"{np.mean([r['cpu_s'] for r in runs]):.0f}"))
        both = [results.get((name, f), []) for f in (False, True)]
        saved = "-"
        if all(both):
            n = min(len(both[0]), len(both[1]))
            saved = _interval(np.array([both[1][i]["cpu_s"] - both[0][i]["cpu_s"]
                                        for i in range(n)]), rng)
        print(f"| {name} | {cells[0]} | {cells[1]} | {saved} |")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
