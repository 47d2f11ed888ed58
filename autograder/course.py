"""The nbgrader course: lay it out, and grade an assignment independently of nbgrader's kernel.

``init_course(DIR)`` makes a directory where the instructor's usual nbgrader commands work
(``nbgrader generate_assignment lab0_frames``, ``nbgrader autograde lab0_frames``, ...).
``grade_course(DIR, ASSIGNMENT)`` then grades every submission in ``DIR/submitted`` with the
isolated grader (:mod:`autograder.grading`), cross-checks nbgrader's own hidden-test results
where it has them, and writes ``DIR/grades.csv`` and per-student feedback HTML.
"""

from __future__ import annotations

import csv
import html
import json
import os
import resource
import secrets
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone
from pathlib import Path

from autograder import checks, grading

__all__ = ["LABS_DIR", "GRADE_COLUMNS", "init_course", "run_nbgrader_autograde", "grade_course"]

LABS_DIR = Path(__file__).resolve().parent.parent / "labs"
GRADE_COLUMNS = ["assignment", "duedate", "timestamp", "student_id", "last_name", "first_name",
                 "email", "raw_score", "late_submission_penalty", "score", "max_score", "flags"]

_CONFIG = '''\
# nbgrader configuration written by cobotlab (autograder.course.init_course).
c = get_config()  # noqa: F821
c.CourseDirectory.course_id = "cobotlab"
c.CourseDirectory.root = {root!r}
# Each cell gets this long in nbgrader's kernel; the authoritative grade comes from
# `cobotlab grade`, which runs the code again in an isolated, limited worker.
c.Execute.timeout = 30
c.Execute.interrupt_on_timeout = True
c.ClearSolutions.code_stub = {{"python": "# YOUR CODE HERE\\nraise NotImplementedError()"}}
'''


def init_course(course_dir, labs_dir=None) -> Path:
    """Lay out an nbgrader course in ``course_dir`` with every lab in ``labs/``.

    Writes ``nbgrader_config.py``, copies each ``labs/<name>/`` (notebook and data, no
    saved outputs) to ``source/<name>/``, and creates the grading secret in
    ``.cobotlab/secret`` (mode 0600; not copied into any assignment). Existing sources and
    the secret are kept, so running it again after adding a lab is safe. Returns the path.
    """
    root = Path(course_dir).resolve()
    labs = Path(labs_dir) if labs_dir else LABS_DIR
    if not labs.is_dir():
        raise ValueError(f"labs directory {labs} not found; pass labs_dir=")
    root.mkdir(parents=True, exist_ok=True)
    config = root / "nbgrader_config.py"
    if not config.exists():
        config.write_text(_CONFIG.format(root=str(root)))
    for lab in sorted(p for p in labs.iterdir() if p.is_dir() and any(p.glob("*.ipynb"))):
        target = root / "source" / lab.name
        if not target.exists():
            shutil.copytree(lab, target, ignore=shutil.ignore_patterns(
                ".ipynb_checkpoints", "__pycache__"))
    grading.create_secret(root)
    return root


def _limit_memory(mb: int):
    def apply():
        resource.setrlimit(resource.RLIMIT_AS, (mb * 1024 * 1024, mb * 1024 * 1024))
    return apply


def run_nbgrader_autograde(course_dir, assignment: str, student_id: str | None = None,
                           timeout_s: float = 1800, memory_mb: int = 3072,
                           cell_timeout_s: int | None = None) -> str:
    """Run ``nbgrader autograde ASSIGNMENT [--student ID]`` with the secret out of its reach.

    nbgrader's kernel runs student code, so it gets a memory limit, an environment without
    the secret, a wall-clock limit after which its whole process group is killed, and
    (where namespaces work) a view of the course with ``.cobotlab/`` masked. Its results
    are only a cross-check: if a submission makes nbgrader hang past ``timeout_s``, the
    students it had not reached get the ``nbgrader_no_result`` flag, not a lost grade.
    Returns nbgrader's output (for the run log).
    """
    root = Path(course_dir).resolve()
    env = {k: v for k, v in os.environ.items() if k != grading.SECRET_ENV}
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    # nbgrader runs `alembic` from PATH: put this interpreter's scripts first.
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    command = [sys.executable, "-m", "nbgrader", "autograde", assignment, "--force"]
    if student_id is not None:
        command += ["--student", student_id]
    if cell_timeout_s:
        command.append(f"--Execute.timeout={int(cell_timeout_s)}")
    if grading.sandbox_available():
        command = grading.sandbox_prefix([str(root / grading.PRIVATE_DIR)],
                                         isolate_network=False) + command
    proc = subprocess.Popen(command, cwd=root, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=_limit_memory(memory_mb))
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, _ = proc.communicate()
        out = (out or "") + f"\nkilled after {timeout_s:g} s"
    return out or ""


