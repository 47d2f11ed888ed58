"""Stage 4 of the grader's line, execute: run each submission's code, in a sandbox only.

Why not just trust nbgrader's hidden-test cells? They run in the same kernel as the student's
code, which can swallow failing asserts, patch numpy or the kernel, or find the expected
answer on the caller's stack. So here the truth and the score never enter the student's
process: :func:`execute_notebook` loads the notebook's code (:mod:`autograder.pipeline.cells`)
in a worker (:mod:`autograder.pipeline.worker`) and calls each graded function on its
problems' inputs (:class:`NotebookRunner`), giving an
:class:`~autograder.pipeline.execution.Execution`: what each call came to, a value or a typed
failure, nothing scored. A crash, hang, NaN or exception costs the student the problems it
touched, nothing else; a worker that dies is restarted for the next function. A function
whose code reaches one of its spec's forbidden routines (:mod:`autograder.forbidden`) is
stopped there.

:func:`execute` is the stage: every frozen submission, in threads, each in nbgrader's run of
its cells when there is one (:mod:`autograder.scratch`), on a Dask cluster's worker
(:mod:`autograder.cluster`) or forked from a template (:mod:`autograder.template`), tried
again in a fresh sandbox when the grader fails; its value per student is an
:class:`Executed`. :func:`grade_notebook` is draw, execute and score in a row.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from autograder import (
    checks,
    freeze,
    gradebook,
    sandbox,
    scratch,
)
from autograder.forbidden import static_hits
from autograder.freeze import printable
from autograder.outcomes import Cause, Failed, Failure, Flag, Note, Place
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.cells import (
    CellOrigin,
    extract_code,
    hidden_tests_called,
    scan_for_tampering,
)
from autograder.pipeline.execution import CellRun, Execution, FunctionRun, cell_error_note
from autograder.pipeline.problems import DrawnProblems, Problems, draw_problems, specs_of
from autograder.pipeline.score import SubmissionGrade, kernel_verdicts, score_execution
from autograder.pipeline.worker import (
    CellHang,
    GraderError,
    Limits,
    LoadBudget,
    TemplateUnavailable,
    Worker,
    WorkerFailure,
    WorkerSetup,
    not_loaded,
)
from autograder.template import Template, imported_modules, leading_cells

if TYPE_CHECKING:   # made after this stage, from its values
    from autograder.pipeline.nbgrader_results import NbgraderCells


def execute_notebook(notebook_paths, problems: Problems, limits: Limits = Limits(),
                     run_tests: bool = False, template=None) -> Execution:
    """Run one submission (its frozen notebook file or files) on its hidden problems and
    say what each call came to (:class:`Execution`); nothing is scored here.

    The code runs in the sandboxed worker, all of its processes in one cgroup when the
    machine has one. A function whose code reaches one of its spec's forbidden routines
    (static scan here, tripwire in the worker) is stopped there (``FunctionRun.forbidden``).
    Never raises because of anything in the submission: every failure becomes the outcome
    of the problems it touched, or a note; past ``limits.deadline_s`` the rest are skipped.
    Raises :class:`GraderError` when the grader could not run it (its sandbox did not start,
    or the machine starved it): the caller tries again in a fresh sandbox.

    ``run_tests`` is nbgrader's run of the same notebook, for a notebook nbgrader has
    sanitized (see :func:`extract_code`): its test cells run too, in order, on the first load
    only (a restart skips them), each cell's outcome goes to ``cell_runs``, and each
    ``hidden_test(f)`` of a test cell is run here on the kernel seeds' problems, into
    ``kernel_runs``.

    ``template``: an :class:`autograder.template.Template` of this assignment; when the
    submission's first cells are its shared ones, each worker is a fork of it (a sandbox of
    its own, the shared cells not run again), else, or when it cannot fork, a cold one.
    ``execution.profile`` says where the wall-clock time went.
    """
    started = time.monotonic()
    specs = specs_of(problems.assignment)
    run = Execution(student_id=problems.student_id, assignment=problems.assignment)
    tests: set[int] | None = set() if run_tests else None
    cells, run.cell_origins, run.notes = extract_code(notebook_paths, with_origins=True,
                                                      tests=tests)
    tests = tests or set()
    own = [c for i, c in enumerate(cells) if i not in tests]   # the student's code
    run.suspicious = scan_for_tampering(own)
    if not cells:
        run.notes.append(Note("no code cells found", for_student="no code cells found"))
    banned = {spec.name: static_hits(own, spec.name, spec.forbidden) for spec in specs}
    routines = sorted({name for spec in specs for name in spec.forbidden})

    caps = sandbox.capabilities()
    cgroup = _cgroup(caps, limits, run)
    if template is not None and not template.matches(cells):
        run.notes.append("started cold: the notebook's first cells are not the released "
                         "notebook's read-only ones")
        template = None
    setup = WorkerSetup(cgroup=cgroup, cpu_s=limits.worker_cpu_s(specs), template=template,
                        forbidden=tuple(routines))
    worker = NotebookRunner(cells, limits, run, setup, tests, run_tests)
    deadline = started + limits.deadline_s
    profile = run.profile
    try:
        if run_tests:   # every cell runs once even if no function gets called
            try:
                worker.loaded()
            except WorkerFailure as exc:
                run.notes.append(f"the notebook did not load: {exc}")
        hidden_started, loading_before = time.monotonic(), profile["start_s"] + profile["cells_s"]
        for spec in specs:
            if banned[spec.name]:
                run.functions.append(FunctionRun(spec.name, forbidden=tuple(banned[spec.name])))
                continue
            outcomes, tripped = worker.run(spec, problems.trials[spec.name], deadline)
            banned[spec.name] = sorted(tripped)
            run.functions.append(FunctionRun(spec.name, outcomes, tuple(sorted(tripped))))
        run.kernel_tests = hidden_tests_called(cells[i] for i in sorted(tests))
        for name in run.kernel_tests:
            spec = next((s for s in specs if s.name == name), None)
            if spec is None or banned.get(name):
                continue   # scored as such: no graded function of that name, or forbidden
            outcomes, tripped = worker.run(spec, problems.kernel_trials(name), deadline)
            run.kernel_runs[name] = FunctionRun(name, outcomes, tuple(sorted(tripped)))
        # restarts while calling count as loading, not as the hidden problems
        profile["hidden_s"] = (time.monotonic() - hidden_started
                               - (profile["start_s"] + profile["cells_s"] - loading_before))
    finally:
        worker.close()
        if cgroup is not None:
            _remove_cgroup(cgroup, limits, run)
    if not caps.bwrap:
        run.sandbox_flags.append(Flag("sandbox", "rlimits_only"))
    elif not caps.syscall_filter:   # a machine the keyring filter does not know
        run.sandbox_flags.append(Flag("sandbox", "no_keyring_filter"))
    run.seconds = time.monotonic() - started
    return run


def _cgroup(caps: sandbox.Capabilities, limits: Limits, run: Execution):
    """The submission's own cgroup (memory and processes of ``limits``), or None: none on
    this machine, or none could be made (``run`` says so)."""
    if not (caps.bwrap and caps.cgroup):
        return None
    try:
        return sandbox.Cgroup(limits.memory_mb, limits.max_processes)
    except (OSError, RuntimeError) as exc:
        # The run's header promised a cgroup: this row says it did not get one.
        run.sandbox_flags.append(Flag("sandbox", "no_cgroup"))
        run.notes.append(f"no cgroup for this submission ({exc}): per-process limits only")
        return None


def _remove_cgroup(cgroup: sandbox.Cgroup, limits: Limits, run: Execution) -> None:
    """Note the cgroup's peak memory (MB) in ``run.profile`` and each time the memory limit
    stopped the code, then remove it."""
    run.profile["peak_mb"] = cgroup.peak_memory_mb()
    if cgroup.oom_kills():
        text = (f"the memory limit ({limits.memory_mb} MB for all the submission's "
                f"processes) stopped it {cgroup.oom_kills()} time(s)")
        run.notes.append(Note(text, for_student=text))
    cgroup.remove()


class NotebookRunner:
    """Calls a notebook's functions on problems in a sandboxed worker: the one way the
    grader (:func:`execute_notebook`) and ``cobotlab labs verify`` (the reference notebook)
    run code on trials.

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
        :class:`GraderError` when the machine starved a call (the caller tries again)."""
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
    (see :class:`GraderError`)."""
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


