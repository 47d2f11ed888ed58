"""An :class:`~autograder.pipeline.execution.Execution` as data: one wire form for the cluster's replies
and for the executions a grade run keeps (``cobotlab grade --rescore``).

The form is :mod:`autograder.inside.wire`'s JSON (arrays as raw little-endian bytes: a value read
back is the value the worker sent, bit for bit, so a rescore scores exactly what the grade
run scored). Reading one back validates everything: the functions are the lab's, in order,
every string is capped, every count and time is a bounded number, every value passes
:func:`autograder.inside.wire.decode`, a failure's place is ``[cell, line]`` within
:class:`~autograder.outcomes.Place`'s bounds. What fails is refused
(:class:`ExecutionRefused`), never half-read. A failure's place and a note's travel typed
only, never in their words. An execution kept in an older :data:`FORMAT` (format 1 wrote
a failure's place into its message too, and notes held theirs in words only) is refused,
with a message saying to run the student code again (``cobotlab grade`` without
``--rescore``): its words are not parsed back into a place.

The problems' inputs travel the same way (:func:`problems_to_wire`): a cluster task carries
them instead of the secret. A function graded in one call gets its inputs only; a closed
loop also gets what its ``drive`` flies by (the start and the targets), since the loop runs
where the student's code runs.
"""

from __future__ import annotations

import hashlib
import json
import math

from autograder import checks
from autograder.freeze import printable
from autograder.inside import wire
from autograder.outcomes import (
    Cause,
    Failed,
    Failure,
    Note,
    Place,
    TrialOutcome,
    note_place,
    student_words,
)
from autograder.pipeline.cells import CellOrigin
from autograder.pipeline.execution import CellRun, Execution, FunctionRun
from autograder.pipeline.problems import KernelTrials, Problems

__all__ = ["FORMAT", "ExecutionRefused", "older_format", "file_key", "to_wire", "from_wire",
           "problems_to_wire", "problems_from_wire", "inputs_digest"]

# 2: a failure's place is only typed (format 1 also wrote it into the error's words, which
# a renderer would now write in a second time) and notes carry their place.
FORMAT = 2


def older_format(found) -> str:
    """Why an execution kept in format ``found`` is not read, and what to do instead. One
    of format 1 holds its places in its messages' words, which are not parsed back into a
    place; any other was kept by another version of cobotlab."""
    why = ("by an older cobotlab, which wrote a failure's place into its message" if found == 1
           else "by another version of cobotlab")
    return (f"an execution kept in format {printable(found, 20)}, not {FORMAT} ({why}); run "
            "the student code again with this cobotlab: `cobotlab grade` without --rescore "
            "(with --replay <nonce> for a `cobotlab grade --fresh` run's problems), or the "
            "shard job again")


class ExecutionRefused(ValueError):
    """An encoded execution (or problem set) failed validation: nothing of it is used."""


def file_key(student_id: str) -> str:
    """The name (without extension) of a student's file of executions or problems: a hash,
    so that no student id, however it is spelt, becomes a path."""
    return hashlib.sha256(student_id.encode("utf-8", "backslashreplace")).hexdigest()[:40]


# --------------------------------------------------------------------------- checked reading


def _text(value, limit: int, what: str) -> str:
    if not isinstance(value, str):
        raise ExecutionRefused(f"{what} is not a string")
    return value[:limit]


def _count(value, what: str, top: int = 10**6) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
        raise ExecutionRefused(f"{what} is not a count within 0..{top}")
    return value


def _number(value, what: str, low=0.0, high=86400.0 * 7) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ExecutionRefused(f"{what} is not a number")
    try:
        value = float(value)
    except OverflowError:
        raise ExecutionRefused(f"{what} is an integer too large for a float") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ExecutionRefused(f"{what} = {value!r} is outside {low:g}..{high:g}")
    return value


def _items(value, top: int, what: str) -> list:
    if not isinstance(value, list) or len(value) > top:
        raise ExecutionRefused(f"{what} is not a list of at most {top}")
    return value


def _mapping(value, what: str) -> dict:
    if not isinstance(value, dict):
        raise ExecutionRefused(f"{what} is not an object")
    return value


# --------------------------------------------------------------------------- outcomes


