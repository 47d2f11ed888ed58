"""The nbgrader course: lay it out, and grade an assignment so no submission can damage it.

``init_course(DIR)`` makes a directory where the instructor's usual nbgrader commands work
(``nbgrader generate_assignment lab0_frames``, ``nbgrader autograde lab0_frames``, ...).
``grade_course(DIR, ASSIGNMENT)`` grades every submission in three visible stages: freeze
(:mod:`autograder.freeze`), execute untrusted code in throwaway sandboxes (nbgrader's
autograde in :mod:`autograder.scratch`, the isolated grader in :mod:`autograder.grading`),
and record from the trusted process (:mod:`autograder.record`), writing ``DIR/grades.csv``
and per-student feedback HTML.
"""

from __future__ import annotations

import html
import json
import os
import secrets
import shutil
import stat
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone
from pathlib import Path

from autograder import checks, freeze, grading, record, sandbox, scratch
from autograder.freeze import printable

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


def run_nbgrader_autograde(course_dir, assignment: str, student_id,
                           timeout_s: float = 1800, memory_mb: int = 3072,
                           cell_timeout_s: int | None = None) -> str:
    """nbgrader's autograde of one student (or a list of them), the safe way, into the
    gradebook.

    The same three stages as :func:`grade_course` for nbgrader alone: freeze the
    submissions, run ``nbgrader autograde`` in a throwaway sandboxed course per student
    (:mod:`autograder.scratch`), record the validated cell scores into ``gradebook.db``.
    Returns nbgrader's output.
    """
    root = Path(course_dir).resolve()
    wanted = [student_id] if isinstance(student_id, str) else list(student_id)
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    logs = []
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        (Path(store) / "submissions").mkdir()
        frozen = {f.student_id: f for f in freeze.freeze_submissions(
            root / "submitted", assignment, expected, Path(store) / "submissions")
            if f.accepted}
        missing = [s for s in wanted if s not in frozen]
        if missing:
            raise ValueError(f"no usable submission of {assignment!r} by {missing}")
        template = scratch.make_template(root, assignment, Path(store), _duedate(root, assignment))
        known = scratch.template_cells(template, assignment)
        for sid in wanted:
            result = scratch.autograde_one(frozen[sid], assignment, root, template, known,
                                           timeout_s=timeout_s, cell_timeout_s=cell_timeout_s,
                                           memory_mb=memory_mb)
            _record_nbgrader(root, assignment, frozen[sid], result)
            logs.append(f"--- {sid}\n{result.log}")
    return "\n".join(logs)


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