# --------------------------------------------------------------------------- nbgrader's view


def _nbgrader_results(root: Path, assignment: str, students: list[str]) -> dict:
    """{student: {"cells": {grade_id: (score, max)}, "student": {...}, "timestamp", ...}}."""
    db = root / "gradebook.db"
    out: dict = {}
    if not db.exists():
        return out
    try:
        from nbgrader.api import Gradebook, MissingEntry
    except ImportError:
        return out
    with Gradebook(f"sqlite:///{db}") as gb:
        try:
            duedate = gb.find_assignment(assignment).duedate
        except MissingEntry:
            return out
        for sid in students:
            entry: dict = {"duedate": duedate, "cells": {}}
            try:
                st = gb.find_student(sid)
                entry["student"] = {"last_name": st.last_name or "", "first_name":
                                    st.first_name or "", "email": st.email or ""}
                sub = gb.find_submission(assignment, sid)
            except MissingEntry:
                out[sid] = entry
                continue
            entry["timestamp"] = sub.timestamp
            entry["penalty"] = float(sub.late_submission_penalty or 0.0)
            for nb in sub.notebooks:
                for g in nb.grades:
                    entry["cells"][g.name] = (float(g.score or 0.0), float(g.max_score or 0.0))
            out[sid] = entry
    return out


def _cell_to_function(root: Path, assignment: str) -> dict[str, str]:
    """grade_id of each hidden-test cell in the source notebooks -> graded function name."""
    names = [s.name for s in checks.SPECS.get(assignment, ())]
    mapping = {}
    for path in sorted((root / "source" / assignment).glob("*.ipynb")):
        for cell in json.loads(path.read_text()).get("cells", []):
            meta = cell.get("metadata", {}).get("nbgrader", {})
            source = "".join(cell.get("source", ""))
            if meta.get("grade") and grading.HIDDEN_MARK in source:
                for name in names:
                    if f"({name}" in source or f" {name}" in source:
                        mapping[meta.get("grade_id", "")] = name
    return mapping


def _cross_check(grade: grading.SubmissionGrade, nb: dict, cell_map: dict[str, str]) -> None:
    """Flag functions nbgrader's kernel passed but the independent grader failed."""
    if not nb.get("cells"):
        grade.flags.append("nbgrader_no_result")
        return
    by_function = {f.name: f for f in grade.functions}
    for grade_id, function in cell_map.items():
        if grade_id not in nb["cells"]:
            grade.flags.append(f"nbgrader_missing_cell:{function}")
            continue
        score, max_score = nb["cells"][grade_id]
        ours = by_function.get(function)
        if ours is not None and max_score > 0 and score >= max_score and ours.fraction < 0.5:
            grade.flags.append(f"nbgrader_passed_but_grader_failed:{function}")


# --------------------------------------------------------------------------- feedback


