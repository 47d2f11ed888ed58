"""One submission's code run on its hidden problems, nothing scored:
:func:`execute_notebook`, the execute stage's act per submission.

Why not just trust nbgrader's hidden-test cells? They run in the same kernel as the student's
code, which can swallow failing asserts, patch numpy or the kernel, or find the expected
answer on the caller's stack. So here the truth and the score never enter the student's
process: :func:`execute_notebook` loads the notebook's code (:mod:`autograder.pipeline.cells`)
in a worker (:mod:`autograder.pipeline.worker`) and calls each graded function on its
problems' inputs (:class:`~autograder.pipeline.notebook_runner.NotebookRunner`), giving an
:class:`~autograder.pipeline.execution.Execution`: what each call came to, a value or a typed
failure, nothing scored. A function whose code reaches one of its spec's forbidden routines
(:mod:`autograder.forbidden`) is stopped there. :func:`grade_notebook` is draw, execute and
score in a row.
"""

from __future__ import annotations

import time

from autograder import (
    sandbox,
)
from autograder.forbidden import static_hits
from autograder.outcomes import Flag, Note
from autograder.pipeline.cells import extract_code, hidden_tests_called, scan_for_tampering
from autograder.pipeline.execution import Execution, FunctionRun
from autograder.pipeline.notebook_runner import NotebookRunner
from autograder.pipeline.problems import Problems, draw_problems, specs_of
from autograder.pipeline.score import SubmissionGrade, score_execution
from autograder.pipeline.worker import Limits, WorkerFailure, WorkerSetup


def execute_notebook(notebook_paths, problems: Problems, limits: Limits = Limits(),
                     run_tests: bool = False, template=None) -> Execution:
    """Run one submission (its frozen notebook file or files) on its hidden problems and
    say what each call came to (:class:`Execution`); nothing is scored here.

    The code runs in the sandboxed worker, all of its processes in one cgroup when the
    machine has one. A function whose code reaches one of its spec's forbidden routines
    (static scan here, tripwire in the worker) is stopped there (``FunctionRun.forbidden``).
    Never raises because of anything in the submission: every failure becomes the outcome
    of the problems it touched, or a note; past ``limits.deadline_s`` the rest are skipped.
    Raises :class:`~autograder.pipeline.worker.GraderError` when the grader could not run
    it (its sandbox did not start, or the machine starved it): the caller tries again in a
    fresh sandbox.

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


def grade_notebook(notebook_paths, assignment: str, student_id: str, secret: str,
                   nonce: str | None, limits: Limits = Limits(),
                   run_tests: bool = False, template=None) -> SubmissionGrade:
    """Grade one submission on its own hidden problems: :func:`draw_problems`, then
    :func:`execute_notebook` (see it for ``run_tests`` and ``template``), then
    :func:`score_execution`. Never raises because of anything in the submission."""
    problems = draw_problems(assignment, student_id, secret, nonce)
    return score_execution(problems, execute_notebook(notebook_paths, problems, limits,
                                                      run_tests, template))
