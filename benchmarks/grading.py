"""Time `cobotlab grade` on every lab against plain `nbgrader autograde` on the same class.

Usage: python benchmarks/grading.py [--labs lab0_frames ...] [--students 30] [--workers 1 2]
                                    [--seed 0] [--bootstrap 2000] [--no-previous]
                                    [--json PATH] [--smoke]

One run measures every lab (``autograder.checks.SPECS``; ``--labs`` picks some). Per lab, a
temporary course (`init_course`, `nbgrader generate_assignment`) and a class of
``--students`` submissions (at least 30; fewer only with ``--smoke``, whose numbers are not
for the docs), built from ``--seed`` by ``benchmarks/grading_class.py``: references, classic
mistakes (exact text edits of a graded function's reference cell), blanks (fully and partly)
and one hostile submission from tests/adversarial. Its composition is printed. Every row
grades the very same class, in its own copy of the course:

1. plain nbgrader: one `nbgrader autograde LAB --force` over the class, as an instructor
   without cobotlab runs it (one process, no sandbox, no second grader);
2. cobotlab, 1 worker: ``grade_course(..., run_nbgrader=True, template=True)``, the whole
   pipeline (freeze; per submission a sandboxed worker forked from the lab's template runs the
   notebook once for both nbgrader's autograde converter and the hidden problems; recording);
3. cobotlab, N workers (each further ``--workers`` count, 2 by default), template=True;
4. previous: no template: 1 worker, ``template=False`` (a fresh sandboxed interpreter per
   submission, the approach before the template); ``--no-previous`` skips it.

Columns of the first table (Markdown):

* wall s: the run's wall clock;
* s/submission [95 % CI]: wall over the class, its interval from a bootstrap over the
  per-submission completion gaps (scaled so the point is wall / N);
* median s/submission [95 % CI]: the median completion gap, bootstrap interval. The gaps
  are the autograded notebooks' write times for plain nbgrader and the progress callback's
  completions for cobotlab (the first gap holds the run's start-up);
* median vs nbgrader [95 % CI]: the row's median over plain nbgrader's, the interval of that
  ratio from resampling both samples;
* speed-up [95 % CI]: the mean gap of 1 worker over that of N workers (bootstrap);
* CPU s/sub: CPU time (user + system) of the grading process and everything below it, from
  /proc, over the class;
* peak MB per worker: max; median over the class of each submission's cgroup peak memory
  (``SubmissionGrade.profile["peak_mb"]``; "-" without a cgroup or for plain nbgrader);
* mean score.

Targets, printed per lab as met / NOT met: at 1 worker the median ratio to plain nbgrader
<= 0.30 with its upper bound <= 0.35; 2 workers a speed-up >= 1.80.

The second table profiles one submission per lab: the median over the class (1-worker
template run) of each phase, in seconds: sandbox start (bubblewrap, interpreter and imports,
or the fork from the template), the notebook's own cells, the hidden problems and tests,
nbgrader's converter (its own share, from .cobotlab/last_run.log), recording and the rest
(the completion gap less those), and the total (the median gap); then the template's shared
leading cells and its one-off build (one template per worker thread), paid once, not per
submission. The phases come from ``SubmissionGrade.profile``, captured by wrapping
``autograder.pipeline.score.score_execution``. Each is a median on its own, so they need not add up
to the total's median.

After each cobotlab run the scores are checked and a line starting ``!!! WARNING`` says
where a reference missed full marks, a mistake got full marks, a blank got more than its
non-blank functions allow, the hostile case scored what it should not (see
``grading_class.check_scores``) or missed its flag, or two runs disagree. ``--json PATH``
writes every number (per lab, per row, the samples too) after each lab, so the docs can be
regenerated. Share the machine with nothing else while it runs (about 40 minutes for every
lab on 2 cores).
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
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import grading_class  # noqa: E402

from autograder import checks  # noqa: E402
from autograder.course import init_course  # noqa: E402
from autograder.pipeline import execute as execute_stage  # noqa: E402
from autograder.pipeline import score as score_stage  # noqa: E402
from autograder.pipeline.pipeline import grade_course  # noqa: E402
from autograder.pipeline.score import SubmissionGrade  # noqa: E402

MIN_STUDENTS = 30
TARGET_RATIO, TARGET_RATIO_UPPER, TARGET_SPEEDUP = 0.30, 0.35, 1.80
PROFILE_KEYS = ("start_s", "shared_s", "cells_s", "hidden_s", "peak_mb")


def _nbgrader(course: Path, *args: str) -> None:
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    env.pop("COBOTLAB_GRADING_SECRET", None)
    subprocess.run([sys.executable, "-m", "nbgrader", *args], cwd=course, env=env, check=True,
                   capture_output=True)


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


def time_plain_nbgrader(course: Path, lab: str) -> dict:
    """One `nbgrader autograde LAB` over the class: wall s, per-submission gaps s, CPU s."""
    started = time.time()
    with _CpuMeter() as meter:
        _nbgrader(course, "autograde", lab, "--force")
    wall, cpu = time.time() - started, meter.cpu_s
    done = sorted(p.stat().st_mtime for p in (course / "autograded").glob(f"*/{lab}/{lab}.ipynb"))
    return {"wall_s": wall, "gaps_s": np.diff([started, *done]), "cpu_s": cpu}


def _profile(grade) -> dict:
    """The grade's phase profile (empty when this version of the grader has none)."""
    profile = getattr(grade, "profile", None)
    return dict(profile) if isinstance(profile, dict) else {}