def _failure_to_wire(failure: Failure | None):
    if failure is None:
        return None
    return {"kind": failure.kind.value, "exception": failure.exception,
            "cause": failure.cause.value if failure.cause is not None else None,
            "limit_s": failure.limit_s,
            "place": None if failure.place is None else failure.place.to_wire()}


def _failure_from_wire(data, what: str) -> Failure | None:
    if data is None:
        return None
    data = _mapping(data, what)
    try:
        kind = Failed(data.get("kind"))
        cause = None if data.get("cause") is None else Cause(data.get("cause"))
    except ValueError:
        raise ExecutionRefused(f"{what} is no kind of failure the grader knows") from None
    limit = data.get("limit_s")
    return Failure(kind, exception=_text(data.get("exception"), 80, f"{what}.exception"),
                   cause=cause,
                   limit_s=None if limit is None else _number(limit, f"{what}.limit_s"),
                   place=_place(data, what))


def _place(data: dict, what: str) -> Place | None:
    """A failure's, a cell run's or a note's ``place``: null, or ``[cell, line]`` of
    non-negative integers within :class:`Place`'s bounds (``line`` null: the whole cell).
    One without a ``place`` was kept by a cobotlab that wrote the place as words, which
    are not read back: it is refused."""
    if "place" not in data:
        raise ExecutionRefused(
            f"{what} has no place (kept by an older cobotlab, which wrote it as words); "
            "run the lab's student code again: `cobotlab grade` without --rescore (with "
            "--replay <nonce> for a `cobotlab grade --fresh` run's problems)")
    value = data["place"]
    if value is None:
        return None
    value = _items(value, 2, f"{what}.place")
    if len(value) != 2:
        raise ExecutionRefused(f"{what}.place is not [cell, line]")
    cell = _count(value[0], f"{what}.place.cell")
    line = None if value[1] is None else _count(value[1], f"{what}.place.line")
    try:
        return Place(cell, line)
    except ValueError as exc:   # a count, but out of Place's bounds
        raise ExecutionRefused(f"{what}.place: {exc}") from None


def _outcome_to_wire(outcome: TrialOutcome) -> dict:
    return {"value": wire.encode(outcome.value), "error": outcome.error,
            "seconds": outcome.seconds, "cpu_seconds": outcome.cpu_seconds,
            "failure": _failure_to_wire(outcome.failure)}


def _outcome_from_wire(data, what: str) -> TrialOutcome:
    data = _mapping(data, what)
    error = data.get("error")
    try:
        value = wire.decode(data.get("value"))
    except (wire.WireError, ValueError, TypeError, RecursionError) as exc:
        raise ExecutionRefused(f"{what}.value: {printable(exc, 200)}") from None
    return TrialOutcome(
        value=value, error=None if error is None else _text(error, 1000, f"{what}.error"),
        seconds=_number(data.get("seconds"), f"{what}.seconds"),
        cpu_seconds=_number(data.get("cpu_seconds"), f"{what}.cpu_seconds"),
        failure=_failure_from_wire(data.get("failure"), f"{what}.failure"))


def _run_to_wire(run: FunctionRun) -> dict:
    return {"name": run.name, "outcomes": [_outcome_to_wire(o) for o in run.outcomes],
            "forbidden": list(run.forbidden)}


def _run_from_wire(data, name: str, top: int, what: str) -> FunctionRun:
    data = _mapping(data, what)
    if data.get("name") != name:
        raise ExecutionRefused(f"{what} is not {name}'s")
    outcomes = [_outcome_from_wire(o, f"{what}.outcomes")
                for o in _items(data.get("outcomes"), top, f"{what}.outcomes")]
    forbidden = tuple(_text(n, 80, f"{what}.forbidden")
                      for n in _items(data.get("forbidden"), 16, f"{what}.forbidden"))
    return FunctionRun(name, outcomes, forbidden)


# --------------------------------------------------------------------------- executions


def to_wire(execution: Execution) -> dict:
    """``execution`` as JSON-ready data (see the module docstring)."""
    return {
        "format": FORMAT, "student_id": execution.student_id,
        "assignment": execution.assignment,
        "functions": [_run_to_wire(r) for r in execution.functions],
        "kernel_tests": list(execution.kernel_tests),
        "kernel_runs": {name: _run_to_wire(r) for name, r in execution.kernel_runs.items()},
        "suspicious": list(execution.suspicious), "sandbox_flags": list(execution.sandbox_flags),
        "notes": [_note_to_wire(n) for n in execution.notes],
        "cell_origins": [[o.notebook, o.position, o.prompt] for o in execution.cell_origins],
        "cell_runs": [_cell_run_to_wire(r) for r in execution.cell_runs],
        "seconds": execution.seconds,
        "profile": {k: v for k, v in execution.profile.items()},
    }


