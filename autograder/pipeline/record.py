"""Stage 6 of the grader's line, record: the grades into the course, from this process.

Validated numbers into ``gradebook.db`` (backed up first, integrity-checked after, restored if
damaged; the ledger of nbgrader's own cell values), the comments formgrader shows,
``grades.csv``, the feedback pages, and at the end the run's line in ``runs.jsonl``, its log
and the console summary; every file written atomically without following links
(:mod:`autograder.record`). Record reads the grades it is given and returns its own copies.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from datetime import datetime, timezone
from pathlib import Path

from autograder import (
    checks,
    feedback,
    freeze,
    gradebook,
    record,
    registry,
    sandbox,
    scratch,
)
from autograder.feedback_release import (
    Comment,
    unreleasable_note,
    write_exchange_files,
    write_section,
)
from autograder.freeze import printable
from autograder.grade_options import GradeOptions
from autograder.outcomes import about_function, instructor_words
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.execute import Executed
from autograder.pipeline.nbgrader_results import LEDGER, cell_to_function, load_ledger, source_cells
from autograder.pipeline.score import SubmissionGrade
from autograder.record import read_private

GRADE_COLUMNS = ["assignment", "duedate", "timestamp", "student_id", "last_name", "first_name",
                 "email", "raw_score", "late_submission_penalty", "score", "max_score", "flags"]


GRADES_CSV = "grades.csv"




def _solution_cells(root: Path, assignment: str) -> dict[str, str]:
    """graded function name -> grade_id of the solution cell that defines it (where
    formgrader shows a comment box)."""
    mapping = {}
    for role, source in source_cells(root, assignment):
        grade_id = role.grade_id
        if not role.solution:
            continue
        for spec in checks.SPECS.get(assignment, ()):
            if grade_id == spec.name or (spec.name not in mapping and re.search(
                    rf"^def {re.escape(spec.name)}\s*\(", source, re.MULTILINE)):
                mapping[spec.name] = grade_id
    return mapping


def record_nbgrader(root: Path, assignment: str, sub: freeze.Frozen,
                     result: scratch.ScratchResult) -> None:
    """The validated cell scores and autograded notebooks of one scratch run, into the course
    (the notebooks for nbgrader's own next commands: generate_feedback, formgrader)."""
    present = {p.stem for p in sub.notebooks}
    gradebook.write_nbgrader_cells(root, assignment, sub.student_id, sub.timestamp,
                                   result.cells, present)
    write_autograded(root, assignment, sub, result)


def write_autograded(root: Path, assignment: str, sub: freeze.Frozen,
                      result: scratch.ScratchResult) -> None:
    for name, data in result.notebooks.items():
        record.write_file(root, f"autograded/{sub.student_id}/{assignment}/{name}.ipynb", data)
    if result.notebooks:   # what nbgrader's release_feedback reads beside them
        write_exchange_files(root, assignment, sub)


def record_grades(run: GradeRun, frozen, executed: dict[str, Executed],
            scored) -> tuple[list[dict], list[SubmissionGrade]]:
    """(the grades.csv rows, the grades as recorded): ``scored`` written into the course.
    What recording adds (a restored gradebook's flag, notes of what could not be written)
    goes on copies; ``scored`` is read, never changed. nbgrader's own cell results, for the
    comments and the ledger, are those each ``Executed`` carries."""
    root, assignment, private, run_notes = run.root, run.assignment, run.private, run.notes
    run_nbgrader = run.options.run_nbgrader
    grades = [dataclasses.replace(g, flags=list(g.flags), notes=list(g.notes)) for g in scored]
    unreleasable = unreleasable_note(assignment, frozen)
    if unreleasable and run_nbgrader:
        run_notes.append(unreleasable)
    ungraded = [g.student_id for g in grades if not g.graded]
    if ungraded:
        run_notes.append(f"not graded, the grader failed on every attempt (no score recorded; "
                         f"the next run grades them again): {', '.join(ungraded)}")
    _record_nbgrader_runs(run, frozen, executed, grades)
    damaged = _check_gradebook(root, private, run_notes)

    # A submission the grader could not grade gets nothing in the gradebook, not a zero.
    accepted = [(g, sub) for g, sub in zip(grades, frozen) if sub.accepted and g.graded]
    comments = {}
    if not damaged:
        nb_own = {sid: d.nbgrader_cells.scores for sid, d in executed.items()
                  if d.nbgrader_cells is not None}
        comments = _record_cobotlab(root, private, assignment, accepted, nb_own,
                                    cell_to_function(root, assignment), load_ledger(private),
                                    run_notes)
        _withdraw_ungraded(root, assignment, grades, frozen, run_notes)
        damaged = _check_gradebook(root, private, run_notes)
    # names, timestamps and late penalties as the gradebook has them now, our scores in it
    nb_results = {} if damaged else gradebook.results(
        root, assignment, [g.student_id for g, _ in accepted])

    rows = []
    for grade, sub in zip(grades, frozen):
        nb = nb_results.get(grade.student_id, {}) if sub.accepted else {}
        if damaged:
            grade.flags.append("gradebook_restored")
        rows.append(grade_row(assignment, grade.student_id, nb,
                              grade.score if grade.graded else None, grade.max_score,
                              ";".join(printable(f, 120) for f in grade.flags),
                              sub.timestamp))
        if sub.accepted and grade.graded:
            try:
                record.write_file(root, f"feedback_cobotlab/{grade.student_id}/{assignment}/"
                                  "feedback.html", feedback.feedback_html(grade).encode("utf-8"))
                write_section(root, assignment, grade, sub.timestamp,
                              comments.get(grade.student_id, {}))
            except (OSError, ValueError) as exc:
                grade.notes.append(f"feedback not written: {printable(exc)}")
    # every assignment graded so far, one row per student and assignment (this run's replace)
    record.update_csv(root, GRADES_CSV, GRADE_COLUMNS, rows, key=("assignment", "student_id"))
    return rows, grades


def _record_nbgrader_runs(run: GradeRun, frozen, executed: dict[str, Executed],
                          grades) -> dict[str, scratch.ScratchResult]:
    """{student: nbgrader's run} of this run's submissions (none in a rescore), each
    written into the course; a failure to is noted on the (record's own) grade."""
    by_student = {g.student_id: g for g in grades}
    nb_runs = {sid: d.nbgrader for sid, d in executed.items()
               if d.nbgrader is not None and run.problems != "rescore"}
    for sub in frozen:
        result = nb_runs.get(sub.student_id)
        if result is None:
            continue
        try:
            record_nbgrader(run.root, run.assignment, sub, result)
        except Exception as exc:  # noqa: BLE001 - the cross-check is lost, not the grade
            by_student[sub.student_id].notes.append(
                f"could not record nbgrader's result: {printable(exc)}")
    return nb_runs


def _withdraw_ungraded(root: Path, assignment: str, grades, frozen, run_notes) -> None:
    """No score in gradebook.db for a submission the grader failed on: grades.csv leaves
    its score empty, and nbgrader's export and formgrader must not show one that cobotlab
    did not give (an earlier trusting ``nbgrader autograde``'s, say)."""
    for grade, sub in zip(grades, frozen):
        if grade.graded or not sub.accepted:
            continue
        try:
            emptied = gradebook.withdraw_scores(
                root, assignment, grade.student_id,
                "cobotlab: not graded (the grader failed on every attempt); no score is "
                "recorded, and the next `cobotlab grade` grades it again.")
        except Exception as exc:  # noqa: BLE001 - said in the run notes, the row stays empty
            run_notes.append(f"could not empty the gradebook's scores of "
                             f"{printable(grade.student_id)}: {printable(exc, 200)}")
            continue
        if emptied:
            grade.notes.append(f"{emptied} automatic score(s) in gradebook.db emptied: "
                               "cobotlab did not give them")


def grade_row(assignment: str, student_id: str, nb: dict, raw_score: float | None,
              max_score: float, flags: str, timestamp="") -> dict:
    """One grades.csv row (:data:`GRADE_COLUMNS`): the score cobotlab gave, with the names,
    due date, timestamp and late penalty as the gradebook has them now (``nb``: an entry of
    :func:`autograder.gradebook.results`; the score less the penalty, never below 0). ``raw_score`` None:
    not graded (the grader failed), so the score columns stay empty."""
    penalty = float(nb.get("penalty", 0.0))
    if raw_score is None:
        return {**grade_row(assignment, student_id, nb, 0.0, max_score, flags, timestamp),
                "raw_score": "", "late_submission_penalty": "", "score": ""}
    who = nb.get("student", {})
    return {"assignment": assignment, "duedate": nb.get("duedate") or "",
            "timestamp": nb.get("timestamp") or timestamp, "student_id": student_id,
            "last_name": who.get("last_name", ""), "first_name": who.get("first_name", ""),
            "email": who.get("email", ""), "raw_score": raw_score,
            "late_submission_penalty": penalty,
            "score": gradebook.net_score(raw_score, penalty),
            "max_score": max_score, "flags": flags}


def _check_gradebook(root: Path, private: Path, run_notes: list[str]) -> str | None:
    """None if gradebook.db passes its check; else restore the copy made before this run and
    say so (in ``run_notes`` too)."""
    problem = gradebook.problem(root / "gradebook.db")
    if not problem:
        return None
    damaged = f"gradebook.db failed its check after grading ({problem})"
    backup = private / "gradebook.backup.db"
    if backup.is_file():
        gradebook.restore(root, backup)
        damaged += "; restored from the copy made before this run"
    run_notes.append(damaged)
    return damaged


def _record_cobotlab(root, private, assignment, accepted, nb_own, cell_map, ledger,
                     run_notes) -> dict[str, dict[str, Comment]]:
    """Each function's score into its autograder cell(s) of gradebook.db, the findings
    into the comment of the solution cell that defines it; nbgrader's own values into the
    ledger for the next run's cross-check. Returns {student: {grade id: comment}} of the
    comments written (their section tells nbgrader's feedback which lines to show)."""
    solution_of = _solution_cells(root, assignment)
    mapped = set(cell_map.values())
    unmapped = [s.name for s in checks.SPECS[assignment] if s.name not in mapped]
    if unmapped:
        run_notes.append(f"no autograder cell in the source notebook for {unmapped}: their "
                         "scores are in grades.csv only")
    mine, written_comments = ledger.setdefault(assignment, {}), {}
    for grade, sub in accepted:
        by_function = {f.name: f for f in grade.functions}
        fractions = {gid: by_function[name].fraction for gid, name in cell_map.items()
                     if name in by_function}
        theirs = nb_own.get(grade.student_id, {})
        comments = {solution_of[f.name]: _comment(grade, f, i == 0, [
            theirs[g] for g, name in cell_map.items() if name == f.name and g in theirs])
            for i, f in enumerate(grade.functions) if f.name in solution_of}
        try:
            written = gradebook.write_cobotlab(root, assignment, grade.student_id,
                                               sub.timestamp, fractions,
                                               {gid: c.text for gid, c in comments.items()})
        except Exception as exc:  # noqa: BLE001 - grades.csv still gets the score
            note = f"cobotlab's scores not written to gradebook.db: {printable(exc, 200)}"
            if note not in run_notes:
                run_notes.append(note)
            continue
        written_comments[grade.student_id] = comments
        mine[grade.student_id] = {"timestamp": sub.timestamp, "cells": {
            gid: [score, theirs[gid][0] if gid in theirs else None]
            for gid, (_, score) in written.items()}}
    record.write_file(private, LEDGER, json.dumps(ledger).encode("utf-8"))
    return written_comments


def _comment(grade: SubmissionGrade, f: checks.FunctionResult, first: bool,
             nbgrader_cells: list[tuple[float, float]]) -> Comment:
    """The auto comment formgrader shows under the function's solution cell: the score and
    failed checks, which nbgrader's feedback shows the student too (no test code or data in
    them), then nbgrader's cross-check and the flags, for the instructor only."""
    student = [f"cobotlab: {f.points:g} / {f.max_points:g} points on {f.n_problems} hidden "
               "problems" + (f", {f.n_failed} not fully right" if f.n_failed else "") + "."]
    if f.failed_checks:
        student.append("Failed checks: " + ", ".join(f.failed_checks) + ".")
    instructor = []
    if nbgrader_cells:
        instructor.append("nbgrader's own hidden-test cell: " + ", ".join(
            f"{s:g} / {m:g}" for s, m in nbgrader_cells) + " (cross-check; the score above "
            "is the grade).")
    own = [x for x in grade.flags if about_function(x) == f.name]
    whole = [x for x in grade.flags if about_function(x) is None]
    if own:
        instructor.append("Flags: " + "; ".join(printable(x, 120) for x in own) + ".")
    if first and whole:
        instructor.append("Flags on the whole submission: "
                          + "; ".join(printable(x, 120) for x in whole) + ".")
    return Comment(tuple(student), tuple(instructor))


def end_run(run: GradeRun, rows, grades, executed: dict[str, Executed]) -> None:
    """The run's line in runs.jsonl and its log (last_run.log); the run is over."""
    private = run.private
    # A fresh run's nonce reaches the disk only now that every worker is gone (replays use it).
    previous = read_private(private, "runs.jsonl") or b""
    entry = {"assignment": run.assignment, "problems": run.problems, "nonce": run.nonce,
             "when": datetime.now(timezone.utc).isoformat(), "students": len(rows),
             "spec_hash": registry.spec_hash(run.assignment),
             "sandbox": sandbox.mode(), "notes": run.notes}
    record.write_file(private, "runs.jsonl", previous + (json.dumps(entry) + "\n").encode())
    log = ["sandbox: " + sandbox.mode(), *("  " + e for e in sandbox.capabilities().evidence),
           *run.notes, ""]
    for g in grades:
        log.append(f"{printable(g.student_id, 2000)}: "
                   + " | ".join(printable(instructor_words(n)) for n in g.notes))
        nb = executed[g.student_id].nbgrader if g.student_id in executed else None
        if nb is not None and nb.log:
            log.append("  nbgrader: " + nb.log[-1500:])
    record.write_file(private, "last_run.log", "\n".join(log).encode("utf-8"))
    (private / record.RUN_MARKER).unlink(missing_ok=True)


def print_summary(grades, assignment: str, elapsed: float, run_notes,
                   executed: dict[str, Executed], options: GradeOptions) -> None:
    workers = options.workers
    if options.rescore:
        print(f"{assignment}: rescored {len(grades)} submissions in {elapsed:.1f} s from the "
              "executions the last grade run kept (no student code ran)")
    else:
        mode = sandbox.mode()
        warn = "   WARNING: no sandbox, student code ran with rlimits only" \
            if mode == "rlimits only" else ""
        # elapsed is the whole run (freeze, nbgrader's template and autograde, the grader,
        # recording); the shares are summed over submissions, so with workers they overlap.
        nb_s = sum(d.nbgrader.seconds for d in executed.values() if d.nbgrader is not None)
        ours = sum(getattr(g, "seconds", 0.0) for g in grades)
        print(f"{assignment}: graded {len(grades)} submissions in {elapsed:.1f} s wall clock "
              f"with {workers} worker(s) (nbgrader's autograde {nb_s:.1f} s + isolated grader "
              f"{ours:.1f} s, summed over submissions); sandbox: {mode}{warn}")
    for note in run_notes:
        print(f"  note: {printable(note)}")
    # a long id is cut to fit the column, with a short hash of the whole so that two ids
    # alike in their first characters (refused ones may run to 1000) still differ here
    names = [printable(g.student_id) if len(g.student_id) <= 60 else
             printable(g.student_id, 48) + "#"
             + hashlib.sha256(g.student_id.encode("utf-8", "backslashreplace")).hexdigest()[:8]
             for g in grades]
    width = max([10] + [len(n) for n in names])
    print(f"{'student':<{width}}  {'score':>11}  failed checks / flags")
    for name, g in zip(names, grades):
        failed = [f"{f.name}:{c}" for f in g.functions for c in f.failed_checks]
        text = ", ".join(failed) or "-"
        if g.flags:
            text += "   FLAGS: " + ", ".join(printable(f, 80) for f in g.flags)
        score = f"{g.score:>5g} / {g.max_score:<3g}" if g.graded else f"{'NOT GRADED':>11}"
        print(f"{name:<{width}}  {score}  {text if g.graded else instructor_words(g.notes[-1])}")
    ungraded = [n for n, g in zip(names, grades) if not g.graded]
    if ungraded:
        print(f"NOT GRADED ({len(ungraded)}): {', '.join(ungraded)}: the grader failed on every "
              "attempt (see .cobotlab/last_run.log); no score was recorded for them, and the "
              "next `cobotlab grade` grades them again")