def time_pipeline(course: Path, lab: str, workers: int, template: bool) -> dict:
    """`grade_course` with nbgrader's cross-check: wall s, completion gaps s (and whose),
    CPU s, the rows, each submission's SubmissionGrade (captured by wrapping
    ``autograder.pipeline.score.score_execution``, which the score stage looks up at call time), nbgrader's
    own share per student and the run's log."""
    marks: list[tuple[float, str]] = []
    captured: dict[str, object] = {}
    templates: dict[int, object] = {}
    original_execute = execute_stage.execute_notebook
    original_score = score_stage.score_execution

    def execute(*args, **kwargs):
        template = kwargs.get("template")
        if template is not None:   # autograder.template.Template: its build_s is one-off
            templates[id(template)] = template
        return original_execute(*args, **kwargs)

    def score(*args, **kwargs):
        grade = original_score(*args, **kwargs)
        if isinstance(grade, SubmissionGrade):
            captured[grade.student_id] = grade   # one scoring per submission
        return grade

    execute_stage.execute_notebook, score_stage.score_execution = execute, score
    started = time.time()
    try:
        with _CpuMeter() as meter:
            rows = grade_course(course, lab, workers=workers, run_nbgrader=True,
                                template=template, quiet=True,
                                progress=lambda done, total, sid: marks.append(
                                    (time.time(), sid)) if done else None)
    finally:
        execute_stage.execute_notebook = original_execute
        score_stage.score_execution = original_score
    wall, cpu = time.time() - started, meter.cpu_s
    log = (course / ".cobotlab" / "last_run.log").read_text()
    own = {}
    for m in re.finditer(r"^(\S+): (.*)$", log, re.M):
        share = re.search(r"nbgrader autograde: ([0-9.]+) s of its own", m.group(2))
        if share:
            own[m.group(1)] = float(share.group(1))
    return {"wall_s": wall, "gaps_s": np.diff([started, *(t for t, _ in marks)]),
            "gap_students": [sid for _, sid in marks], "cpu_s": cpu, "rows": rows,
            "grades": captured, "nbgrader_own_s": own, "log": log,
            "template_build_s": [float(t.build_s) for t in templates.values()
                                 if getattr(t, "build_s", None) is not None]}


def _template_cost(run: dict) -> float | None:
    """The template's one-off cost of the run, if this version of the grader reports it:
    the ``build_s`` of the templates handed to execute_notebook (summed: one per run, or per
    worker), else ``profile["template_s"]``, else a run note "template...: X s" in the log."""
    if run["template_build_s"]:
        return float(sum(run["template_build_s"]))
    for grade in run["grades"].values():
        value = _profile(grade).get("template_s")
        if value is not None:
            return float(value)
    head = run["log"].split("\n\n", 1)[0]
    m = re.search(r"^\s*template\b[^\n]*?: ([0-9.]+) s\b", head, re.M | re.I)
    return float(m.group(1)) if m else None


def _boot_mean(gaps: np.ndarray, wall: float, rng, n: int) -> tuple[float, float]:
    """95 % interval of wall/N from resampled gaps (scaled so the point estimate is wall/N)."""
    scale = wall / gaps.sum() if gaps.sum() > 0 else 1.0
    means = rng.choice(gaps, size=(n, len(gaps))).mean(axis=1) * scale
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def _boot_median(gaps: np.ndarray, rng, n: int) -> tuple[float, float]:
    medians = np.median(rng.choice(gaps, size=(n, len(gaps))), axis=1)
    return float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))


