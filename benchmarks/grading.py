"""Time `cobotlab grade` on a class against plain `nbgrader autograde` on the same submissions.

Usage: python benchmarks/grading.py [--labs lab0_frames ...] [--students 100] [--workers 1 2]
                                    [--bootstrap 2000]

For each lab: a temporary course (`init_course`, `nbgrader generate_assignment`), and
``--students`` submissions made from the released notebook, each graded function holding the
reference solution (80 %) or left blank (20 %), seeded, so every configuration grades the very
same class. Then, side by side:

* plain nbgrader: one `nbgrader autograde LAB` over the whole class, as an instructor without
  cobotlab runs it (one process, no sandbox, no second grader);
* `grade_course(..., run_nbgrader=True)` with each ``--workers``: the whole pipeline (freeze,
  one sandboxed run of each notebook that serves both nbgrader's autograde and the isolated
  grader on hidden problems, recording);
* the previous pipeline, ``nbgrader_kernel=True`` (`cobotlab grade --nbgrader-kernel`), with
  1 worker: nbgrader's autograde with its own kernel in a sandboxed scratch course per
  student, then the isolated grader's own run of the notebook.

Time per submission is the run's wall clock over the class size; its 95 % interval comes from
a bootstrap over the per-submission completion gaps (the autograded notebooks' write times
for nbgrader, the progress callback for the pipeline). The speed-up of N workers is the
1-worker time over the N-worker time (bootstrap interval of the ratio). Targets: the pipeline
per submission no slower than plain nbgrader, and a speed-up near N (linear in workers) on a
machine with N idle cores. Share the machine with nothing else while it runs.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from autograder import checks
from autograder.course import LABS_DIR, grade_course, init_course


def _nbgrader(course: Path, *args: str) -> None:
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    env.pop("COBOTLAB_GRADING_SECRET", None)
    subprocess.run([sys.executable, "-m", "nbgrader", *args], cwd=course, env=env, check=True,
                   capture_output=True)


def _reference_cells(lab: str) -> dict[str, str]:
    """grade id -> the source notebook's solution cell, solution markers removed."""
    nb = json.loads((LABS_DIR / lab / f"{lab}.ipynb").read_text())
    names = {s.name for s in checks.SPECS[lab]}
    out = {}
    for cell in nb["cells"]:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if gid in names:
            out[gid] = "".join(line for line in "".join(cell["source"]).splitlines(True)
                               if "### BEGIN SOLUTION" not in line
                               and "### END SOLUTION" not in line)
    return out


def build_class(course: Path, lab: str, n: int, seed: int = 0) -> None:
    """Release ``lab`` in ``course`` and write ``n`` seeded submissions into submitted/."""
    _nbgrader(course, "generate_assignment", lab)
    released = json.loads((course / "release" / lab / f"{lab}.ipynb").read_text())
    reference = _reference_cells(lab)
    rng = np.random.default_rng(seed)
    for i in range(n):
        nb = json.loads(json.dumps(released))
        for cell in nb["cells"]:
            gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
            if gid in reference and rng.random() < 0.8:
                cell["source"] = reference[gid]
        out = course / "submitted" / f"s{i:03d}" / lab
        out.mkdir(parents=True)
        (out / f"{lab}.ipynb").write_text(json.dumps(nb))