def grade_notebook(notebook_paths, assignment: str, student_id: str, secret: str,
                   nonce: str | None, limits: Limits = Limits(),
                   run_tests: bool = False, template=None) -> SubmissionGrade:
    """Grade one submission on its own hidden problems: :func:`draw_problems`, then
    :func:`execute_notebook` (see it for ``run_tests`` and ``template``), then
    :func:`score_execution`. Never raises because of anything in the submission."""
    problems = draw_problems(assignment, student_id, secret, nonce)
    return score_execution(problems, execute_notebook(notebook_paths, problems, limits,
                                                      run_tests, template))


@dataclass
class Executed:
    """Stage 4's value for one submission: what its code did (``execution``; None when it
    was not run: refused, no notebook, or the grader failed on every attempt), the problems
    it ran on (the run's draw; a rescore's, drawn with the nonce its kept execution names),
    nbgrader's own run of it, the grader's failed attempts, and the frozen submission's
    digest (a kept execution belongs to that submission only)."""

    execution: Execution | None = None
    nbgrader: scratch.ScratchResult | None = None
    grader_errors: list[str] = field(default_factory=list)
    submission: str = ""
    problems: Problems | None = None
    # nbgrader's own cell results, for score's cross-check (autograder.pipeline.nbgrader_results)
    nbgrader_cells: NbgraderCells | None = None


