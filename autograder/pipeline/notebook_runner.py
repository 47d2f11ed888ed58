"""Calls a notebook's functions on problems in a sandboxed worker, the one call loop of the
grader and of ``cobotlab labs verify``: :class:`NotebookRunner`.

The worker (:mod:`autograder.pipeline.worker`) loads the notebook's cells when first
needed and again after it dies; a cell that hung is skipped from then on, and what the
first load did becomes notes (a cell that raised: its words and its typed
:class:`~autograder.outcomes.Place`) and, with nbgrader's test cells, a
:class:`~autograder.pipeline.execution.CellRun` per cell. A crash, hang, NaN or exception
costs the student the problems it touched, nothing else: after a time-out or a worker that
stopped, the rest of that function's problems are skipped, each saying why.
"""

from __future__ import annotations

import dataclasses
import math
import time

from autograder import (
    checks,
)
from autograder.outcomes import Cause, Failed, Failure, Place
from autograder.pipeline.cells import CellOrigin
from autograder.pipeline.execution import CellRun, Execution, cell_error_note
from autograder.pipeline.problems import specs_of
from autograder.pipeline.worker import (
    CellHang,
    Limits,
    LoadBudget,
    TemplateUnavailable,
    Worker,
    WorkerFailure,
    WorkerSetup,
    not_loaded,
)


class NotebookRunner:
    """Calls a notebook's functions on problems in a sandboxed worker: the one way the
    grader (:func:`~autograder.pipeline.run_submission.execute_notebook`) and ``cobotlab
    labs verify`` (the reference notebook) run code on trials.

    The worker loads ``cells`` when first needed and again after it dies (cells that hung
    are skipped from then on, the load budget is shared by every start); :meth:`run` gives
    one outcome per trial (a value or a typed failure). ``execution`` collects the load's
    notes (and, with ``run_tests``, what each cell did on the first load); ``tests`` are the
    indices of nbgrader's test cells, run on the first load only; ``routines``: the
    forbidden routines the worker takes hold of before any cell runs; ``cpu_s``: the
    worker's lifetime CPU limit (default: loading plus every function's trials, for
    ``execution``'s assignment). ``batch_calls``: make a function's problems in one round trip
    (``labs verify``'s thousands of reference calls); a batch that met a time-out, a wall
    clock or a dead worker is made again call by call on a freshly loaded worker, so for a
    function that keeps no state between calls :meth:`run` returns the same either way."""

    def __init__(self, cells, limits: Limits, execution: Execution | None = None,
                 setup: WorkerSetup = WorkerSetup(), tests: set[int] = frozenset(),
                 run_tests: bool = False, batch_calls: bool = False):
        run = execution if execution is not None else Execution(student_id="", assignment="")
        cpu_s = setup.cpu_s
        if cpu_s is None:
            cpu_s = limits.worker_cpu_s(specs_of(run.assignment))
        self.cells, self.limits, self.execution, self.tests = cells, limits, run, set(tests)
        # over every restart, not since the start: a worker that dies late must still be
        # able to reload
        self.budget = LoadBudget.of(limits)
        self.setup = dataclasses.replace(setup, cpu_s=cpu_s, budget=self.budget)
        self.run_tests, self.batch_calls = run_tests, batch_calls
        self.worker: Worker | None = None
        self.skip: set[int] = set()
        self.starts = 0
        self.noted_load = False

    def loaded(self) -> Worker:
        if self.worker is not None and self.worker.alive:
            return self.worker
        if self.worker is not None:
            self.worker.close()
        self.starts += 1
        run, profile = self.execution, self.execution.profile
        setup = dataclasses.replace(self.setup, first=self.starts == 1)
        try:
            self.worker = _start_worker(self.cells, self.limits, run, self.skip, setup)
        except TemplateUnavailable as exc:
            run.notes.append(f"started without the template ({exc})")
            self.setup = dataclasses.replace(self.setup, template=None)
            self.worker = _start_worker(self.cells, self.limits, run, self.skip,
                                        dataclasses.replace(setup, template=None))
        worker = self.worker
        profile["start_s"] += worker.start_s
        profile["cells_s"] += worker.cells_s
        if worker.shared:
            profile["shared_s"] = self.setup.template.shared_s
        if not self.noted_load:   # a restart repeats the same load
            _note_load(run, worker.load_report, self.tests)
            self.noted_load = True
        if self.run_tests and not run.cell_runs:
            run.cell_runs = _cell_runs(worker.load_report, run.cell_origins, self.skip)
        self.skip.update(self.tests)   # they ran once, as in nbgrader; a restart needs the code
        return worker

    @property
    def load_report(self) -> list[dict]:
        """What each cell did on the current worker's load (empty before the first)."""
        return self.worker.load_report if self.worker is not None else []

    def run(self, spec: checks.FunctionSpec, trials: list[checks.Trial],
            deadline: float = math.inf):
        """(outcomes, forbidden routines tripped) of ``spec``'s function on ``trials``,
        each call within its CPU limit; after a time-out, or a call that stopped the worker,
        the rest are skipped, and past ``deadline`` (monotonic) nothing more runs. Raises
        :class:`~autograder.pipeline.worker.GraderError` when the machine starved a call
        (the caller tries again)."""
        if self.batch_calls and spec.drive is None and len(trials) > 1 and deadline == math.inf:
            batched = self._batched(spec, trials)
            if batched is not None:
                return batched
        outcomes: list[checks.TrialOutcome] = []
        failure: checks.TrialOutcome | None = None   # what every later problem gets
        tripped: set[str] = set()
        limits = self.limits
        for trial in trials:
            if failure is None and time.monotonic() > deadline:
                failure = checks.TrialOutcome(
                    error=f"not run: the submission's {limits.deadline_s:g} s were used up",
                    failure=Failure(Failed.SKIPPED, cause=Cause.DEADLINE))
            if failure is not None:  # one hang is enough: do not wait on every problem
                outcomes.append(checks.TrialOutcome(error=failure.error,
                                                    failure=failure.failure))
                continue
            try:
                w = self.loaded()
                timeout = limits.call_limit_s(spec)
                timeout = max(0.1, min(timeout, (deadline - time.monotonic())
                                       / limits.wall_factor))
                outcome = checks.run_trial(
                    spec, trial, lambda args, t, w=w, s=spec: w.call(
                        s.name, args, t, s.forbidden,
                        s.substitutes(args) if s.substitutes else None), timeout,
                    limits.wall_factor)
                tripped |= w.tripped
                w.tripped.clear()
                outcomes.append(outcome)
                if outcome.failure is not None and outcome.failure.kind is Failed.TIMED_OUT:
                    failure = checks.TrialOutcome(
                        error=f"skipped: an earlier problem timed out after {timeout:g} s",
                        failure=Failure(Failed.SKIPPED, cause=Cause.TIMED_OUT,
                                        limit_s=timeout))
            except WorkerFailure as exc:
                # The problem that stopped the worker says why; the rest say they were
                # not run (so feedback counts one time-out, not one per problem).
                outcomes.append(checks.TrialOutcome(error=str(exc), failure=exc.failure))
                failure = checks.TrialOutcome(
                    error=f"skipped: an earlier problem stopped the worker ({exc})",
                    failure=Failure(Failed.SKIPPED, cause=Cause.WORKER_STOPPED))
                self.close()
        return outcomes, tripped

    def _batched(self, spec: checks.FunctionSpec, trials: list[checks.Trial]):
        """:meth:`run`'s result from one round trip, or None where only single calls give
        it: a call that timed out or found no function (the loop's skips follow from single
        calls), a wall clock met (only a single call can be judged starved) or a worker that
        died (which call killed it is not known). The worker is then stopped, so the calls
        made again one by one meet a freshly loaded notebook, as the batch did not."""
        try:
            w = self.loaded()
            calls = [(t.args, spec.substitutes(t.args) if spec.substitutes else None)
                     for t in trials]
            outcomes = w.call_many(spec.name, calls, self.limits.call_limit_s(spec),
                                   spec.forbidden)
        except WorkerFailure:
            self.close()
            return None
        tripped = set(w.tripped)
        w.tripped.clear()
        if outcomes is None or len(outcomes) < len(trials):
            self.close()
            return None
        return outcomes, tripped

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
        self.worker = None