def _feedback_html(grade: grading.SubmissionGrade) -> str:
    """Feedback naming failed checks and errors in physical units; no test code or data."""
    esc = html.escape
    parts = [f"<html><head><meta charset='utf-8'><title>{esc(grade.assignment)} feedback"
             "</title></head><body>",
             f"<h1>{esc(grade.assignment)}: {esc(grade.student_id)}</h1>",
             f"<p><b>Score: {grade.score:g} / {grade.max_score:g}</b></p>",
             "<p>Each function was run on fresh problems from the same generator as "
             "<code>check(...)</code> in your notebook; errors are measured against the "
             "true answer.</p>"]
    for f in grade.functions:
        parts.append(f"<h2>{esc(f.name)}: {f.points:g} / {f.max_points:g}</h2><ul>")
        for c in f.checks:
            unit = f" {c.unit}" if c.unit else ""
            status = "passed" if c.credit >= 1 else ("partly passed" if c.credit > 0 else
                                                     "FAILED")
            worst = (f"{c.worst_error:.3g}{unit}" if c.worst_error != float("inf")
                     else "no usable answer on some problems")
            parts.append(f"<li>{esc(c.name)}: {status}, {c.n_full}/{c.n_trials} problems within "
                         f"{c.tolerance:.3g}{esc(unit)}; worst error {esc(worst)}"
                         + (f" &mdash; {esc(c.describe)}" if c.credit < 1 and c.describe else "")
                         + "</li>")
        parts.append("</ul>")
        if f.errors:
            parts.append("<p>Problems your code had:</p><ul>"
                         + "".join(f"<li><code>{esc(e)}</code></li>" for e in f.errors)
                         + "</ul>")
    notes = [n for n in grade.notes if "cell error" in n or "unreadable" in n or "no code" in n]
    if notes:
        parts.append("<h2>While running your notebook</h2><ul>"
                     + "".join(f"<li><code>{esc(n.strip())}</code></li>" for n in notes) + "</ul>")
    parts.append("</body></html>")
    return "\n".join(parts)


# --------------------------------------------------------------------------- grading


def _submission_notebooks(sub_dir: Path, assignment: str, root: Path) -> list[Path]:
    """The submission's notebooks, the expected one(s) last so its definitions win."""
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    found = sorted(p for p in sub_dir.rglob("*.ipynb") if ".ipynb_checkpoints" not in p.parts)
    return [p for p in found if p.name not in expected] + [p for p in found if p.name in expected]