def execute(run: GradeRun, frozen, problems: DrawnProblems, store: Path,
             progress=None, cluster=None) -> dict[str, Executed]:
    """{student: :class:`Executed`} for every frozen submission. With ``cluster``, each
    runs on a worker of that Dask cluster (:mod:`autograder.cluster`); otherwise, with the
    ``template`` option, each grading thread forks its workers from a template of its own."""
    sandbox.capabilities()   # probed here, once, before any worker thread starts
    _announce_fallback()
    use_template = run.options.template and cluster is None
    templates = _Templates(run.root, run.assignment, run.limits, run.notes) \
        if use_template else None
    executor = _Executor(run, problems, templates, cluster, *_nbgrader_template(run, store))
    lock, finished = threading.Lock(), []

    def one(sub: freeze.Frozen) -> Executed:
        done = executor.one(sub)
        if progress is not None:
            with lock:
                finished.append(sub.student_id)
                progress(len(finished), len(frozen), sub.student_id)
        return done

    if progress is not None:
        progress(0, len(frozen), "")
    try:
        done = _in_threads(one, frozen, run.options.workers)
    finally:
        if templates is not None:
            templates.close()
    return {sub.student_id: d for sub, d in zip(frozen, done)}


def _in_threads(one, frozen, workers: int) -> list:
    """[one(sub) for sub in frozen], ``workers`` at a time; on any exception (Ctrl-C
    included) every sandbox is stopped before it propagates."""
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        done = list(pool.map(one, frozen))
    except BaseException:
        # Ctrl-C reaches only this process (each sandbox has a session of its own): end
        # nbgrader, its kernels and the workers now, not when their runs time out.
        sandbox.stop_all()
        pool.shutdown(wait=True, cancel_futures=True)
        sandbox.allow_starts()
        raise
    pool.shutdown()
    return done


def _nbgrader_template(run: GradeRun, store: Path) -> tuple[Path | None, list | None]:
    """(nbgrader's throwaway template course, the grade cells it knows), or (None, None)
    without ``run_nbgrader`` or when it cannot be made (the run's notes say why)."""
    if not run.options.run_nbgrader:
        return None, None
    try:
        template = scratch.make_template(run.root, run.assignment, store,
                                         gradebook.duedate(run.root, run.assignment))
        return template, gradebook.template_cells(template, run.assignment)
    except Exception as exc:  # noqa: BLE001 - the cross-check is lost, not the grades
        run.notes.append(f"nbgrader cross-check skipped: {printable(exc, 300)}")
        return None, None


def _attempts(execute_once, errors: list[str]):
    """execute_once()'s execution, or None: up to GRADER_ATTEMPTS tries, each a fresh
    sandbox, worker and cgroup; the failed attempts' errors go to ``errors``."""
    for _ in range(GRADER_ATTEMPTS):
        try:
            return execute_once()
        except Exception as exc:  # noqa: BLE001 - the grader's failure, never the student's
            errors.append(f"{type(exc).__name__}: {printable(exc, 300)}")
    return None


class _Executor:
    """Runs one submission at a time (from any grading thread): in nbgrader's run of its
    cells when there is one (``template``, ``known``), else on its own."""

    def __init__(self, run: GradeRun, problems: DrawnProblems, templates, cluster,
                 template: Path | None, known: list | None):
        self.run, self.problems, self.templates, self.cluster = run, problems, templates, cluster
        self.template, self.known = template, known
        # one run of the cells for both nbgrader and the grader takes a single notebook
        self.in_worker = (not run.options.nbgrader_kernel and known is not None
                          and len({name for name, _ in known}) == 1)

    def one(self, sub: freeze.Frozen) -> Executed:
        """Stage 4's value for ``sub`` (its code run only if it is usable)."""
        done = Executed(submission=submission_digest(sub))
        if sub.accepted and sub.notebooks:
            done.problems = self.problems.of(sub.student_id)
            done.execution, done.nbgrader = self._usable(sub, done.problems,
                                                         done.grader_errors)
        return done

    def _notebook(self, paths, mine: Problems, run_tests: bool = False):
        if self.cluster is not None:
            return self.cluster.execute_notebook(paths, mine, self.run.limits, run_tests)
        template = self.templates.mine() if self.templates is not None else None
        return execute_notebook(paths, mine, self.run.limits, run_tests,
                                        template=template)

    def _usable(self, sub: freeze.Frozen, mine: Problems, errors: list[str]):
        """(execution or None, nbgrader's result or None) of one usable submission."""
        if self.templates is not None:
            self.templates.mine()   # this thread's, built before nbgrader's share is timed
        nb = execution = None
        if self.template is not None:
            nb, execution = self._with_nbgrader(sub, mine, errors)
        if execution is None and len(errors) < GRADER_ATTEMPTS:
            # not run in nbgrader's run (no cross-check, or nbgrader refused the notebook)
            execution = _attempts(lambda: self._notebook(sub.notebooks, mine), errors)
        return execution, (nb if execution is not None else None)

    def _with_nbgrader(self, sub: freeze.Frozen, mine: Problems, errors: list[str]):
        """(nbgrader's result, the execution made in its run or None)."""
        def run_tests(paths):
            ran = _attempts(lambda: self._notebook(paths, mine, run_tests=True), errors)
            if ran is None:
                raise GraderError("the grader failed on every attempt")
            return ran, kernel_verdicts(mine, ran)

        run, options = self.run, self.run.options
        try:
            if self.in_worker:   # one run of the cells for both nbgrader and the grader
                return scratch.autograde_in_worker(sub, run.assignment, run.root,
                                                   self.template, self.known, run_tests)
            # the in-worker run takes one notebook: nbgrader's own kernel
            return scratch.autograde_one(sub, run.assignment, run.root, self.template,
                                         self.known, timeout_s=options.nbgrader_timeout_s,
                                         cell_timeout_s=options.nbgrader_cell_timeout_s), None
        except Exception as exc:  # noqa: BLE001 - a grader bug must not lose the row
            return scratch.ScratchResult(notes=[f"nbgrader run failed: {printable(exc)}"]), None


