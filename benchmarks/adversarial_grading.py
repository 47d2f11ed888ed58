"""The whole adversarial corpus (tests/adversarial/, lab 0) against plain nbgrader and `cobotlab grade`.

Prints one row per attack: what plain ``nbgrader autograde`` gave it (score, and the damage it
did: files changed in the course, beside it or in the grader's code, gradebook health,
processes left behind) next to what ``cobotlab grade`` gave it, in the same course layout.

Plain nbgrader runs each attack in its own copy of the course (with an honest ``victim``, so
attacks on a classmate and on the gradebook show), as the instructor would run it, except for
a safety net this machine needs: the root is read-only apart from the benchmark's folder and
/tmp, the checkout's ``autograder/`` is a writable decoy copy (a write there is reported, not
made), and a cgroup caps memory at 6 GB and processes at 600. ``cobotlab grade`` runs all the
attacks in one course, as a class would be graded.

    .venv/bin/python benchmarks/adversarial_grading.py --part plain     # ~10 min on 2 cores
    .venv/bin/python benchmarks/adversarial_grading.py --part cobotlab  # ~8 min on 2 cores
    .venv/bin/python benchmarks/adversarial_grading.py --cases copy_source,fifo_notebook
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import course_kit as kit  # noqa: E402

from autograder import gradebook, sandbox  # noqa: E402
from autograder.freeze import student_key  # noqa: E402

ASSIGNMENT = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
TOKEN = "instructor-token-5f1e"
PORT = 47613


def _hashes(top: Path, skip=()) -> dict[str, str]:
    out = {}
    for dirpath, dirnames, filenames in os.walk(top):
        rel_dir = os.path.relpath(dirpath, top)
        dirnames[:] = [d for d in dirnames if os.path.normpath(os.path.join(rel_dir, d))
                       not in skip and d not in ("__pycache__", ".ipynb_checkpoints")]
        for name in filenames:
            path = Path(dirpath) / name
            rel = os.path.normpath(os.path.join(rel_dir, name))
            if rel in skip:
                continue
            try:
                out[rel] = ("link:" + os.readlink(path)) if path.is_symlink() else (
                    hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "special")
            except OSError:
                out[rel] = "unreadable"
    return out


def _changed(before: dict, after: dict) -> list[str]:
    return sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))


# Attacks on a classmate need one to be there; the others run alone (nbgrader's time is
# the cost of this benchmark).
NEEDS_VICTIM = {"overwrite_classmate", "copy_classmate", "symlink_folder",
                "gradebook_sqlite_edit", "gradebook_overwrite", "hyperlink_cells"}


def _build(base: Path, released: Path, cases: dict, names, victim: bool = True):
    course = kit.fresh_course(released, base)
    if victim:
        kit.submit(course, ASSIGNMENT, "victim",
                   replace=kit.solution_sources(ASSIGNMENT, FUNCTIONS))
        kit.submit(course, ASSIGNMENT, "blank")
    folders = {name: kit.submit_case(course, ASSIGNMENT, name, cases[name]) for name in names}
    (base / "instructor_notes.txt").write_text("the instructor's own file\n")
    return course, folders


OUTPUTS = ("gradebook.db", "autograded", "feedback", "feedback_cobotlab", "grades.csv",
           ".cobotlab/runs.jsonl", ".cobotlab/last_run.log", ".cobotlab/gradebook.backup.db",
           "export.csv")


def _scores(course: Path) -> tuple[dict[str, float], str | None]:
    problem = gradebook.problem(course / "gradebook.db")
    if problem:
        return {}, problem
    try:
        return gradebook.net_scores(course, ASSIGNMENT), None
    except Exception as exc:  # noqa: BLE001 - a forged gradebook may break the API
        return {}, f"{type(exc).__name__}: {exc}"


def run_plain(base: Path, released: Path, cases: dict, name: str) -> dict:
    """One attack (and the victim) through plain `nbgrader autograde`, in a safety net."""
    course, folders = _build(base, released, cases, [name], victim=name in NEEDS_VICTIM)
    home = base / "home"
    home.mkdir()
    decoy = base / "decoy_autograder"
    shutil.copytree(ROOT / "autograder", decoy, ignore=shutil.ignore_patterns("__pycache__"))
    watched = {"course": (course, OUTPUTS), "beside": (base, ("course", "home", "decoy_autograder")),
               "home": (home, (".cache",)), "autograder": (decoy, ())}
    before = {k: _hashes(p, s) for k, (p, s) in watched.items()}
    secret = (course / ".cobotlab" / "secret").read_text().strip()
    env = dict(os.environ, HOME=str(home), COBOTLAB_TEST_INSTRUCTOR_TOKEN=TOKEN)
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    cgroup = sandbox.Cgroup(6144, 600) if sandbox.capabilities().cgroup else None
    net = ["bwrap", "--cap-drop", "ALL", "--ro-bind", "/", "/", "--dev", "/dev", "--proc", "/proc",
           "--bind", "/tmp", "/tmp", "--bind", str(base), str(base),
           "--bind", str(decoy), str(ROOT / "autograder"), "--chdir", str(course), "--"]
    command = [sys.executable, "-m", "nbgrader", "autograde", ASSIGNMENT, "--force"]
    if cgroup is not None:
        join = " && ".join(f"echo $$ > {p}" for p in cgroup.procs_files)
        command = ["/bin/sh", "-c", f'{join} && exec "$@"', "net", *net, *command]
    started = time.monotonic()
    try:
        done = subprocess.run(command, cwd=course, env=env, capture_output=True, text=True,
                              timeout=120, check=False)
        outcome = f"exit {done.returncode}"
    except subprocess.TimeoutExpired:
        outcome = "HUNG (killed after 120 s)"
    seconds = time.monotonic() - started
    left = 0
    if cgroup is not None:
        time.sleep(1)
        left = len(cgroup.pids())
        oom = cgroup.oom_kills()
        cgroup.remove()
    else:
        oom = 0
    after = {k: _hashes(p, s) for k, (p, s) in watched.items()}
    scores, problem = _scores(course)
    student = folders[name]
    leaked = [what for what, needle in (("secret", secret), ("token", TOKEN),
                                        ("service", "instructor-service-secret"))
              if any(needle in p.read_text(errors="ignore") for p in
                     (course / "autograded").rglob("*.ipynb"))] if (course / "autograded").exists() else []
    fills = list(Path("/tmp").glob("cobotlab-attack-*")) + list(home.glob("cobotlab-attack-*"))
    for path in fills:
        path.unlink(missing_ok=True)
    return {"score": scores.get(student), "victim": scores.get("victim"), "gradebook": problem,
            "changed": {k: _changed(before[k], after[k]) for k in watched}, "left": left,
            "oom": oom, "outcome": outcome, "seconds": seconds, "leaked": leaked,
            "filled": len(fills)}


def run_cobotlab(base: Path, released: Path, cases: dict, names) -> dict:
    course, folders = _build(base, released, cases, names)
    watched = {"course": (course, OUTPUTS + (".cobotlab",)),
               "beside": (base, ("course",)), "autograder": (ROOT / "autograder", ()),
               "home": (Path.home(), (".cache", ".local", ".config", ".ipython", ".jupyter",
                                      ".pyenv", ".npm", ".mozilla"))}
    before = {k: _hashes(p, s) for k, (p, s) in watched.items()}
    env = dict(os.environ, COBOTLAB_TEST_INSTRUCTOR_TOKEN=TOKEN)
    started = time.monotonic()
    done = subprocess.run([str(Path(sys.executable).parent / "cobotlab"), "grade", str(course),
                           ASSIGNMENT, "--workers", "2"], env=env, capture_output=True,
                          text=True, timeout=3000, check=False)
    seconds = time.monotonic() - started
    after = {k: _hashes(p, s) for k, (p, s) in watched.items()}
    with open(course / "grades.csv", newline="") as f:
        rows = {r["student_id"]: r for r in csv.DictReader(f)}
    return {"rows": rows, "folders": folders, "exit": done.returncode, "seconds": seconds,
            "stdout": done.stdout, "gradebook": gradebook.problem(course / "gradebook.db"),
            "changed": {k: _changed(before[k], after[k]) for k in watched},
            "export": kit.nbgrader(course, "export", "--CsvExportPlugin.to=export.csv").returncode}


def _plain_text(r: dict) -> str:
    bits = [f"{r['score']:g}/10" if r["score"] is not None else "no score"]
    if r["victim"] is not None and r["victim"] < 10:
        bits.append(f"victim {r['victim']:g}/10")
    if r["gradebook"]:
        bits.append(f"gradebook broken ({r['gradebook'][:40]})")
    for key, changed in r["changed"].items():
        if changed:
            bits.append(f"{key} changed: {', '.join(changed[:3])}")
    if r["leaked"]:
        bits.append("leaked " + "+".join(r["leaked"]))
    if r["left"]:
        bits.append(f"{r['left']} processes left")
    if r["filled"]:
        bits.append(f"{r['filled']} fill files")
    if not r["outcome"].startswith("exit 0"):
        bits.append(r["outcome"])
    return "; ".join(bits)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("plain", "cobotlab", "both"), default="both")
    parser.add_argument("--cases", default="", help="comma-separated case names (default all)")
    parser.add_argument("--out", default="", help="write the results as JSON here too")
    args = parser.parse_args()
    cases = kit.corpus(ASSIGNMENT)
    names = [n for n in args.cases.split(",") if n] or sorted(cases)
    stop = threading.Event()
    kit.serve_localhost(PORT, b"instructor-service-secret", stop)
    results: dict = {"plain": {}, "cobotlab": None}
    started = time.monotonic()
    released_dir = tempfile.TemporaryDirectory(prefix="bench-released-")
    released = kit.released_course(Path(released_dir.name), ASSIGNMENT)
    try:
        if args.part in ("plain", "both"):
            for name in names:
                with tempfile.TemporaryDirectory(prefix="bench-plain-") as tmp:
                    results["plain"][name] = run_plain(Path(tmp), released, cases, name)
                print(f"plain nbgrader  {name:<26} {_plain_text(results['plain'][name])}",
                      flush=True)
        if args.part in ("cobotlab", "both"):
            with tempfile.TemporaryDirectory(prefix="bench-cobotlab-") as tmp:
                results["cobotlab"] = run_cobotlab(Path(tmp), released, cases, names)
    finally:
        stop.set()
        released_dir.cleanup()
    c = results["cobotlab"]
    if c is not None:
        print(f"\ncobotlab grade: exit {c['exit']}, {c['seconds']:.0f} s for {len(c['rows'])} rows;"
              f" gradebook: {c['gradebook'] or 'ok'}; nbgrader export: exit {c['export']}; "
              f"files changed outside the outputs: "
              + (", ".join(f"{k}: {v[:3]}" for k, v in c["changed"].items() if v) or "none"))
        print(f"  victim {c['rows']['victim']['score']}, blank {c['rows']['blank']['score']}")
        print("  " + c["stdout"].splitlines()[0] if c["stdout"] else "")
    print("\n| attack | plain nbgrader autograde | cobotlab grade |\n|---|---|---|")
    for name in names:
        plain = _plain_text(results["plain"][name]) if name in results["plain"] else "-"
        ours = "-"
        if c is not None:
            row = c["rows"].get(student_key(c["folders"][name]))
            if row is not None:
                ours = f"{float(row['score']):g}/10" + (f"; {row['flags']}" if row["flags"] else "")
        print(f"| {name} | {plain} | {ours} |")
    print(f"\nwall time {time.monotonic() - started:.0f} s; sandbox: {sandbox.mode()}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, default=str, indent=1))


if __name__ == "__main__":
    main()