def grade_course(course_dir, assignment: str, workers: int = 1, *,
                 run_nbgrader: bool = False, nbgrader_cell_timeout_s: int | None = None,
                 nbgrader_timeout_s: float = 300,
                 limits: grading.Limits = grading.Limits(),
                 caps: freeze.Caps = freeze.Caps(),
                 nonce: str | None = None, quiet: bool = False) -> list[dict]:
    """Grade every submission of ``assignment`` in ``course_dir/submitted`` and write results.

    Three stages, so that no submission can damage or fool the grade:

    1. **freeze**: every submission is copied, as data (regular files only, capped), into
       grader-private storage before any student code runs (:mod:`autograder.freeze`);
    2. **execute untrusted**: per student, nbgrader's autograde in a throwaway sandboxed
       course (:mod:`autograder.scratch`) and the isolated grader's worker on hidden problems
       (:mod:`autograder.grading`); neither sees the course, the secret or the answer key;
    3. **record**, from this trusted process: validated numbers into ``gradebook.db``
       (backed up first, integrity-checked after, restored if damaged), then ``grades.csv``
       and the feedback pages, written atomically without following links.

    Args:
        course_dir: an nbgrader course made by :func:`init_course`.
        assignment: e.g. ``"lab0_frames"``.
        workers: submissions graded in parallel (each in its own sandbox).
        run_nbgrader: run nbgrader's autograde (stage 2) for its cell results; otherwise use
            whatever nbgrader results ``gradebook.db`` already holds, if any.
        nbgrader_cell_timeout_s: override nbgrader's per-cell timeout (config: 30 s).
        nbgrader_timeout_s: wall clock of one student's nbgrader run.
        limits: the isolated grader's per-submission limits (``deadline_s``: wall clock).
        caps: what one submission may hold (sizes, file and cell counts).
        nonce: replay a previous run's problems (its nonce is in ``.cobotlab/runs.jsonl``);
            by default a fresh one, never on disk while student code runs.
        quiet: do not print the summary.

    Returns the gradebook rows (dicts with :data:`GRADE_COLUMNS` keys, ``flags`` a
    ``;``-separated string), also written to ``course_dir/grades.csv``, one per submission
    whatever it did, with feedback in
    ``course_dir/feedback_cobotlab/<student>/<assignment>/feedback.html``.
    """
    root = Path(course_dir).resolve()
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if assignment not in checks.SPECS:
        raise ValueError(f"no graded functions are registered for assignment {assignment!r}; "
                         f"known assignments: {sorted(checks.SPECS)}")
    secret = grading.load_secret(root)
    nonce = nonce or secrets.token_hex(16)
    private = _private_dir(root)
    started = time.monotonic()
    run_notes = _begin_run(root, private)
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        # 1. freeze
        frozen = _freeze(root, assignment, Path(store), caps)
        # 2. execute untrusted code, each submission in its own throwaway world
        nb_runs, grades = _execute(root, assignment, frozen, Path(store), workers, secret,
                                   nonce, limits, run_nbgrader, nbgrader_timeout_s,
                                   nbgrader_cell_timeout_s, run_notes)
    # 3. record from the trusted side
    rows = _record(root, assignment, frozen, nb_runs, grades, private, run_notes)
    _end_run(root, private, assignment, nonce, rows, grades, nb_runs, run_notes)
    if not quiet:
        _print_summary(grades, assignment, time.monotonic() - started, workers, run_notes)
    return rows


# ----------------------------------------------------------------- stage 1: freeze


def _private_dir(root: Path) -> Path:
    private = root / grading.PRIVATE_DIR
    private.mkdir(mode=0o700, exist_ok=True)
    if not stat.S_ISDIR(os.lstat(private).st_mode):
        raise ValueError(f"{private} is not a folder (a symlink?): refusing to grade")
    return private


def _freeze(root: Path, assignment: str, store: Path, caps: freeze.Caps) -> list[freeze.Frozen]:
    submitted = root / "submitted"
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    (store / "submissions").mkdir(mode=0o700)
    frozen = (freeze.freeze_submissions(submitted, assignment, expected, store / "submissions",
                                        caps) if os.path.lexists(submitted) else [])
    if not frozen:
        raise ValueError(f"no submissions for {assignment!r} in {submitted}; collect them "
                         "first (nbgrader collect / zip_collect) or check the assignment name")
    return frozen


# ----------------------------------------------------------------- stage 2: execute


def _execute(root, assignment, frozen, store: Path, workers, secret, nonce, limits,
             run_nbgrader, nbgrader_timeout_s, nbgrader_cell_timeout_s, run_notes):
    """({student: scratch.ScratchResult}, [SubmissionGrade]) for the accepted submissions;
    a refused one gets an empty grade here (zero, with its flags)."""
    template = known = None
    if run_nbgrader:
        try:
            template = scratch.make_template(root, assignment, store,
                                             _duedate(root, assignment))
            known = scratch.template_cells(template, assignment)
        except Exception as exc:  # noqa: BLE001 - the cross-check is lost, not the grades
            run_notes.append(f"nbgrader cross-check skipped: {printable(exc, 300)}")

    def one(sub: freeze.Frozen):
        nb = None
        if sub.accepted and sub.notebooks and template is not None:
            try:
                nb = scratch.autograde_one(sub, assignment, root, template, known,
                                           timeout_s=nbgrader_timeout_s,
                                           cell_timeout_s=nbgrader_cell_timeout_s)
            except Exception as exc:  # noqa: BLE001 - a grader bug must not lose the row
                nb = scratch.ScratchResult(notes=[f"nbgrader run failed: {printable(exc)}"])
        try:
            if not sub.accepted or not sub.notebooks:
                raise _NothingToGrade()
            grade = grading.grade_notebook(sub.notebooks, assignment, sub.student_id, secret,
                                           nonce, limits)
        except _NothingToGrade:
            grade = _zero_grade(sub, assignment)
        except Exception as exc:  # noqa: BLE001 - a grader bug must not lose the row
            grade = _zero_grade(sub, assignment, ["grader_error"],
                                [f"grader error: {type(exc).__name__}: {printable(exc)}"])
        grade.flags[:0] = sub.flags
        grade.notes[:0] = sub.notes
        return sub.student_id, nb, grade

    with ThreadPoolExecutor(max_workers=workers) as pool:
        done = list(pool.map(one, frozen))
    return {sid: nb for sid, nb, _ in done if nb is not None}, [g for _, _, g in done]


