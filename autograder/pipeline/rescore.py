"""Kept executions: what ``grade --rescore``, ``cobotlab report`` and ``cobotlab merge`` read
instead of running student code.

Each grade run keeps every execution (``.cobotlab/executions/<lab>/<hash>.json``) with the
digest of the frozen submission and of its problems' inputs; :func:`use_kept` takes one back
only when it is this submission's and ran on the inputs the lab draws now (a shard job's as
untrusted data), so a rescore scores it again without running anything.
"""

from __future__ import annotations

import json
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from autograder import (
    executions,
    freeze,
    record,
    scratch,
)
from autograder.freeze import freeze_course, printable
from autograder.pipeline.begin import GradeRun, course_and_secret
from autograder.pipeline.draw import draw
from autograder.pipeline.execute import Executed, submission_digest
from autograder.pipeline.execution import Execution
from autograder.pipeline.problems import DrawnProblems, Problems, draw_problems
from autograder.pipeline.worker import Limits
from autograder.record import read_private
from autograder.secret import PRIVATE_DIR

KEPT = "executions"


def kept_path(assignment: str, student_id: str) -> str:
    """Where, below the course's private folder, a student's kept execution is."""
    return f"{KEPT}/{assignment}/{executions.file_key(student_id)}.json"


def keep(run: GradeRun, student_id: str, done: Executed) -> None:
    """Keep what a submission's code did, for ``rescore``: its execution, the problems'
    inputs digest and nonce it ran on, nbgrader's flags and notes of that run, and the
    digest of the frozen submission it belongs to."""
    record.write_file(run.private, kept_path(run.assignment, student_id),
                      kept_bytes(run, done))


def kept_bytes(run: GradeRun, done: Executed) -> bytes:
    """The kept form of ``done`` (see :func:`keep`): an execution and the problems it ran
    on."""
    ex, problems = done.execution, done.problems
    kept = {"format": executions.FORMAT, "student_id": problems.student_id,
            "assignment": run.assignment, "nonce": run.nonce, "submission": done.submission,
            "inputs": executions.inputs_digest(problems, ex.kernel_runs),
            "execution": executions.to_wire(ex), "grader_errors": done.grader_errors,
            "nbgrader": None if done.nbgrader is None else {
                "flags": list(done.nbgrader.flags), "notes": list(done.nbgrader.notes)}}
    return json.dumps(kept).encode("utf-8")


def kept_executions(run: GradeRun, frozen, problems: DrawnProblems,
                     progress=None) -> dict[str, Executed]:
    """Stage 4 without running anything: each usable submission's execution as the last
    grade run kept it, checked to be this submission's and to have run on the problems'
    inputs as the lab draws them now. Refuses (ValueError), naming every submission that
    cannot be rescored and why."""
    out: dict[str, Executed] = {}
    refused: list[str] = []
    if progress is not None:
        progress(0, len(frozen), "")
    for i, sub in enumerate(frozen, 1):
        done = Executed(submission=submission_digest(sub))
        out[sub.student_id] = done
        if sub.accepted and sub.notebooks:
            why = _load_kept(run, problems, sub, done)
            if why:
                refused.append(f"{printable(sub.student_id, 80)} ({why})")
        if progress is not None:
            progress(i, len(frozen), sub.student_id)
    if refused:
        raise ValueError(
            f"cannot rescore {run.assignment} without running student code: "
            + "; ".join(refused[:20]) + (f"; and {len(refused) - 20} more" if len(refused) > 20
                                         else "")
            + ". Grade them with `cobotlab grade` (`--students` picks them), or grade the "
            "whole class again")
    return out


def _load_kept(run: GradeRun, problems: DrawnProblems, sub: freeze.Frozen,
               done: Executed) -> str | None:
    """Fill ``done`` from the kept execution of ``sub``; None, or why it cannot be used."""
    data = read_private(run.private, kept_path(run.assignment, sub.student_id))
    if data is None:
        return "no execution kept: never graded by this version of cobotlab, or not graded"
    return use_kept(run, problems, sub, done, data)


