"""The grader's line: :func:`grade_course` calls each stage with the values of the ones
before it (docs/architecture.md): begin, freeze, draw, execute (or read the kept
executions), score, record."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from autograder.freeze import freeze_course, printable
from autograder.grade_options import GradeOptions
from autograder.pipeline.begin import GradeRun, begin, run_options
from autograder.pipeline.draw import draw
from autograder.pipeline.execute import Executed, execute
from autograder.pipeline.nbgrader_results import with_nbgrader_cells
from autograder.pipeline.record import (
    end_run,
    grade_row,
    print_summary,
    record_grades,
    write_autograded,
)
from autograder.pipeline.rescore import KEPT, keep, keep_all, kept_executions
from autograder.pipeline.score import score_submission
from autograder.secret import PRIVATE_DIR


def grade_course(course_dir, assignment: str, workers: int = 1, *,
                 options: GradeOptions | None = None, progress=None, cluster=None,
                 **settings) -> list[dict]:
    """Grade every submission of ``assignment`` in ``course_dir/submitted`` and write results.

    One straight line of stages, each a function of the one before, so that no submission
    can damage or fool the grade (docs/architecture.md):

    1. **begin**: the course, its secret, the run's problems (fixed, fresh or replayed);
       refuse a concurrent run, back up the gradebook;
    2. **freeze**: every submission is copied, as data (regular files only, capped), into
       grader-private storage before any student code runs (:mod:`autograder.freeze`);
    3. **draw**: every submission's hidden problems, from the secret, in this process,
       all of them before any code runs (:mod:`autograder.pipeline.draw`); only their inputs
       go to a sandbox or a cluster's worker;
    4. **execute** (:mod:`autograder.pipeline.execute`): per student, one sandboxed worker
       runs the notebook once and calls the graded functions on the problems' inputs, an
       :class:`~autograder.pipeline.execution.Execution`: what each call came to, nothing
       scored; it sees neither the course, the secret nor the answer key. With ``run_nbgrader``,
       nbgrader's own autograde converter (sanitize, restore the locked and test cells,
       score, late penalty) runs here on a throwaway course and takes its cell outcomes from
       that same run (:func:`autograder.scratch.autograde_in_worker`), so the cross-check
       costs no second execution; an assignment of several notebooks gets nbgrader's own
       kernel, sandboxed;
    5. **score** (:mod:`autograder.pipeline.score`): a pure function of the problems and
       the execution: no I/O, no student code;
    6. **record** (:mod:`autograder.pipeline.record`), from this trusted process: validated numbers into ``gradebook.db``
       (backed up first, integrity-checked after, restored if damaged), then ``grades.csv``,
       the feedback pages, the executions (kept for ``rescore``) and the run log, written
       atomically without following links.

    Args:
        course_dir: an nbgrader course made by :func:`init_course`.
        assignment: e.g. ``"lab0_frames"``.
        workers: submissions graded in parallel (each in its own sandbox).
        options: every setting below as one :class:`autograder.grade_options.GradeOptions`;
            or pass them as keywords (``settings``), not both. The run reads them from
            that one frozen value.
        run_nbgrader: run nbgrader's autograde (stage 4) for its cell results; otherwise use
            whatever nbgrader results ``gradebook.db`` already holds, if any.
        nbgrader_kernel: run nbgrader's autograde with its own kernel, sandboxed, a second
            run of each notebook (slower; the autograded notebooks then hold rich output such
            as plots); always so for an assignment of several notebooks.
        nbgrader_cell_timeout_s: nbgrader's per-cell timeout in its kernel (config: 30 s).
        nbgrader_timeout_s: wall clock of one student's nbgrader kernel run.
        limits: the isolated grader's per-submission limits (``deadline_s``: wall clock).
        caps: what one submission may hold (sizes, file and cell counts).
        fresh: draw new hidden problems for this run (a random nonce, written to
            ``.cobotlab/runs.jsonl`` only after every worker is gone). By default each
            student gets the course's fixed problems (from the secret, the assignment, the
            student and the function), so a regrade reproduces every score.
        nonce: replay a fresh run's problems (its ``nonce`` in ``.cobotlab/runs.jsonl``).
        quiet: do not print the summary.
        students: grade only these student ids (a shard of the class); default: everyone.
        progress: called as ``progress(done, total, student_id)`` once with ``done=0``
            before any student code runs and after each submission is graded (e.g. a tqdm
            bar; the CLI's). Ctrl-C (KeyboardInterrupt) at any point stops every sandbox
            (nbgrader, its kernels, the workers) before it propagates.
        rescore: run no student code: score each submission again from the execution the
            last grade run kept (after a change to a lab's tolerances, points, bands or
            mistakes) and record as a grade run does. Refused, naming them, when a
            submission changed since it was graded, has no kept execution, or when the
            lab's change altered the problems' inputs.

    Returns the gradebook rows (dicts with :data:`GRADE_COLUMNS` keys, ``flags`` a
    ``;``-separated string), also written to ``course_dir/grades.csv``, one per submission
    whatever it did, with feedback in
    ``course_dir/feedback_cobotlab/<student>/<assignment>/feedback.html`` (and, for nbgrader's
    generate_feedback and release_feedback, :mod:`autograder.feedback_release`'s files).

    ``cluster``: an :class:`autograder.cluster.ClusterGrader`: stage 4 runs each
    submission on a worker of its Dask cluster, in the same sandbox, instead of here
    (``workers`` submissions in flight at once); the other stages stay in this process,
    which draws the problems, sends their inputs, and scores what each worker returns.

    ``template``: each of the ``workers`` grading threads loads the interpreter, the lab's
    imports and the released notebook's leading read-only cells once, and forks every
    submission's worker from it into a sandbox of its own (:mod:`autograder.template`);
    False starts a new interpreter per submission (the results are the same, slower).
    """
    options = run_options(workers, options, settings)
    run = begin(course_dir, assignment, options, cluster)
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        frozen = freeze_course(run.root, assignment, Path(store), options.caps, options.students)
        problems = draw(run, frozen)
        if options.rescore:
            executed = kept_executions(run, frozen, problems, progress)
        else:
            executed = execute(run, frozen, problems, Path(store), progress, cluster)
    if run.problems == "job":   # a shard job: home scores what it kept (autograder.shards)
        return _end_job(run, frozen, executed)
    executed = with_nbgrader_cells(run, frozen, executed)
    grades = [score_submission(run, sub, executed[sub.student_id]) for sub in frozen]
    rows, grades = record_grades(run, frozen, executed, grades)
    if run.problems != "rescore":   # a rescore's executions are those it read
        keep_all(run, frozen, executed)
    end_run(run, rows, grades, executed)
    if not options.quiet:
        print_summary(grades, assignment, time.monotonic() - run.started, run.notes,
                       executed, options)
    return rows


def _end_job(run: GradeRun, frozen, executed: dict[str, Executed]) -> list[dict]:
    """A shard job's end: each execution kept for home to score (``cobotlab merge``), the
    autograded notebooks of nbgrader's run for formgrader at home, the run's log; nothing
    scored, no grades.csv, nothing in the gradebook. Returns a row (no score) for each
    submission the grader failed on, so the CLI's exit status says so."""
    failed, kept = [], 0
    for sub in frozen:
        done = executed[sub.student_id]
        if done.execution is None:
            if sub.accepted and sub.notebooks:
                failed.append(grade_row(run.assignment, sub.student_id, {}, None, 0.0,
                                        "grader_error", sub.timestamp))
            continue
        keep(run, sub.student_id, done)
        kept += 1
        if done.nbgrader is not None:
            write_autograded(run.root, run.assignment, sub, done.nbgrader)
    run.notes.append(f"shard job: {kept} execution(s) kept for the home course to score")
    end_run(run, failed, [], executed)
    if not run.options.quiet:
        print(f"{run.assignment}: executed {kept} submission(s); nothing was scored here. "
              f"Bring back {run.root / PRIVATE_DIR / KEPT} and "
              f"{run.root / 'autograded'}, then run `cobotlab merge` at home")
        if failed:
            print(f"NOT EXECUTED ({len(failed)}): "
                  + ", ".join(printable(r["student_id"], 80) for r in failed)
                  + f" (see {run.root / PRIVATE_DIR / 'last_run.log'})")
    return failed