class _NothingToGrade(Exception):
    pass


def _zero_grade(sub: freeze.Frozen, assignment: str, flags=(), notes=()):
    grade = grading.SubmissionGrade(sub.student_id, assignment, flags=list(flags),
                                    notes=list(notes))
    grade.functions = [checks.score_function(s, [], []) for s in checks.SPECS[assignment]]
    return grade


# ----------------------------------------------------------------- stage 3: record


def _duedate(root: Path, assignment: str):
    db = root / "gradebook.db"
    if not db.is_file():
        return None
    from nbgrader.api import Gradebook, MissingEntry

    with Gradebook(f"sqlite:///{db}") as gb:
        try:
            return gb.find_assignment(assignment).duedate
        except MissingEntry:
            return None


def _record_nbgrader(root: Path, assignment: str, sub: freeze.Frozen,
                     result: scratch.ScratchResult) -> None:
    """The validated cell scores and autograded notebooks of one scratch run, into the course
    (the notebooks for nbgrader's own next commands: generate_feedback, formgrader)."""
    present = {p.stem for p in sub.notebooks}
    record.record_nbgrader(root, assignment, sub.student_id, sub.timestamp, result.cells,
                           present)
    for name, data in result.notebooks.items():
        record.write_file(root, f"autograded/{sub.student_id}/{assignment}/{name}.ipynb", data)


def _record(root, assignment, frozen, nb_runs, grades, private, run_notes) -> list[dict]:
    damaged = None
    for sub in frozen:
        result = nb_runs.get(sub.student_id)
        if result is None:
            continue
        try:
            _record_nbgrader(root, assignment, sub, result)
        except Exception as exc:  # noqa: BLE001 - the cross-check is lost, not the grade
            result.notes.append(f"could not record nbgrader's result: {printable(exc)}")
    problem = record.gradebook_problem(root / "gradebook.db")
    backup = private / "gradebook.backup.db"
    if problem:
        damaged = f"gradebook.db failed its check after grading ({problem})"
        if backup.is_file():
            record.restore_gradebook(root, backup)
            damaged += "; restored from the copy made before this run"
        run_notes.append(damaged)

    ids = [g.student_id for g, sub in zip(grades, frozen) if sub.accepted]
    nb_results = _nbgrader_results(root, assignment, ids) if not problem else {}
    cell_map = _cell_to_function(root, assignment)
    rows = []
    for grade, sub in zip(grades, frozen):
        nb = nb_results.get(grade.student_id, {}) if sub.accepted else {}
        if sub.accepted and nb_runs.get(grade.student_id) is not None:
            grade.notes += nb_runs[grade.student_id].notes
            grade.flags += nb_runs[grade.student_id].flags
        if sub.accepted and sub.notebooks:
            _cross_check(grade, nb, cell_map)
        if damaged:
            grade.flags.append("gradebook_restored")
        penalty = nb.get("penalty", 0.0)
        who = nb.get("student", {})
        rows.append({
            "assignment": assignment, "duedate": nb.get("duedate") or "",
            "timestamp": nb.get("timestamp") or sub.timestamp, "student_id": grade.student_id,
            "last_name": who.get("last_name", ""), "first_name": who.get("first_name", ""),
            "email": who.get("email", ""), "raw_score": grade.score,
            "late_submission_penalty": penalty,
            "score": max(0.0, round(grade.score - penalty, 2)),
            "max_score": grade.max_score, "flags": ";".join(printable(f, 120)
                                                            for f in grade.flags)})
        if sub.accepted:
            try:
                record.write_file(root, f"feedback_cobotlab/{grade.student_id}/{assignment}/"
                                  "feedback.html", _feedback_html(grade).encode("utf-8"))
            except (OSError, ValueError) as exc:
                grade.notes.append(f"feedback not written: {printable(exc)}")
    record.write_csv(root, "grades.csv", GRADE_COLUMNS, rows)
    return rows


