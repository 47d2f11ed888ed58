"""Record what `cobotlab grade` writes for the grading benchmark's class, to compare two
versions of the grader byte for byte.

Usage: python benchmarks/grading_gate.py OUT [--labs lab0_frames ...] [--students 30]
                                         [--seed 0] [--workers 1] [--compare BASE]
                                         [--cell-timeout-s S]

Per lab, a course at a fixed path (``/tmp/cobotlab-gate/<lab>``: nothing in the output then
depends on where it was graded), a fixed grading secret (:data:`SECRET`) and the class of
``benchmarks/grading_class.py`` (``--students`` from ``--seed``: references, classic
mistakes, blanks, one hostile notebook), graded as the benchmark grades it
(``grade_course(..., run_nbgrader=True, template=True)``). Into ``OUT/<lab>/`` go:

* ``grades.csv``, as the course has it;
* ``feedback/``: every file under the course's ``feedback_cobotlab/`` (each student's page and
  the section nbgrader's feedback carries);
* ``gradebook.json``: what nbgrader's gradebook holds per student and cell after the run
  (automatic score, maximum, automatic comment), the record formgrader and
  ``nbgrader export`` read;

and ``OUT/manifest.json``, the SHA-256 of each of those files. ``--compare BASE`` then
compares OUT with an earlier OUT (``BASE/manifest.json``): one line per file that differs or
is missing, a unified diff of the first lines that differ, and exit status 1 if anything
does. This is the gate of a refactoring that must keep every grade: record BASE on the
old version, OUT on the new one. ``--cell-timeout-s`` grades with another per-cell limit
than :class:`autograder.pipeline.worker.Limits`' default, to compare with a version whose default
differed (issue 39 raised it from 10 s to 20 s: ``--cell-timeout-s 10`` compares with f7588bf).
"""

from __future__ import annotations

import argparse
import difflib
import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import grading_class  # noqa: E402

from autograder import checks, gradebook  # noqa: E402
from autograder.course import init_course  # noqa: E402
from autograder.pipeline.pipeline import grade_course  # noqa: E402
from autograder.pipeline.worker import Limits  # noqa: E402
from autograder.secret import SECRET_ENV  # noqa: E402

SECRET = "cobotlab-grading-gate-fixed-secret-0001"
COURSES = Path("/tmp/cobotlab-gate")


def gradebook_dump(course: Path, lab: str) -> dict:
    """{student: {cell: [auto score, max score, auto comment]}} of ``lab`` in the course's
    gradebook.db, sorted, so that two runs compare as text."""
    return gradebook.cells_and_comments(course, lab)


def record_lab(lab: str, out: Path, students: int, seed: int, workers: int,
               limits: Limits = Limits()) -> dict:
    """Grade the class of ``lab`` and copy what the run wrote into ``out``; per file its hash."""
    course = COURSES / lab
    shutil.rmtree(course, ignore_errors=True)
    course.parent.mkdir(parents=True, exist_ok=True)
    init_course(course)
    subs = grading_class.build_class(course, lab, students, seed=seed)
    print(grading_class.describe(lab, subs), flush=True)
    started = time.monotonic()
    grade_course(course, lab, workers=workers, run_nbgrader=True, template=True, quiet=True,
                 limits=limits)
    print(f"{lab}: graded in {time.monotonic() - started:.0f} s", flush=True)
    mine = out / lab
    shutil.rmtree(mine, ignore_errors=True)
    (mine / "feedback").mkdir(parents=True)
    shutil.copy2(course / "grades.csv", mine / "grades.csv")
    shutil.copytree(course / "feedback_cobotlab", mine / "feedback", dirs_exist_ok=True)
    (mine / "gradebook.json").write_text(json.dumps(gradebook_dump(course, lab), indent=1))
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(mine.rglob("*")) if p.is_file()}


def compare(out: Path, base: Path) -> int:
    """Print each file of ``base``'s manifest that ``out`` lacks or holds otherwise; the count."""
    mine = json.loads((out / "manifest.json").read_text())
    theirs = json.loads((base / "manifest.json").read_text())
    labs = {name.split("/", 1)[0] for name in mine}
    differ = 0
    for name in sorted(set(mine) | {n for n in theirs if n.split("/", 1)[0] in labs}):
        if mine.get(name) == theirs.get(name):
            continue
        differ += 1
        if name not in mine or name not in theirs:
            print(f"DIFFERS {name}: only in {'the base' if name in theirs else 'this run'}")
            continue
        print(f"DIFFERS {name}")
        old = (base / name).read_text(errors="replace").splitlines()
        new = (out / name).read_text(errors="replace").splitlines()
        diff = list(difflib.unified_diff(old, new, "base", "this run", lineterm="", n=1))
        print("\n".join(line[:300] for line in diff[:40]))
    compared = sum(1 for n in theirs if n.split("/", 1)[0] in labs)
    print(f"{compared} files of the base compared for {len(labs)} lab(s): "
          + ("all byte-identical" if not differ else f"{differ} differ"))
    return differ


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for the recorded files")
    parser.add_argument("--labs", nargs="+", default=sorted(checks.SPECS))
    parser.add_argument("--students", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--compare", type=Path, default=None, metavar="BASE",
                        help="an earlier OUT to compare this run with")
    parser.add_argument("--cell-timeout-s", type=float, default=None, metavar="S",
                        help="per-cell CPU limit while the notebook loads "
                             f"(default: {Limits().cell_timeout_s:g} s)")
    args = parser.parse_args()
    limits = (Limits() if args.cell_timeout_s is None
              else Limits(cell_timeout_s=args.cell_timeout_s))
    os.environ[SECRET_ENV] = SECRET
    args.out.mkdir(parents=True, exist_ok=True)
    manifest_path = args.out / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    for lab in args.labs:
        manifest = {k: v for k, v in manifest.items() if not k.startswith(f"{lab}/")}
        manifest.update(record_lab(lab, args.out, args.students, args.seed, args.workers,
                                   limits))
        manifest_path.write_text(json.dumps(dict(sorted(manifest.items())), indent=1))
    if args.compare is not None:
        return 1 if compare(args.out, args.compare) else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