def use_kept(run: GradeRun, problems: DrawnProblems, sub: freeze.Frozen,
             done: Executed, data: bytes, from_job: bool = False) -> str | None:
    """Fill ``done`` from ``data``, a kept execution of ``sub`` (untrusted bytes: this
    course's, or a shard job's with ``from_job``, whose nbgrader findings are its word and
    are dropped); None, or why it cannot be used: another format or submission, another
    nonce than a job runs on, problems whose inputs are not those drawn here, or not one
    outcome per problem."""
    try:
        kept = json.loads(data)
        if not isinstance(kept, dict):
            return "its kept execution is not an object"
        if kept.get("format") != executions.FORMAT:
            return executions.older_format(kept.get("format"))
        if kept.get("submission") != done.submission:
            return "submitted again since it was graded"
        nonce = kept.get("nonce")
        if nonce is not None and not (isinstance(nonce, str)
                                      and re.fullmatch(r"[0-9a-f]{16,64}", nonce)):
            return "its kept execution names no valid nonce"
        execution = executions.from_wire(kept.get("execution"), run.assignment,
                                         sub.student_id, {Path(p).name for p in sub.notebooks})
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        return f"its kept execution is unreadable: {printable(exc, 200)}"
    if from_job and nonce is not None:
        return "a shard job runs the course's fixed problems, and this one names a nonce"
    mine = problems.of(sub.student_id) if nonce == run.nonce else draw_problems(
        run.assignment, sub.student_id, run.secret, nonce, problems.kernel)
    now = executions.inputs_digest(mine, execution.kernel_runs)
    before = kept.get("inputs") if isinstance(kept.get("inputs"), dict) else {}
    changed = sorted({name.removeprefix("kernel:") for name, digest in now.items()
                      if before.get(name) != digest})
    if changed:
        return ("the lab's change altered the problems' inputs of " + ", ".join(changed)
                + ": the code must run on the new ones")
    uneven = _uneven_counts(mine, execution)
    if uneven:
        return f"not one outcome per problem of {', '.join(uneven)}"
    done.problems, done.execution = mine, execution
    errors = kept.get("grader_errors")
    done.grader_errors = [printable(e, 400) for e in errors[:8]] if isinstance(errors, list) \
        else []
    nb = kept.get("nbgrader")
    if isinstance(nb, dict) and not from_job:
        done.nbgrader = scratch.ScratchResult(
            flags=[printable(f, 200) for f in nb.get("flags", [])[:64]],
            notes=[printable(n, 1000) for n in nb.get("notes", [])[:64]])
    return None


def _uneven_counts(problems: Problems, execution: Execution) -> list[str]:
    """The functions of ``execution`` whose outcomes are not one per problem (hidden, or
    the kernel seeds' of a ``hidden_test``); a function stopped as forbidden scores zero
    whatever it has."""
    uneven = [r.name for r in execution.functions if not r.forbidden
              and len(r.outcomes) != len(problems.trials[r.name])]
    return uneven + [f"hidden_test({name})" for name, r in execution.kernel_runs.items()
                     if not r.forbidden and len(r.outcomes) != len(problems.kernel_trials(name))]


@dataclass
class KeptSubmission:
    """One submission as the last grade run left it, for a report: its problems and the
    execution kept for it (None, and ``why`` says why, when there is none to use), and the
    text of its frozen notebooks by file name (data only; nothing of it ran here)."""

    problems: Problems | None
    execution: Execution | None
    notebooks: dict[str, str]
    why: str | None = None


def kept_submissions(course_dir, assignment: str) -> dict[str, KeptSubmission]:
    """{student: :class:`KeptSubmission`} of every submission of ``assignment`` in
    ``course_dir/submitted``, frozen as a grade run freezes them and matched with the
    executions the last grade run kept, as ``grade --rescore`` reads them (the same checks:
    this submission's, run on the problems' inputs as the lab draws them now). Reads only:
    no student code runs, nothing is recorded. Score one with
    :func:`autograder.pipeline.score.score_execution`."""
    root, secret = course_and_secret(course_dir, assignment)
    run = GradeRun(root, root / PRIVATE_DIR, assignment, secret, None, "report",
                   Limits(), [], time.monotonic())
    out: dict[str, KeptSubmission] = {}
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        frozen = freeze_course(root, assignment, Path(store), freeze.Caps())
        problems = draw(run, frozen)
        for sub in frozen:
            texts = {Path(p).name: Path(p).read_text(encoding="utf-8", errors="replace")
                     for p in sub.notebooks}
            if not (sub.accepted and sub.notebooks):
                out[sub.student_id] = KeptSubmission(None, None, texts, "refused, or no "
                                                     "notebook: it scored zero")
                continue
            done = Executed(submission=submission_digest(sub))
            why = _load_kept(run, problems, sub, done)
            out[sub.student_id] = KeptSubmission(
                done.problems if why is None else None, done.execution, texts, why)
    return out


def keep_all(run: GradeRun, frozen, executed: dict[str, Executed]) -> None:
    """Keep each execution of the run for ``rescore``; a failure to is in the run's notes."""
    for sub in frozen:
        done = executed[sub.student_id]
        if done.execution is None:
            continue
        try:
            keep(run, sub.student_id, done)
        except (OSError, ValueError) as exc:
            note = f"executions not kept (no rescore for them): {printable(exc, 200)}"
            if note not in run.notes:
                run.notes.append(note)
