"""Time the independent grader: one submission, and a class of 100 with 1 and 2 workers.

Usage: python benchmarks/grading.py [--students 100] [--workers 1 2]

Builds a temporary course with `init_course`, releases lab 0 with `nbgrader
generate_assignment`, writes seeded submissions (a mix of reference, blank and subtly wrong
answers), and grades them with `grade_course` (the isolated worker per submission; nbgrader's
own autograde is not included: it is a separate, optional cross-check). Target: under 15 s per
submission, and near-linear scaling with workers on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from autograder.course import grade_course, init_course

ASSIGNMENT = "lab0_frames"
SOLUTIONS = {
    "invert_pose": "def invert_pose(a_T_b):\n    R, t = a_T_b[:3, :3], a_T_b[:3, 3]\n"
                   "    out = np.eye(4)\n    out[:3, :3], out[:3, 3] = R.T, {trans}\n    return out",
    "compose_chain": "def compose_chain(poses):\n    out = np.eye(4)\n    for T in poses:\n"
                     "        out = {product}\n    return out",
    "pose_from_rotvec": "def pose_from_rotvec(rvec, t):\n    theta = np.linalg.norm(rvec)\n"
                        "    T = np.eye(4)\n    if {guard}:\n        kx, ky, kz = rvec / theta\n"
                        "        K = np.array([[0, -kz, ky], [kz, 0, -kx], [-ky, kx, 0]])\n"
                        "        T[:3, :3] = np.eye(3) + np.sin(theta) * K "
                        "+ (1 - np.cos(theta)) * K @ K\n    T[:3, 3] = t\n    return T",
}


def _submission(rng) -> dict[str, str]:
    """Each function right (70 %), subtly wrong (20 %) or left blank (10 %)."""
    right = {"trans": "-R.T @ t", "product": "out @ T", "guard": "theta > 0"}
    wrong = {"trans": "-t", "product": "T @ out", "guard": "True"}
    keys = {"invert_pose": "trans", "compose_chain": "product", "pose_from_rotvec": "guard"}
    out = {}
    for name, template in SOLUTIONS.items():
        u = rng.random()
        if u < 0.1:
            continue
        choice = dict(right)
        if u < 0.3:
            choice[keys[name]] = wrong[keys[name]]
        out[name] = template.format(**choice)
    return out


def _build(course: Path, n: int) -> None:
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    subprocess.run([sys.executable, "-m", "nbgrader", "generate_assignment", ASSIGNMENT],
                   cwd=course, env=env, check=True, capture_output=True)
    released = json.loads((course / "release" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb").read_text())
    for i in range(n):
        nb = json.loads(json.dumps(released))
        answers = _submission(np.random.default_rng(i))
        for cell in nb["cells"]:
            gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
            if gid in answers:
                cell["source"] = answers[gid]
        out = course / "submitted" / f"s{i:03d}" / ASSIGNMENT
        out.mkdir(parents=True)
        (out / f"{ASSIGNMENT}.ipynb").write_text(json.dumps(nb))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--students", type=int, default=100)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        one = init_course(Path(tmp) / "one")
        _build(one, 1)
        started = time.perf_counter()
        grade_course(one, ASSIGNMENT, workers=1, quiet=True)
        single = time.perf_counter() - started

        course = init_course(Path(tmp) / "class")
        _build(course, args.students)
        rows = [("1 submission", 1, single, single)]
        for workers in args.workers:
            started = time.perf_counter()
            graded = grade_course(course, ASSIGNMENT, workers=workers, quiet=True)
            elapsed = time.perf_counter() - started
            assert len(graded) == args.students
            rows.append((f"{args.students} submissions", workers, elapsed,
                         elapsed / args.students))
        scores = np.array([r["score"] for r in graded])
    base = rows[1][2]
    print(f"{'batch':<18} {'workers':>7} {'wall s':>8} {'s/submission':>13} {'speed-up':>9}")
    for label, workers, elapsed, per in rows:
        speedup = f"{base / elapsed:.2f}x" if label != "1 submission" else ""
        print(f"{label:<18} {workers:>7} {elapsed:>8.1f} {per:>13.2f} {speedup:>9}")
    print(f"scores: mean {scores.mean():.2f} / 10, full marks {int((scores == 10).sum())}, "
          f"zero {int((scores == 0).sum())}; target < 15 s per submission "
          f"({'met' if max(r[3] for r in rows) < 15 else 'NOT met'})")


if __name__ == "__main__":
    main()