def grade_course(course_dir, assignment: str, workers: int = 1, *,
                 run_nbgrader: bool = False, nbgrader_cell_timeout_s: int | None = None,
                 nbgrader_timeout_s: float = 300,
                 limits: grading.Limits = grading.Limits(),
                 nonce: str | None = None, quiet: bool = False) -> list[dict]:
    """Grade every submission of ``assignment`` in ``course_dir/submitted`` and write results.

    Args:
        course_dir: an nbgrader course made by :func:`init_course`.
        assignment: e.g. ``"lab0_frames"``.
        workers: submissions graded in parallel (each in its own limited worker process).
        run_nbgrader: run ``nbgrader autograde`` first, one student at a time (memory-limited,
            killed after ``nbgrader_timeout_s``, secret masked: :func:`run_nbgrader_autograde`);
            otherwise
            use whatever nbgrader results ``gradebook.db`` already holds, if any.
        nbgrader_cell_timeout_s: override nbgrader's per-cell timeout (config: 30 s).
        limits: per-submission resource limits.
        nonce: replay a previous run's problems (its nonce is in ``.cobotlab/runs.jsonl``);
            by default a fresh one, never on disk while student code runs.
        quiet: do not print the summary.

    Returns the gradebook rows (dicts with :data:`GRADE_COLUMNS` keys, ``flags`` a
    ``;``-separated string), also written to ``course_dir/grades.csv``, with feedback in
    ``course_dir/feedback_cobotlab/<student>/<assignment>/feedback.html``. Every
    submission gets a row whatever it did.
    """
    root = Path(course_dir).resolve()
    submitted = root / "submitted"
    students = sorted(p.name for p in submitted.iterdir() if (p / assignment).is_dir()) \
        if submitted.is_dir() else []
    if not students:
        raise ValueError(f"no submissions for {assignment!r} in {submitted}; collect them "
                         "first (nbgrader collect / zip_collect) or check the assignment name")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    secret = grading.load_secret(root)
    nonce = nonce or secrets.token_hex(16)
    nb_log = None
    if run_nbgrader:
        # Before the worker threads start: preexec_fn is not safe alongside threads.
        # One student per nbgrader run: a submission that wedges nbgrader (garbage written to
        # its kernel's sockets does) then costs only its own cross-check.
        nb_log = "\n".join(
            f"--- {sid}\n" + run_nbgrader_autograde(
                root, assignment, sid, timeout_s=nbgrader_timeout_s,
                cell_timeout_s=nbgrader_cell_timeout_s)[-2000:]
            for sid in students)
    nb_results = _nbgrader_results(root, assignment, students)
    cell_map = _cell_to_function(root, assignment)
    hide = [str(root)]

    def one(sid: str) -> grading.SubmissionGrade:
        notebooks = _submission_notebooks(submitted / sid / assignment, assignment, root)
        try:
            grade = grading.grade_notebook(notebooks, assignment, sid, secret, nonce, limits, hide)
        except Exception as exc:  # noqa: BLE001 - a grader bug must not lose the row
            grade = grading.SubmissionGrade(sid, assignment, flags=["grader_error"],
                                            notes=[f"grader error: {type(exc).__name__}: {exc}"])
            grade.functions = [checks.score_function(s, [], []) for s in checks.SPECS[assignment]]
        _cross_check(grade, nb_results.get(sid, {}), cell_map)
        return grade

    started = time.monotonic()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        grades = list(pool.map(one, students))
    elapsed = time.monotonic() - started

    rows = []
    for grade in grades:
        nb = nb_results.get(grade.student_id, {})
        stamp = nb.get("timestamp") or _timestamp_file(submitted / grade.student_id / assignment)
        penalty = nb.get("penalty", 0.0)
        who = nb.get("student", {})
        rows.append({
            "assignment": assignment, "duedate": nb.get("duedate") or "",
            "timestamp": stamp or "", "student_id": grade.student_id,
            "last_name": who.get("last_name", ""), "first_name": who.get("first_name", ""),
            "email": who.get("email", ""), "raw_score": grade.score,
            "late_submission_penalty": penalty, "score": max(0.0, round(grade.score - penalty, 2)),
            "max_score": grade.max_score, "flags": ";".join(grade.flags)})
        out = root / "feedback_cobotlab" / grade.student_id / assignment
        out.mkdir(parents=True, exist_ok=True)
        (out / "feedback.html").write_text(_feedback_html(grade), encoding="utf-8")

    with open(root / "grades.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=GRADE_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    # The nonce reaches the disk only now that every worker is gone (replays use it).
    private = root / grading.PRIVATE_DIR
    private.mkdir(mode=0o700, exist_ok=True)
    with open(private / "runs.jsonl", "a") as f:
        f.write(json.dumps({"assignment": assignment, "nonce": nonce, "when":
                            datetime.now(timezone.utc).isoformat(), "students": len(rows)}) + "\n")
    (private / "last_run.log").write_text(
        "\n".join(f"{g.student_id}: " + " | ".join(g.notes) for g in grades)
        + ("\n\nnbgrader autograde output:\n" + nb_log if nb_log else ""))
    if not quiet:
        _print_summary(grades, assignment, elapsed, workers)
    return rows


def _timestamp_file(path: Path) -> str:
    stamp = path / "timestamp.txt"
    return stamp.read_text().strip() if stamp.is_file() else ""


def _print_summary(grades, assignment: str, elapsed: float, workers: int) -> None:
    print(f"{assignment}: graded {len(grades)} submissions in {elapsed:.1f} s with {workers} "
          f"worker(s); sandbox: {'namespaces' if grading.sandbox_available() else 'rlimits only'}")
    width = max([10] + [len(g.student_id) for g in grades])
    print(f"{'student':<{width}}  {'score':>11}  failed checks / flags")
    for g in grades:
        failed = [f"{f.name}:{c}" for f in g.functions for c in f.failed_checks]
        text = ", ".join(failed) or "-"
        if g.flags:
            text += "   FLAGS: " + ", ".join(g.flags)
        print(f"{g.student_id:<{width}}  {g.score:>5g} / {g.max_score:<3g}  {text}")