def _note_to_wire(note) -> list:
    place = note_place(note)
    return [str(note), student_words(note), None if place is None else place.to_wire()]


def _note(data) -> Note:
    """A kept note: ``[text, what a student reads or null, place or null]``."""
    data = _items(data, 3, "notes")
    if len(data) != 3:
        raise ExecutionRefused("a note is not [text, what a student reads, place]")
    shown = None if data[1] is None else _text(data[1], 1000, "notes")
    return Note(_text(data[0], 1000, "notes"), for_student=shown,
                place=_place({"place": data[2]}, "notes"))


def _origin(data, notebooks, what: str) -> CellOrigin:
    data = _items(data, 3, what)
    if len(data) != 3 or not isinstance(data[0], str) or (
            notebooks is not None and data[0] not in notebooks):
        raise ExecutionRefused(f"{what} does not name a cell of the submission's notebooks")
    return CellOrigin(data[0][:200], _count(data[1], f"{what}.position"),
                      _count(data[2], f"{what}.prompt"))


def _cell_run_to_wire(run: CellRun) -> dict:
    return {"origin": [run.origin.notebook, run.origin.position, run.origin.prompt],
            "error": run.error, "stdout": run.stdout, "stderr": run.stderr,
            "timed_out": run.timed_out, "exception": run.exception, "message": run.message,
            "place": None if run.place is None else run.place.to_wire()}


def _cell_run_from_wire(data, notebooks) -> CellRun:
    """A kept :class:`CellRun`. One kept before cell runs carried their exception typed (a
    ``where`` in words, no ``exception``) is refused, as a failure without a place is."""
    data = _mapping(data, "cell_runs")
    timed_out = data.get("timed_out")
    if not isinstance(timed_out, bool):
        raise ExecutionRefused("cell_runs.timed_out is not true or false")
    if "exception" not in data or "message" not in data:
        raise ExecutionRefused(
            "cell_runs has no exception (kept by an older cobotlab, which wrote it as "
            "words); run the lab's student code again: `cobotlab grade` without --rescore")
    return CellRun(_origin(data.get("origin"), notebooks, "cell_runs.origin"),
                   _text(data.get("error"), 400, "cell_runs.error"),
                   _text(data.get("stdout"), 4096, "cell_runs.stdout"),
                   _text(data.get("stderr"), 4096, "cell_runs.stderr"), timed_out,
                   exception=_text(data.get("exception"), 80, "cell_runs.exception"),
                   message=_text(data.get("message"), 400, "cell_runs.message"),
                   place=_place(data, "cell_runs"))