def _copy_course(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    config = dst / "nbgrader_config.py"
    config.write_text(config.read_text().replace(str(src), str(dst)))
    return dst


class _CpuMeter:
    """CPU seconds (user + system) of this process and of every process below it, sampled
    from /proc every ``every_s`` (each process's last sample counts: sandboxes are killed,
    not waited for, so getrusage's children total would miss them). On a shared machine
    this is the cost that does not depend on what else runs."""

    def __init__(self, every_s: float = 0.25):
        self.every_s, self.seen, self._stop = every_s, {}, threading.Event()
        self._tick = os.sysconf("SC_CLK_TCK")

    def _sample(self) -> None:
        table = {}
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    with open(f"/proc/{entry}/stat", "rb") as f:
                        fields = f.read().rsplit(b")", 1)[1].split()
                except OSError:
                    continue
                table[int(entry)] = (int(fields[1]), fields[19], int(fields[11]) + int(fields[12]))
        me, frontier = os.getpid(), [os.getpid()]
        while frontier:
            parent = frontier.pop()
            for pid, (ppid, start, ticks) in table.items():
                if ppid == parent and pid != me:
                    key = (pid, start)
                    if key not in self.seen or ticks > self.seen[key]:
                        self.seen[key] = ticks
                    frontier.append(pid)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            self._sample()

    def __enter__(self):
        self._self0 = resource.getrusage(resource.RUSAGE_SELF)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        now = resource.getrusage(resource.RUSAGE_SELF)
        own = (now.ru_utime - self._self0.ru_utime) + (now.ru_stime - self._self0.ru_stime)
        self.cpu_s = own + sum(self.seen.values()) / self._tick


def time_plain_nbgrader(course: Path, lab: str) -> tuple[float, np.ndarray, float]:
    """(wall s, per-submission gaps s, CPU s) of one `nbgrader autograde LAB` over the class."""
    started = time.time()
    with _CpuMeter() as meter:
        _nbgrader(course, "autograde", lab, "--force")
    wall, cpu = time.time() - started, meter.cpu_s
    done = sorted(p.stat().st_mtime for p in (course / "autograded").glob(f"*/{lab}/{lab}.ipynb"))
    return wall, np.diff([started, *done]), cpu


def time_pipeline(course: Path, lab: str, workers: int, kernel: bool = False):
    """(wall s, per-submission gaps s, CPU s, rows, mean s of nbgrader's own share) of
    `grade_course` with nbgrader's cross-check (``kernel``: in nbgrader's own kernel)."""
    marks: list[float] = []
    started = time.time()
    with _CpuMeter() as meter:
        rows = grade_course(course, lab, workers=workers, run_nbgrader=True,
                            nbgrader_kernel=kernel, quiet=True,
                            progress=lambda done, total, sid: marks.append(time.time()) if done
                            else None)
    wall, cpu = time.time() - started, meter.cpu_s
    log = (course / ".cobotlab" / "last_run.log").read_text()
    nb = [float(x) for x in re.findall(r"nbgrader autograde: ([0-9.]+) s", log)]
    return wall, np.diff([started, *marks]), cpu, rows, float(np.mean(nb)) if nb else np.nan


def _boot_mean(gaps: np.ndarray, wall: float, rng, n: int) -> tuple[float, float]:
    """95 % interval of wall/N from resampled gaps (scaled so the point estimate is wall/N)."""
    scale = wall / gaps.sum() if gaps.sum() > 0 else 1.0
    means = rng.choice(gaps, size=(n, len(gaps))).mean(axis=1) * scale
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def _boot_ratio(a: np.ndarray, b: np.ndarray, rng, n: int) -> tuple[float, float]:
    ra = rng.choice(a, size=(n, len(a))).mean(axis=1)
    rb = rng.choice(b, size=(n, len(b))).mean(axis=1)
    ratio = ra / rb
    return float(np.percentile(ratio, 2.5)), float(np.percentile(ratio, 97.5))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labs", nargs="+", default=sorted(checks.SPECS))
    parser.add_argument("--students", type=int, default=100)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--bootstrap", type=int, default=2000)
    parser.add_argument("--no-previous", dest="previous", action="store_false",
                        help="skip the previous pipeline's row (nbgrader's own kernel)")
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    print(f"{args.students} submissions per lab; {os.cpu_count()} cores; load average "
          f"{os.getloadavg()[0]:.1f} at the start")
    header = (f"{'lab':<14} {'grader':<26} {'wall s':>8} {'s/submission [95% CI]':>26} "
              f"{'vs nbgrader':>12} {'speed-up [95% CI]':>22} {'CPU s/sub':>10}")
    lines = []
    for lab in args.labs:
        with tempfile.TemporaryDirectory(prefix="cobotlab-bench-") as tmp:
            base = init_course(Path(tmp) / "base")
            build_class(base, lab, args.students)
            plain_wall, plain_gaps, plain_cpu = time_plain_nbgrader(
                _copy_course(base, Path(tmp) / "plain"), lab)
            plain = plain_wall / args.students
            lo, hi = _boot_mean(plain_gaps, plain_wall, rng, args.bootstrap)
            lines.append(f"{lab:<14} {'plain nbgrader':<26} {plain_wall:>8.1f} "
                         f"{plain:>9.2f} [{lo:6.2f}, {hi:6.2f}] {'1.00x':>12} {'':>22} "
                         f"{plain_cpu / args.students:>10.1f}")
            first = None
            runs = [(w, False) for w in args.workers] + ([(1, True)] if args.previous else [])
            for workers, kernel in runs:
                course = _copy_course(base, Path(tmp) / f"w{workers}{'k' * kernel}")
                wall, gaps, cpu, rows, nb_s = time_pipeline(course, lab, workers, kernel)
                assert len(rows) == args.students
                per = wall / args.students
                lo, hi = _boot_mean(gaps, wall, rng, args.bootstrap)
                if first is None or kernel:
                    first = gaps if first is None else first
                    speed = ""
                else:
                    slo, shi = _boot_ratio(first, gaps, rng, args.bootstrap)
                    speed = f"{first.mean() / gaps.mean():.2f}x [{slo:.2f}, {shi:.2f}]"
                mean = np.mean([r["score"] for r in rows])
                name = "previous, nbgrader kernel" if kernel else f"cobotlab, {workers} worker(s)"
                lines.append(f"{lab:<14} {name:<26} {wall:>8.1f} "
                             f"{per:>9.2f} [{lo:6.2f}, {hi:6.2f}] {per / plain:>11.2f}x "
                             f"{speed:>22} {cpu / args.students:>10.1f}   mean score "
                             f"{mean:.2f}, nbgrader's own share {nb_s:.1f} s each")
        print(header, *lines[-1 - len(runs):], sep="\n", flush=True)
    print("\nall labs:", header, *lines, sep="\n")
    print("targets: 'vs nbgrader' <= 1.00x (the whole pipeline no slower per submission than "
          "plain nbgrader) and the speed-up of N workers near N")


if __name__ == "__main__":
    main()