def _begin_run(root: Path, private: Path) -> list[str]:
    """Recover from an interrupted run, refuse a concurrent one, back up the gradebook."""
    notes = []
    marker = private / record.RUN_MARKER
    if marker.is_file():
        try:
            pid = int(json.loads(marker.read_text()).get("pid", 0))
        except (ValueError, AttributeError):
            pid = 0
        if pid and pid != os.getpid() and sandbox.process_alive(pid):
            raise ValueError(f"another `cobotlab grade` (pid {pid}) is grading this course; "
                             f"wait for it, or remove {marker} if it is gone")
        problem = record.gradebook_problem(root / "gradebook.db")
        backup = private / "gradebook.backup.db"
        if problem and backup.is_file():
            record.restore_gradebook(root, backup)
            notes.append(f"the previous run was interrupted and gradebook.db was damaged "
                         f"({problem}): restored from its backup")
        else:
            notes.append("the previous run was interrupted; gradebook.db checked: "
                         + (problem or "ok"))
    removed = sandbox.remove_stale_scratch()
    if removed:
        notes.append(f"removed {removed} scratch folder(s) left by an interrupted run")
    problem = record.gradebook_problem(root / "gradebook.db")
    if problem:
        raise ValueError(f"gradebook.db is damaged before grading ({problem}); restore it from "
                         f"{private / 'gradebook.backup.db'} or nbgrader's own backup first")
    record.backup_gradebook(root, private)
    record.write_file(private, record.RUN_MARKER, json.dumps(
        {"pid": os.getpid(), "started": datetime.now(timezone.utc).isoformat()}).encode())
    return notes


def _end_run(root, private, assignment, nonce, rows, grades, nb_runs, run_notes) -> None:
    # The nonce reaches the disk only now that every worker is gone (replays use it).
    runs = private / "runs.jsonl"
    previous = runs.read_bytes() if runs.is_file() and not runs.is_symlink() else b""
    entry = {"assignment": assignment, "nonce": nonce, "when":
             datetime.now(timezone.utc).isoformat(), "students": len(rows),
             "sandbox": sandbox.mode(), "notes": run_notes}
    record.write_file(private, "runs.jsonl", previous + (json.dumps(entry) + "\n").encode())
    log = ["sandbox: " + sandbox.mode(), *("  " + e for e in sandbox.capabilities().evidence),
           *run_notes, ""]
    for g in grades:
        log.append(f"{printable(g.student_id)}: " + " | ".join(printable(n) for n in g.notes))
        if g.student_id in nb_runs:
            log.append("  nbgrader: " + nb_runs[g.student_id].log[-1500:])
    record.write_file(private, "last_run.log", "\n".join(log).encode("utf-8"))
    (private / record.RUN_MARKER).unlink(missing_ok=True)


def _print_summary(grades, assignment: str, elapsed: float, workers: int, run_notes) -> None:
    mode = sandbox.mode()
    warn = "   WARNING: no sandbox, student code ran with rlimits only" \
        if mode == "rlimits only" else ""
    print(f"{assignment}: graded {len(grades)} submissions in {elapsed:.1f} s with {workers} "
          f"worker(s); sandbox: {mode}{warn}")
    for note in run_notes:
        print(f"  note: {printable(note)}")
    names = [printable(g.student_id, 60) for g in grades]
    width = max([10] + [len(n) for n in names])
    print(f"{'student':<{width}}  {'score':>11}  failed checks / flags")
    for name, g in zip(names, grades):
        failed = [f"{f.name}:{c}" for f in g.functions for c in f.failed_checks]
        text = ", ".join(failed) or "-"
        if g.flags:
            text += "   FLAGS: " + ", ".join(printable(f, 80) for f in g.flags)
        print(f"{name:<{width}}  {g.score:>5g} / {g.max_score:<3g}  {text}")