def _boot_ratio(a: np.ndarray, b: np.ndarray, rng, n: int, stat=np.mean) -> tuple[float, float]:
    """95 % interval of stat(a) / stat(b), both samples resampled."""
    ra = stat(rng.choice(a, size=(n, len(a))), axis=1)
    rb = stat(rng.choice(b, size=(n, len(b))), axis=1)
    ratio = ra / rb
    return float(np.percentile(ratio, 2.5)), float(np.percentile(ratio, 97.5))


def _warn(line: str) -> None:
    print(f"!!! WARNING: {line}", flush=True)


def _fmt_ci(x: float, ci, digits: int = 2, unit: str = "") -> str:
    return f"{x:.{digits}f}{unit} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def _md(cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


HEADER = ("lab", "grader", "wall s", "s/submission [95 % CI]", "median s/submission [95 % CI]",
          "median vs nbgrader [95 % CI]", "speed-up [95 % CI]", "CPU s/sub",
          "peak MB per worker (max; median)", "mean score")
PROFILE_HEADER = ("lab", "sandbox start", "own cells", "hidden problems",
                  "nbgrader converter", "recording and the rest", "total",
                  "shared cells (template, once)", "template build (once per worker)")


def _row_line(lab: str, row: dict) -> str:
    n = row["students"]
    speed = (_fmt_ci(row["speedup"], row["speedup_ci"], unit="x")
             if row.get("speedup") is not None else "")
    ratio = (_fmt_ci(row["median_ratio"], row["median_ratio_ci"], unit="x")
             if row["label"] != "plain nbgrader" else "1.00x")
    peak = (f"{row['peak_mb_max']:.0f}; {row['peak_mb_median']:.0f}"
            if row.get("peak_mb_max") is not None else "-")
    score = f"{row['mean_score']:.2f}" if row.get("mean_score") is not None else "-"
    return _md((lab, row["label"], f"{row['wall_s']:.1f}",
                _fmt_ci(row["per_submission_s"], row["per_submission_ci"]),
                _fmt_ci(row["median_s"], row["median_ci"]), ratio, speed,
                f"{row['cpu_s'] / n:.1f}", peak, score))