def _cell_runs(report: list[dict], origins: list[CellOrigin], skip: set[int]) -> list[CellRun]:
    """:class:`CellRun` of every cell from a first load's report (a cell skipped after it
    hung counts as timed out; replies are the worker's, so every field is capped text)."""
    runs = []
    for entry, origin in zip(report, origins):
        error = "" if entry.get("ok") is True else str(entry.get("error") or "failed")[:400]
        timed_out = entry.get("ok") is not True and _timed_out(entry)
        if entry.get("skipped") and entry.get("index") in skip:
            error, timed_out = "timed out", True
        raised = bool(error) and not timed_out
        runs.append(CellRun(origin, error, str(entry.get("stdout") or "")[:4096],
                            str(entry.get("stderr") or "")[:4096], timed_out,
                            exception=_capped(entry.get("exception"), 80) if raised else "",
                            message=_capped(entry.get("message"), 400) if raised else "",
                            place=Place.claimed(entry.get("place")) if error else None))
    return runs


def _capped(value, limit: int) -> str:
    """A text field of the worker's (untrusted) reply, capped; "" when it is no string."""
    return value[:limit] if isinstance(value, str) else ""


def _start_worker(cells, limits: Limits, run: Execution, skip: set[int],
                  setup: WorkerSetup) -> Worker:
    """A loaded worker as ``setup`` says (a fork of its ``template`` when given), without
    the cells in ``skip``; cells that hang or time out are added to ``skip``, so every later
    restart skips them too. ``setup.first``: no worker of this submission has started yet
    (see :class:`~autograder.pipeline.worker.GraderError`)."""
    while True:
        if setup.budget.exhausted:
            raise not_loaded(limits)
        try:
            worker = Worker(cells, limits, dataclasses.replace(setup, skip=frozenset(skip)))
        except CellHang as exc:
            setup = dataclasses.replace(setup, first=False)
            skip.add(exc.index)
            run.notes.append(cell_error_note(f"{exc} (skipped from then on)",
                                             Place.whole_cell(exc.index)))
            continue
        # A cell stopped by its timer would only cost the same seconds again next restart.
        skip.update(r["index"] for r in worker.load_report
                    if r.get("ok") is not True and _timed_out(r))
        return worker


def _note_load(run: Execution, report: list[dict], tests: set[int]) -> None:
    """Note what the first load did; errors of the test cells are nbgrader's result, not
    notes."""
    failed = [c for c in report if isinstance(c, dict) and not c.get("ok")
              and not c.get("skipped") and c.get("index") not in tests]
    run.notes.append(f"notebook loaded: {len(report)} code cells, {len(failed)} raised")
    for c in failed[:5]:
        run.notes.append(cell_error_note(str(c.get("error"))[:200],
                                         Place.claimed(c.get("place"))))
    chars = max([c.get("output_chars", 0) for c in report if isinstance(c, dict)
                 and isinstance(c.get("output_chars"), int)] or [0])
    if chars > 100_000:
        run.notes.append(f"printed {chars} characters while loading (output discarded)")


def _timed_out(reply: dict) -> bool:
    """A cell's reply (or the grader's own entry for a skipped cell) says its time limit
    stopped it."""
    return reply.get("failure") == "timed_out"