def from_wire(data, assignment: str, student_id: str, notebooks=None) -> Execution:
    """The :class:`Execution` that ``data`` describes, or :class:`ExecutionRefused`.
    ``notebooks``: the names of the submission's notebooks, when known."""
    data = _mapping(data, "the execution")
    if data.get("format") != FORMAT:
        raise ExecutionRefused(older_format(data.get("format")))
    if data.get("student_id") != student_id or data.get("assignment") != assignment:
        raise ExecutionRefused("the execution is another submission's")
    specs = checks.SPECS[assignment]
    runs = _items(data.get("functions"), len(specs), "functions")
    if len(runs) != len(specs):
        raise ExecutionRefused(f"{len(runs)} functions run, this lab has {len(specs)}")
    top = max([s.n_trials for s in specs] + [64])
    ex = Execution(student_id=student_id, assignment=assignment)
    ex.functions = [_run_from_wire(r, s.name, s.n_trials, f"functions.{s.name}")
                    for r, s in zip(runs, specs)]
    names = {s.name for s in specs}
    ex.kernel_tests = [_text(n, 80, "kernel_tests")
                       for n in _items(data.get("kernel_tests"), 64, "kernel_tests")]
    kernel = _mapping(data.get("kernel_runs"), "kernel_runs")
    if not set(kernel) <= set(ex.kernel_tests) & names:
        raise ExecutionRefused("kernel_runs names a function no test cell called")
    ex.kernel_runs = {name: _run_from_wire(r, name, top, f"kernel_runs.{name}")
                      for name, r in kernel.items()}
    ex.suspicious = [_text(f, 200, "suspicious") for f in _items(data.get("suspicious"), 64,
                                                                 "suspicious")]
    ex.sandbox_flags = [_text(f, 200, "sandbox_flags")
                        for f in _items(data.get("sandbox_flags"), 8, "sandbox_flags")]
    ex.notes = [_note(n) for n in _items(data.get("notes"), 256, "notes")]
    ex.cell_origins = [_origin(o, notebooks, "cell_origins")
                       for o in _items(data.get("cell_origins"), 20000, "cell_origins")]
    ex.cell_runs = [_cell_run_from_wire(run, notebooks)
                    for run in _items(data.get("cell_runs"), len(ex.cell_origins), "cell_runs")]
    ex.seconds = _number(data.get("seconds"), "seconds")
    profile = _mapping(data.get("profile"), "profile")
    for key in ("start_s", "shared_s", "cells_s", "hidden_s"):
        ex.profile[key] = _number(profile.get(key), f"profile.{key}", low=-1e6)
    peak = profile.get("peak_mb")
    ex.profile["peak_mb"] = None if peak is None else _number(peak, "profile.peak_mb", high=1e7)
    return ex


# --------------------------------------------------------------------------- problems


def _inputs_of(spec, trial: checks.Trial) -> dict:
    """What the student's side needs of one problem: its inputs; for a closed loop, also
    its truth, which the loop flies by; the scoring's truth and tolerances stay here."""
    closed = spec.drive is not None
    return {"args": tuple(trial.args), "truth": trial.truth if closed else None}


def problems_to_wire(problems: Problems) -> dict:
    """The inputs of ``problems`` (see :func:`_inputs_of`), JSON-ready."""
    specs = {s.name: s for s in checks.SPECS[problems.assignment]}
    return {"assignment": problems.assignment, "student_id": problems.student_id,
            "trials": {name: [wire.encode(_inputs_of(specs[name], t)) for t in trials]
                       for name, trials in problems.trials.items()}}


def problems_from_wire(data, assignment: str, student_id: str) -> Problems:
    """Problems rebuilt from their inputs (no tolerances: nothing is scored with them)."""

    data = _mapping(data, "the problems")
    if data.get("assignment") != assignment or data.get("student_id") != student_id:
        raise ExecutionRefused("the problems are another submission's")
    trials = _mapping(data.get("trials"), "trials")
    specs = checks.SPECS[assignment]
    if list(trials) != [s.name for s in specs]:
        raise ExecutionRefused("the problems are not this lab's functions")
    out = {}
    for spec in specs:
        rows = []
        for row in _items(trials[spec.name], spec.n_trials, f"trials.{spec.name}"):
            try:
                fields = wire.decode(row)
            except (wire.WireError, ValueError, TypeError, RecursionError) as exc:
                raise ExecutionRefused(f"trials.{spec.name}: {printable(exc, 200)}") from None
            if not isinstance(fields, dict) or not isinstance(fields.get("args"), tuple):
                raise ExecutionRefused(f"trials.{spec.name}: a problem without inputs")
            rows.append(checks.Trial(args=fields["args"], truth=fields.get("truth"), tol={}))
        out[spec.name] = rows
    return Problems(assignment, student_id, out, KernelTrials(assignment))


def inputs_digest(problems: Problems, kernel=()) -> dict[str, str]:
    """Per function, a SHA-256 of its problems' inputs as the student's side gets them
    (and, as ``kernel:<name>``, of the kernel seeds' problems of each function in
    ``kernel``): a kept execution is scored again only against problems whose inputs are
    these."""
    specs = {s.name: s for s in checks.SPECS[problems.assignment]}

    def digest(name: str, trials) -> str:
        rows = [wire.encode(_inputs_of(specs[name], t)) for t in trials]
        return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()

    out = {name: digest(name, trials) for name, trials in problems.trials.items()}
    out.update({f"kernel:{name}": digest(name, problems.kernel_trials(name)) for name in kernel})
    return out