def _median_or_none(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def profile_of(run: dict) -> dict:
    """Per submission and as medians over the class: the phases of one submission."""
    gap = dict(zip(run["gap_students"], run["gaps_s"]))
    per = {}
    for sid, grade in run["grades"].items():
        p = _profile(grade)
        entry = {k: (float(p[k]) if p.get(k) is not None else None) for k in PROFILE_KEYS}
        entry["nbgrader_s"] = run["nbgrader_own_s"].get(sid)
        entry["gap_s"] = float(gap[sid]) if sid in gap else None
        parts = [entry[k] for k in ("start_s", "cells_s", "hidden_s", "nbgrader_s")]
        entry["rest_s"] = (entry["gap_s"] - sum(parts)
                           if entry["gap_s"] is not None and None not in parts else None)
        per[sid] = entry
    medians = {k: _median_or_none(e[k] for e in per.values())
               for k in ("start_s", "shared_s", "cells_s", "hidden_s", "nbgrader_s", "rest_s")}
    medians["total_s"] = float(np.median(run["gaps_s"])) if len(run["gaps_s"]) else None
    medians["template_s"] = _template_cost(run)
    return {"per_submission": per, "median": medians}


def _profile_line(lab: str, prof: dict) -> str:
    m = prof["median"]

    def s(key):
        return f"{m[key]:.2f}" if m.get(key) is not None else "n/a"

    return _md((lab, s("start_s"), s("cells_s"), s("hidden_s"), s("nbgrader_s"), s("rest_s"),
                s("total_s"), s("shared_s"), s("template_s")))


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [_jsonable(v) for v in x.tolist()]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def measure_lab(lab: str, args, tmp: Path) -> dict:
    """Build the class, grade it every way, check the scores; every number of the lab."""
    rng = np.random.default_rng(1)   # fixed, per lab: a lab's intervals do not depend on --labs
    n, B = args.students, args.bootstrap
    base = init_course(tmp / "base")
    subs = grading_class.build_class(base, lab, n, seed=args.seed)
    print(grading_class.describe(lab, subs), flush=True)
    out: dict = {"submissions": [s.as_dict() for s in subs], "rows": [], "warnings": [],
                 "verdicts": [], "composition": {}}
    for s in subs:
        out["composition"][s.kind] = out["composition"].get(s.kind, 0) + 1

    plain = time_plain_nbgrader(_copy_course(base, tmp / "plain"), lab)
    pg = plain["gaps_s"]
    out["rows"].append({
        "label": "plain nbgrader", "workers": 1, "template": None, "students": n,
        "wall_s": plain["wall_s"], "cpu_s": plain["cpu_s"], "gaps_s": pg,
        "per_submission_s": plain["wall_s"] / n,
        "per_submission_ci": _boot_mean(pg, plain["wall_s"], rng, B),
        "median_s": float(np.median(pg)), "median_ci": _boot_median(pg, rng, B)})
    print(_row_line(lab, out["rows"][-1]), flush=True)

    runs = [(w, True) for w in args.workers] + ([(1, False)] if args.previous else [])
    first_gaps, first_scores, profile = None, None, None
    for workers, template in runs:
        label = (f"cobotlab, {workers} worker{'s' * (workers > 1)}" if template
                 else "previous: no template, 1 worker")
        course = _copy_course(base, tmp / f"w{workers}{'' if template else '-no-template'}")
        run = time_pipeline(course, lab, workers, template)
        gaps, rows = run["gaps_s"], run["rows"]
        if len(rows) != n:
            out["warnings"].append(f"{lab}, {label}: {len(rows)} rows for {n} submissions")
            _warn(out["warnings"][-1])
        for line in grading_class.check_scores(subs, rows, run["grades"], f"{lab}, {label}"):
            out["warnings"].append(line)
            _warn(line)
        scores = {r["student_id"]: r["score"] for r in rows}
        if first_scores is None:
            first_scores = scores
        else:
            for sid in sorted(set(scores) | set(first_scores)):
                if scores.get(sid) != first_scores.get(sid):
                    out["warnings"].append(
                        f"{lab}, {label}: {sid} scored {scores.get(sid)!r}, "
                        f"{first_scores.get(sid)!r} in the first cobotlab run")
                    _warn(out["warnings"][-1])
        median = float(np.median(gaps))
        peaks = [_profile(g).get("peak_mb") for g in run["grades"].values()]
        peaks = [float(p) for p in peaks if p is not None]
        numeric = [float(r["score"]) for r in rows if r["score"] not in ("", None)]
        row = {
            "label": label, "workers": workers, "template": template, "students": n,
            "wall_s": run["wall_s"], "cpu_s": run["cpu_s"], "gaps_s": gaps,
            "gap_students": run["gap_students"],
            "per_submission_s": run["wall_s"] / n,
            "per_submission_ci": _boot_mean(gaps, run["wall_s"], rng, B),
            "median_s": median, "median_ci": _boot_median(gaps, rng, B),
            "median_ratio": median / float(np.median(pg)),
            "median_ratio_ci": _boot_ratio(gaps, pg, rng, B, stat=np.median),
            "peak_mb_max": max(peaks) if peaks else None,
            "peak_mb_median": float(np.median(peaks)) if peaks else None,
            "mean_score": float(np.mean(numeric)) if numeric else None,
            "max_score": float(rows[0]["max_score"]) if rows else None,
            "scores": scores, "flags": {r["student_id"]: r["flags"] for r in rows},
            "nbgrader_own_s": run["nbgrader_own_s"],
            "template_build_s": run["template_build_s"],
            "profiles": {sid: _profile(g) for sid, g in run["grades"].items()},
            "function_points": {sid: {f.name: f.points for f in g.functions}
                                for sid, g in run["grades"].items()},
        }
        if template and workers == 1:
            first_gaps = gaps
            profile = profile_of(run)
        elif template and first_gaps is not None:
            row["speedup"] = float(first_gaps.mean() / gaps.mean())
            row["speedup_ci"] = _boot_ratio(first_gaps, gaps, rng, B)
        out["rows"].append(row)
        print(_row_line(lab, row), flush=True)

    out["profile"] = profile
    for row in out["rows"][1:]:
        if row["template"] and row["workers"] == 1:
            r, (lo, hi) = row["median_ratio"], row["median_ratio_ci"]
            met = r <= TARGET_RATIO and hi <= TARGET_RATIO_UPPER
            out["verdicts"].append(
                f"{lab} 1 worker: median {r:.2f}x nbgrader [{lo:.2f}, {hi:.2f}] — target "
                f"<= {TARGET_RATIO:.2f} (upper <= {TARGET_RATIO_UPPER:.2f}): "
                f"{'met' if met else 'NOT met'}")
        elif row.get("speedup") is not None:
            s, (lo, hi) = row["speedup"], row["speedup_ci"]
            target = (f" — target >= {TARGET_SPEEDUP:.2f}: "
                      f"{'met' if s >= TARGET_SPEEDUP else 'NOT met'}"
                      if row["workers"] == 2 else " (no target)")
            out["verdicts"].append(f"{lab} {row['workers']} workers: {s:.2f}x "
                                   f"[{lo:.2f}, {hi:.2f}]{target}")
    return out


def _tables(results: dict) -> str:
    lines = ["", _md(HEADER), _md(["---"] * len(HEADER))]
    for lab, res in results.items():
        lines += [_row_line(lab, row) for row in res["rows"]]
    lines += ["", "Profile of one submission (median over the class, 1 worker, template; s):",
              "", _md(PROFILE_HEADER), _md(["---"] * len(PROFILE_HEADER))]
    lines += [_profile_line(lab, res["profile"]) for lab, res in results.items()
              if res.get("profile")]
    lines += ["", *(v for res in results.values() for v in res["verdicts"])]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labs", nargs="+", default=sorted(checks.SPECS),
                        choices=sorted(checks.SPECS))
    parser.add_argument("--students", type=int, default=MIN_STUDENTS,
                        help=f"submissions per lab (at least {MIN_STUDENTS} unless --smoke)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                        help="worker counts of the template rows; 1 must be among them")
    parser.add_argument("--seed", type=int, default=0, help="the class's seed")
    parser.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples")
    parser.add_argument("--no-previous", dest="previous", action="store_false",
                        help="skip the previous approach's row (template=False)")
    parser.add_argument("--json", type=Path, default=None, help="write every number here")
    parser.add_argument("--smoke", action="store_true",
                        help=f"allow fewer than {MIN_STUDENTS} students (a smoke test only)")
    args = parser.parse_args()
    if args.students < MIN_STUDENTS and not args.smoke:
        parser.error(f"--students {args.students}: at least {MIN_STUDENTS} (or --smoke)")
    if 1 not in args.workers:
        parser.error("--workers must include 1 (the base of the ratios and the profile)")
    args.workers = sorted(set(args.workers))
    meta = {"started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "cores": os.cpu_count(), "load_average": os.getloadavg()[0],
            "students": args.students, "seed": args.seed, "bootstrap": args.bootstrap,
            "workers": args.workers, "previous": args.previous, "smoke": args.smoke,
            "command": " ".join(sys.argv)}
    print(f"{args.students} submissions per lab{' (smoke test)' if args.smoke else ''}; "
          f"{meta['cores']} cores; load average {meta['load_average']:.1f} at the start; "
          "share the machine with nothing else while it runs", flush=True)
    print(_md(HEADER), _md(["---"] * len(HEADER)), sep="\n", flush=True)
    results: dict = {}
    for lab in args.labs:
        with tempfile.TemporaryDirectory(prefix="cobotlab-bench-") as tmp:
            results[lab] = measure_lab(lab, args, Path(tmp))
        if results[lab]["profile"]:
            print(_md(PROFILE_HEADER), _profile_line(lab, results[lab]["profile"]), sep="\n")
        print(*results[lab]["verdicts"], sep="\n", flush=True)
        if args.json:
            args.json.write_text(json.dumps(_jsonable({"meta": meta, "labs": results}),
                                            indent=1))
    print("\nall labs:" + _tables(results))
    warnings = [w for res in results.values() for w in res["warnings"]]
    if warnings:
        print(f"\n{len(warnings)} score warning(s):")
        for line in warnings:
            _warn(line)
    print(f"\ntargets: 1 worker's median <= {TARGET_RATIO:.2f}x plain nbgrader's (upper bound "
          f"<= {TARGET_RATIO_UPPER:.2f}); 2 workers' speed-up >= {TARGET_SPEEDUP:.2f}")


if __name__ == "__main__":
    main()
