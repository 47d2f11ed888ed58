"""Stage 4 of the grader's line, execute: run each submission's code, in a sandbox only.

:func:`execute` is the stage: every frozen submission, in threads, each in nbgrader's run of
its cells when there is one (:mod:`autograder.scratch`), on a Dask cluster's worker
(:mod:`autograder.cluster`) or forked from a template (:mod:`autograder.template`), tried
again in a fresh sandbox when the grader fails; its value per student is an
:class:`Executed`. One submission's run is
:func:`~autograder.pipeline.run_submission.execute_notebook`, its call loop
:class:`~autograder.pipeline.notebook_runner.NotebookRunner`.
"""

from __future__ import annotations

import hashlib
import sys
import threading
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
from autograder.freeze import printable
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.execution import Execution
from autograder.pipeline.problems import DrawnProblems, Problems
from autograder.pipeline.run_submission import execute_notebook
from autograder.pipeline.score import kernel_verdicts
from autograder.pipeline.worker import GraderError, Limits, TemplateUnavailable
from autograder.template import Template, imported_modules, leading_cells

if TYPE_CHECKING:   # made after this stage, from its values
    from autograder.pipeline.nbgrader_results import NbgraderCells


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
    ``template`` option, every grading thread forks its workers from the run's one template."""
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
            self.templates.mine()   # built before nbgrader's share is timed
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
    """The run's one :class:`autograder.template.Template`, built by the first grading
    thread that needs it (the others wait for it, then fork from it too: its control
    socket serves one fork at a time) and closed at the end. With ``--workers 2`` a
    template per thread cost a second interpreter and the shared cells' CPU again, for
    the same forks, in about the same wall clock. When it cannot be built every
    submission is graded cold; the run log says why, once."""

    def __init__(self, root: Path, assignment: str, limits: Limits, run_notes):
        self.limits, self.run_notes = limits, run_notes
        self.release = root / "release" / assignment / f"{assignment}.ipynb"
        self.cpu_s = limits.worker_cpu_s(checks.SPECS[assignment])
        self._lock, self._tried, self._template = threading.Lock(), False, None

    def mine(self):
        """The run's template, or None (no release, nothing to share, or it failed)."""
        with self._lock:
            if not self._tried:
                self._tried = True
                self._template = self._build()
            return self._template

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
        if why is not None:
            self.run_notes.append(f"no template, every submission started cold: {why}")
            return None
        self.run_notes.append(
            f"template: the interpreter, the notebook's imports and its first {len(cells)} "
            f"cells ({built.shared_s:.1f} s) loaded once for the run, in "
            f"{built.build_s:.1f} s; peak {built.peak_memory_mb():.0f} MB, shared by its forks")
        return built

    def close(self) -> None:
        with self._lock:
            if self._template is not None:
                self._template.close()
            self._template = None


# A grader error (its sandbox did not start, a bug) is tried again in a fresh sandbox; a
# submission the grader fails on every time gets no score, never a zero.
GRADER_ATTEMPTS = 2


def _announce_fallback() -> None:
    """Before any submission is graded: say on stderr (whatever ``quiet``) that student code
    will run without bubblewrap, why, and what to install or enable."""
    warning = sandbox.fallback_warning()
    if warning:
        print(f"cobotlab: {warning}", file=sys.stderr, flush=True)