def submission_digest(sub: freeze.Frozen) -> str:
    """SHA-256 of a frozen submission: its notebooks (names and bytes) and its timestamp."""
    h = hashlib.sha256(printable(sub.timestamp, 200).encode("utf-8", "backslashreplace"))
    for path in sorted(sub.notebooks, key=lambda p: Path(p).name):
        h.update(b"\0" + Path(path).name.encode("utf-8", "backslashreplace") + b"\0")
        h.update(Path(path).read_bytes())
    return h.hexdigest()


class _Templates:
    """One :class:`autograder.template.Template` per grading thread, built on its first
    submission (so ``--workers 2`` builds two at once, one per core) and closed at the end.
    A thread whose template cannot be built grades cold; the run log says why, once."""

    def __init__(self, root: Path, assignment: str, limits: Limits, run_notes):
        self.limits, self.run_notes = limits, run_notes
        self.release = root / "release" / assignment / f"{assignment}.ipynb"
        self.cpu_s = limits.worker_cpu_s(checks.SPECS[assignment])
        self._local, self._lock, self._built = threading.local(), threading.Lock(), []

    def mine(self):
        """This thread's template, or None (no release, nothing to share, or it failed)."""
        if not hasattr(self._local, "template"):
            self._local.template = self._build()
        return self._local.template

    def _build(self):
        why = None
        try:
            cells = leading_cells(self.release) if self.release.is_file() else None
            if not cells:
                why = ("no released notebook to share cells from (run nbgrader "
                       "generate_assignment)" if cells is None else "the released notebook "
                       "does not begin with read-only cells")
            else:
                built = Template(cells, self.limits, self.cpu_s,
                                 preload=imported_modules(self.release))
        except TemplateUnavailable as exc:
            why = printable(exc, 300)
        except Exception as exc:  # noqa: BLE001 - a grader bug costs speed, never a grade
            why = f"{type(exc).__name__}: {printable(exc, 300)}"
        with self._lock:
            if why is not None:
                note = f"no template, every submission started cold: {why}"
                if note not in self.run_notes:
                    self.run_notes.append(note)
                return None
            self._built.append(built)
            if len(self._built) == 1:
                self.run_notes.append(
                    f"template: the interpreter, the notebook's imports and its first "
                    f"{len(cells)} cells "
                    f"({built.shared_s:.1f} s) loaded once per worker, in "
                    f"{built.build_s:.1f} s; peak {built.peak_memory_mb():.0f} MB, shared by "
                    "its forks")
        return built

    def close(self) -> None:
        with self._lock:
            for template in self._built:
                template.close()
            self._built.clear()


# A grader error (its sandbox did not start, a bug) is tried again in a fresh sandbox; a
# submission the grader fails on every time gets no score, never a zero.
GRADER_ATTEMPTS = 2


def _announce_fallback() -> None:
    """Before any submission is graded: say on stderr (whatever ``quiet``) that student code
    will run without bubblewrap, why, and what to install or enable."""
    warning = sandbox.fallback_warning()
    if warning:
        print(f"cobotlab: {warning}", file=sys.stderr, flush=True)


def _timed_out(reply: dict) -> bool:
    """A cell's reply (or the grader's own entry for a skipped cell) says its time limit
    stopped it."""
    return reply.get("failure") == "timed_out"
