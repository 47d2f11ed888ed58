"""The nbgrader course: lay it out, and grade an assignment so no submission can damage it.

``init_course(DIR)`` makes a directory where the instructor's usual nbgrader commands work
(``nbgrader generate_assignment lab0_frames``, ``nbgrader autograde lab0_frames``, ...).
``grade_course(DIR, ASSIGNMENT)`` grades every submission in one line of stages, each
taking the values of the ones before (docs/architecture.md): begin, freeze
(:mod:`autograder.freeze`), draw every problem (:func:`autograder.grading.draw_all`),
execute untrusted code in a throwaway sandbox (the isolated grader's worker,
:mod:`autograder.grading`, which also runs the cells for nbgrader's own autograde,
:mod:`autograder.scratch`), score, and record from the trusted process
(:mod:`autograder.gradebook`, :mod:`autograder.record`), writing ``DIR/grades.csv`` and
per-student feedback HTML (:mod:`autograder.feedback`). The run's options are one frozen
:class:`autograder.grade_options.GradeOptions`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from autograder import (
    checks,
    executions,
    feedback,
    freeze,
    gradebook,
    grading,
    record,
    registry,
    sandbox,
    scratch,
    shard_job,
)
from autograder.feedback_release import (
    HOOK,
    INERT,
    config_problem,
    unreleasable_note,
    write_exchange_files,
    write_section,
)
from autograder.freeze import printable
from autograder.grade_options import GradeOptions
from autograder.nbgrader_cells import cell_role
from autograder.outcomes import Flag, about_function
from autograder.practice import releasable, save_practice
from autograder.safe_files import Refused, Why, move_aside, read_file
from autograder.template import Template, TemplateUnavailable, imported_modules, leading_cells

__all__ = ["LABS_DIR", "GRADE_COLUMNS", "init_course", "run_nbgrader_autograde", "grade_course"]



LABS_DIR = registry.builtin_folder()
GRADE_COLUMNS = ["assignment", "duedate", "timestamp", "student_id", "last_name", "first_name",
                 "email", "raw_score", "late_submission_penalty", "score", "max_score", "flags"]

# Formgrader and nbgrader's feedback show a student's notebook in the grading account's own
# browser origin: what it holds must not run there (autograder.sanitize_notebook). Written by
# `cobotlab course init` into a new course, and added to a course laid out before it.
INERT_PAGES_CONFIG = f'''\
# A submission rendered as HTML (formgrader's pages, generate_feedback's) is made inert
# first: every HTMLExporter nbgrader makes reads this. (HTMLExporter.sanitize_html does not
# reach formgrader's own templates.)
c.HTMLExporter.preprocessors = ["{INERT}"]
'''

_CONFIG = '''\
# nbgrader configuration written by cobotlab (autograder.course.init_course).
c = get_config()  # noqa: F821
c.CourseDirectory.course_id = {course_id!r}
c.CourseDirectory.root = {root!r}
# Where release_assignment / fetch_assignment / submit / collect meet (and formgrader looks):
# made by `cobotlab course init`; students' servers must see the same folder at this path.
c.Exchange.root = {exchange!r}
# Each cell gets this long in nbgrader's kernel; the authoritative grade comes from
# `cobotlab grade`, which runs the code again in an isolated, limited worker.
c.Execute.timeout = 30
c.Execute.interrupt_on_timeout = True
c.ClearSolutions.code_stub = {{"python": "# YOUR CODE HERE\\nraise NotImplementedError()"}}
# `cobotlab grade` keeps grades.csv (every assignment, with flags); `nbgrader export`, whose
# default is the same name, writes its own file (`--to` still chooses another).
c.ExportPlugin.to = "nbgrader_grades.csv"
# nbgrader's feedback (generate_feedback, formgrader's buttons) reads the autograded
# notebooks, which hold the hidden tests: they and their outputs are cut out first. Then
# cobotlab's own feedback goes on top of each page, so release_feedback carries it too.
c.GenerateFeedback.preprocessors = [
    "nbgrader.preprocessors.GetGrades",
    "autograder.nbgrader_hooks.HideHiddenTests",
    "autograder.sanitize_notebook.InertSubmission",
    "autograder.nbgrader_hooks.AddCobotlabFeedback",
    "nbconvert.preprocessors.CSSHTMLHeaderPreprocessor",
]
''' + INERT_PAGES_CONFIG


def init_course(course_dir, labs_dir=None, exchange=None, course_id: str = "cobotlab",
                force: bool = False, quiet: bool = False) -> Path:
    """Lay out an nbgrader course in ``course_dir`` with every lab: the built-in ones (or
    those in ``labs_dir``) and those of the folders its ``cobotlab.toml`` names.

    Writes ``nbgrader_config.py`` (``course_id``, the course root, and nbgrader's exchange:
    ``exchange``, default ``course_dir/exchange``, created world-writable as nbgrader
    requires, unless root made it a private exchange with ``cobotlab course exchange``:
    then its modes are kept and the config names its classes, docs/exchange.md), copies
    each ``labs/<name>/`` (notebook and data, no saved outputs) to ``source/<name>/``, creates an empty ``gradebook.db`` (so nbgrader run from the virtual
    environment without activating it never needs ``alembic`` on ``$PATH``), and the
    grading secret in ``.cobotlab/secret`` (mode 0600; not copied into any assignment).
    Existing config, sources, gradebook and secret are kept, so running it again after
    adding a lab is safe; only the course's own labs are copied again into ``source/``
    (their lab folder is where they are edited and verified). Returns the path.

    A lab that does not load, or whose last ``cobotlab labs verify`` failed
    (:func:`autograder.registry.release_problem`; ``force`` lets the latter through), is
    skipped: nothing of it is written, every other lab is laid out, and one line on stderr
    (unless ``quiet``) names it, why, and the fix. A course lab never verified, or edited
    since, is laid out with a warning line.
    """
    root = Path(course_dir).resolve()
    registry.use_course(root)   # its cobotlab.toml names the instructor's own lab folders
    if labs_dir is None and not LABS_DIR.is_dir() and not registry.source_folders():
        raise ValueError(f"labs directory {LABS_DIR} not found: the lab sources come with the "
                         "instructor's package (pip install cobotlab, not cobotlab-student); "
                         "or pass labs_dir=")
    sources = registry.source_folders(labs_dir)
    # Every lab's spec is loaded and its practice problems drawn before anything is written:
    # a broken lab (an instructor's draft, say) is left out whole, with its file named, and
    # never stops the others. The draws are cached per spec version (autograder.practice):
    # the generators' closed loops and depth images take seconds, and a process laying out
    # several courses pays once.
    documents, skipped = releasable([n for n in sources if n in checks.SPECS], force)
    sources = {name: folder for name, folder in sources.items() if name not in skipped}
    root.mkdir(parents=True, exist_ok=True)
    _write_config(root, exchange, course_id)
    if not (root / "gradebook.db").exists():
        scratch.speed_up_new_gradebooks()   # and no `alembic` needed on $PATH
        gradebook.create(root, course_id)
    own = {name for name, lab in registry.all_labs().items() if not lab.builtin}
    for name, folder in sources.items():
        target = root / "source" / name
        if not target.exists():
            shutil.copytree(folder, target, ignore=shutil.ignore_patterns(
                ".ipynb_checkpoints", "__pycache__"))
        elif name in own:
            # The course's own lab is edited in its lab folder, and `labs verify` proved that
            # folder fair: nbgrader must release the same notebook, not an older copy.
            _sync_folder(folder, target)
        if name in documents:
            # The practice problems, as data, beside the notebook: nbgrader copies them into
            # the release (the students' check()) and the hidden tests score on them in
            # nbgrader's kernel, which sees no generator. Written again on every init, so a
            # changed spec reaches the next release.
            save_practice(documents[name], target)
    grading.create_secret(root)
    if not quiet:
        for name, why in skipped.items():
            kept = (f" (source/{name}/ keeps what an earlier `course init` wrote)"
                    if (root / "source" / name).exists() else "")
            print(f"cobotlab: skipped lab {name}{kept}: {why}", file=sys.stderr)
        for name in sorted(set(sources) & own):
            note = registry.verification_note(name)
            if note:
                print(f"cobotlab: warning: {note}", file=sys.stderr)
    return root


def _write_config(root: Path, exchange, course_id: str) -> None:
    """The course's nbgrader_config.py, with its exchange folder (see :func:`init_course`);
    one already there is kept, with the inert-pages block added if it lacks it."""
    config = root / "nbgrader_config.py"
    if config.exists():
        _add_inert_pages(config)
        return
    exchange_dir = Path(exchange).expanduser().resolve() if exchange else root / "exchange"
    exchange_dir.mkdir(parents=True, exist_ok=True)
    text = _CONFIG.format(root=str(root), exchange=str(exchange_dir), course_id=course_id)
    from autograder import exchange as private

    if private.layout_problem(exchange_dir, course_id) is None:
        # root laid out a private exchange here (`cobotlab course exchange`): keep its
        # modes, and release and collect with its classes
        text += private.config_block(exchange_dir, course_id)
    else:
        os.chmod(exchange_dir, 0o777)   # nbgrader's own requirement (it resets others)
    config.write_text(text)


def _add_inert_pages(config: Path) -> None:
    """Bring a course's ``nbgrader_config.py`` written before issue 51 up to date: append
    the lines that make formgrader's and the feedback's pages inert, and put the same step
    into its feedback preprocessors (after ``GetGrades``, which brings the comments in)."""
    text = config.read_text()
    if INERT in text:
        return
    hook = f'    "{HOOK}",\n'
    if hook in text:
        text = text.replace(hook, f'    "{INERT}",\n' + hook, 1)
    config.write_text(text + "\n" + INERT_PAGES_CONFIG)


def _sync_folder(folder: Path, target: Path) -> None:
    """Copy every file of ``folder`` whose content differs into ``target`` (files only in
    ``target``, such as practice data, are left)."""
    for path in folder.rglob("*"):
        relative = path.relative_to(folder)
        if not path.is_file() or {".ipynb_checkpoints", "__pycache__"} & set(relative.parts):
            continue
        dest = target / relative
        if not dest.is_file() or dest.read_bytes() != path.read_bytes():
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, dest)


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
        template = scratch.make_template(root, assignment, Path(store),
                                         gradebook.duedate(root, assignment))
        known = gradebook.template_cells(template, assignment)
        for sid in wanted:
            result = scratch.autograde_one(frozen[sid], assignment, root, template, known,
                                           timeout_s=timeout_s, cell_timeout_s=cell_timeout_s,
                                           memory_mb=memory_mb)
            _record_nbgrader(root, assignment, frozen[sid], result)
            logs.append(f"--- {sid}\n{result.log}")
    return "\n".join(logs)


# --------------------------------------------------------------------------- nbgrader's view


def _source_cells(root: Path, assignment: str):
    """(:class:`~autograder.nbgrader_cells.CellRole`, source) of every cell of the source
    notebooks."""
    for path in sorted((root / "source" / assignment).glob("*.ipynb")):
        for cell in json.loads(path.read_text()).get("cells", []):
            yield cell_role(cell), "".join(cell.get("source", ""))


def _cell_to_function(root: Path, assignment: str) -> dict[str, str]:
    """grade_id of each hidden-test cell in the source notebooks -> graded function name.

    The labs name a function's test cell ``test_<function>``; a cell named otherwise goes to
    the last graded function it calls.
    """
    names = [s.name for s in checks.SPECS.get(assignment, ())]
    mapping = {}
    for role, source in _source_cells(root, assignment):
        grade_id = role.grade_id
        if not (role.grade and grading.HIDDEN_MARK in source):
            continue
        called = [n for n in names if re.search(rf"\b{re.escape(n)}\s*\(", source)]
        by_name = [n for n in names if grade_id == f"test_{n}"]
        if by_name or called:
            mapping[grade_id] = (by_name or called)[-1]
    return mapping


def _solution_cells(root: Path, assignment: str) -> dict[str, str]:
    """graded function name -> grade_id of the solution cell that defines it (where
    formgrader shows a comment box)."""
    mapping = {}
    for role, source in _source_cells(root, assignment):
        grade_id = role.grade_id
        if not role.solution:
            continue
        for spec in checks.SPECS.get(assignment, ()):
            if grade_id == spec.name or (spec.name not in mapping and re.search(
                    rf"^def {re.escape(spec.name)}\s*\(", source, re.MULTILINE)):
                mapping[spec.name] = grade_id
    return mapping


def _cross_check(grade: grading.SubmissionGrade, nb: dict, cell_map: dict[str, str]) -> None:
    """Flag functions nbgrader's kernel passed but the independent grader failed."""
    if not nb.get("cells"):
        grade.flags.append(Flag("nbgrader_no_result"))
        return
    by_function = {f.name: f for f in grade.functions}
    for grade_id, function in cell_map.items():
        if grade_id not in nb["cells"]:
            grade.flags.append(Flag("nbgrader_missing_cell", function, function=function))
            continue
        score, max_score = nb["cells"][grade_id]
        ours = by_function.get(function)
        if ours is not None and max_score > 0 and score >= max_score and ours.fraction < 0.5:
            grade.flags.append(Flag("nbgrader_passed_but_grader_failed", function,
                                    function=function))


# --------------------------------------------------------------------------- grading


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
       all of them before any code runs (:func:`autograder.grading.draw_all`); only their
       inputs go to a sandbox or a cluster's worker;
    4. **execute**: per student, one sandboxed worker runs the notebook once and calls the
       graded functions on the problems' inputs (:func:`autograder.grading.execute_notebook`),
       an :class:`~autograder.grading.Execution`: what each call came to, nothing scored; it
       sees neither the course, the secret nor the answer key. With ``run_nbgrader``,
       nbgrader's own autograde converter (sanitize, restore the locked and test cells,
       score, late penalty) runs here on a throwaway course and takes its cell outcomes from
       that same run (:func:`autograder.scratch.autograde_in_worker`), so the cross-check
       costs no second execution; an assignment of several notebooks gets nbgrader's own
       kernel, sandboxed;
    5. **score**: a pure function of the problems and the execution
       (:func:`autograder.grading.score_execution`): no I/O, no student code;
    6. **record**, from this trusted process: validated numbers into ``gradebook.db``
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
    options = _options(workers, options, settings)
    run = _begin(course_dir, assignment, options, cluster)
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        frozen = _freeze(run.root, assignment, Path(store), options.caps, options.students)
        problems = _problems(run, frozen)
        if options.rescore:
            executed = _kept_executions(run, frozen, problems, progress)
        else:
            executed = _execute(run, frozen, problems, Path(store), progress, cluster)
    if run.problems == "job":   # a shard job: home scores what it kept (autograder.shards)
        return _end_job(run, frozen, executed)
    grades = [_score(run, sub, executed[sub.student_id]) for sub in frozen]
    rows, grades = _record(run, frozen, executed, grades)
    _end_run(run, rows, grades, executed)
    if not options.quiet:
        _print_summary(grades, assignment, time.monotonic() - run.started, run.notes,
                       executed, options)
    return rows


def _options(workers: int, options: GradeOptions | None, settings: dict) -> GradeOptions:
    """The run's one :class:`GradeOptions`: ``options``, or one made of ``workers`` and the
    keyword ``settings`` (TypeError names a keyword grade_course does not take)."""
    if options is None:
        return GradeOptions(workers=workers, **settings)
    if settings or workers != 1:
        raise TypeError("grade_course takes options= or keyword settings (workers included), "
                        f"not both: got options and {sorted(settings) or ['workers']}")
    return options


# ----------------------------------------------------------------- stage 1: begin


@dataclass
class GradeRun:
    """What every stage of one grade run shares: the course, the assignment, the secret
    and the run's nonce (None: the course's fixed problems), the limits, and the notes for
    the run's log."""

    root: Path
    private: Path
    assignment: str
    secret: str
    nonce: str | None
    problems: str              # "fixed", "fresh", "replay", "rescore" or "job" (runs.jsonl)
    limits: grading.Limits
    notes: list[str]
    started: float
    options: GradeOptions = GradeOptions()


def _course(course_dir, assignment: str) -> Path:
    """The course's root, its labs registered, ``assignment`` one of them; ValueError
    names the known ones."""
    root = Path(course_dir).resolve()
    registry.use_course(root)
    grading.specs_of(assignment)
    return root


def _course_and_secret(course_dir, assignment: str) -> tuple[Path, str]:
    """(the course's root, its grading secret): see :func:`_course`."""
    root = _course(course_dir, assignment)
    return root, grading.load_secret(root)


def _secret_or_job(root: Path, assignment: str, fresh, nonce, rescore, cluster) -> str:
    """The course's grading secret; "" for a shard job's copy, which must hold none and
    runs only the problems home wrote for it (:mod:`autograder.shard_job`)."""
    if not shard_job.is_job(root, assignment):
        return grading.load_secret(root)
    shard_job.refuse_secret(root)
    if fresh or nonce or rescore or cluster is not None:
        raise ValueError("this course is a shard job's copy: it executes the problems home "
                         "wrote for it, and takes no fresh, replay, rescore or cluster")
    return ""


def _begin(course_dir, assignment: str, options: GradeOptions, cluster) -> GradeRun:
    """Check the request, recover from an interrupted run, refuse a concurrent one, back up
    the gradebook; the run's shared values."""
    workers, limits, quiet = options.workers, options.limits, options.quiet
    fresh, nonce, rescore = options.fresh, options.nonce, options.rescore
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    root = _course(course_dir, assignment)
    secret = _secret_or_job(root, assignment, fresh, nonce, rescore, cluster)
    if fresh and nonce:
        raise ValueError("fresh=True draws new problems; nonce= replays a fresh run's: pass "
                         "one of them")
    if rescore and (fresh or nonce or cluster is not None):
        raise ValueError("rescore scores the executions the last grade run kept, on that "
                         "run's problems: it takes no fresh, replay or cluster")
    if nonce is not None and not re.fullmatch(r"[0-9a-f]{16,64}", nonce):
        raise ValueError(f"nonce {printable(nonce, 80)!r} is not one `cobotlab grade --fresh` "
                         "draws (16-64 hex digits): copy it from .cobotlab/runs.jsonl")
    problems = "job" if not secret else "rescore" if rescore else "fresh" if fresh else (
        "replay" if nonce else "fixed")
    nonce = secrets.token_hex(16) if fresh else nonce
    private = _private_dir(root)
    started = time.monotonic()
    # a cluster whose workers would grade differently (lab version) is refused here
    cluster_note = cluster.check(assignment) if cluster is not None else None
    run = GradeRun(root, private, assignment, secret, nonce, problems, limits,
                   _begin_run(root, private), started, options)
    unverified = registry.verification_note(assignment)
    if unverified:
        run.notes.append(f"warning: {unverified}")
        if not quiet:
            print(f"warning: {unverified}", file=sys.stderr)
    if cluster_note:
        run.notes.append(cluster_note)
    old_config = config_problem(root)   # students' feedback would lack cobotlab's, or worse
    if old_config:
        run.notes.append(f"warning: {old_config}")
        if not quiet:
            print(f"warning: {old_config}", file=sys.stderr)
    return run


# ----------------------------------------------------------------- stage 2: freeze


def _private_dir(root: Path) -> Path:
    private = root / grading.PRIVATE_DIR
    private.mkdir(mode=0o700, exist_ok=True)
    if not stat.S_ISDIR(os.lstat(private).st_mode):
        raise ValueError(f"{private} is not a folder (a symlink?): refusing to grade")
    return private


def _freeze(root: Path, assignment: str, store: Path, caps: freeze.Caps,
            students=None) -> list[freeze.Frozen]:
    submitted = root / "submitted"
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    (store / "submissions").mkdir(mode=0o700)
    frozen = (freeze.freeze_submissions(submitted, assignment, expected, store / "submissions",
                                        caps) if os.path.lexists(submitted) else [])
    if not frozen:
        raise ValueError(f"no submissions for {assignment!r} in {submitted}; collect them "
                         "first (nbgrader collect / zip_collect) or check the assignment name")
    if students is not None:
        wanted = list(dict.fromkeys(students))
        missing = sorted(set(wanted) - {f.student_id for f in frozen})
        if missing:
            raise ValueError(f"no submission of {assignment!r} by {', '.join(missing)} in "
                             f"{submitted}; check the --students list")
        frozen = [f for f in frozen if f.student_id in set(wanted)]
    return frozen


# ----------------------------------------------------------------- stage 3: draw


def _problems(run: GradeRun, frozen) -> grading.DrawnProblems:
    """Every usable submission's hidden problems, all of them now, before any code runs:
    drawn from the secret here, or, in a shard job, the inputs home wrote for each (refused,
    naming them, when some are missing)."""
    usable = [s.student_id for s in frozen if s.accepted and s.notebooks]
    if run.problems != "job":
        return grading.draw_all(run.assignment, run.secret, run.nonce, usable)
    problems = shard_job.BundledProblems(run.root, run.assignment)
    missing = problems.missing(usable)
    if missing:
        raise ValueError(
            f"this shard job holds no problems of {run.assignment} for "
            f"{', '.join(printable(m, 80) for m in missing[:20])}: write them at home "
            "(`cobotlab shard HOME ASSIGNMENT JOB STUDENT...`), or "
            "leave them out of --students")
    return grading.DrawnProblems(run.assignment, {sid: problems.of(sid) for sid in usable},
                                 problems.kernel)


# ----------------------------------------------------------------- stage 4: execute


@dataclass
class Executed:
    """Stage 4's value for one submission: what its code did (``execution``; None when it
    was not run: refused, no notebook, or the grader failed on every attempt), the problems
    it ran on (the run's draw; a rescore's, drawn with the nonce its kept execution names),
    nbgrader's own run of it, the grader's failed attempts, and the frozen submission's
    digest (a kept execution belongs to that submission only)."""

    execution: grading.Execution | None = None
    nbgrader: scratch.ScratchResult | None = None
    grader_errors: list[str] = field(default_factory=list)
    submission: str = ""
    problems: grading.Problems | None = None


def _execute(run: GradeRun, frozen, problems: grading.DrawnProblems, store: Path,
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

    def __init__(self, run: GradeRun, problems: grading.DrawnProblems, templates, cluster,
                 template: Path | None, known: list | None):
        self.run, self.problems, self.templates, self.cluster = run, problems, templates, cluster
        self.template, self.known = template, known
        # one run of the cells for both nbgrader and the grader takes a single notebook
        self.in_worker = (not run.options.nbgrader_kernel and known is not None
                          and len({name for name, _ in known}) == 1)

    def one(self, sub: freeze.Frozen) -> Executed:
        """Stage 4's value for ``sub`` (its code run only if it is usable)."""
        done = Executed(submission=_submission_digest(sub))
        if sub.accepted and sub.notebooks:
            done.problems = self.problems.of(sub.student_id)
            done.execution, done.nbgrader = self._usable(sub, done.problems,
                                                         done.grader_errors)
        return done

    def _notebook(self, paths, mine: grading.Problems, run_tests: bool = False):
        if self.cluster is not None:
            return self.cluster.execute_notebook(paths, mine, self.run.limits, run_tests)
        template = self.templates.mine() if self.templates is not None else None
        return grading.execute_notebook(paths, mine, self.run.limits, run_tests,
                                        template=template)

    def _usable(self, sub: freeze.Frozen, mine: grading.Problems, errors: list[str]):
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

    def _with_nbgrader(self, sub: freeze.Frozen, mine: grading.Problems, errors: list[str]):
        """(nbgrader's result, the execution made in its run or None)."""
        def run_tests(paths):
            ran = _attempts(lambda: self._notebook(paths, mine, run_tests=True), errors)
            if ran is None:
                raise grading.GraderError("the grader failed on every attempt")
            return ran, grading.kernel_verdicts(mine, ran)

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


def _submission_digest(sub: freeze.Frozen) -> str:
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

    def __init__(self, root: Path, assignment: str, limits: grading.Limits, run_notes):
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


# ----------------------------------------------------------------- stage 4': kept executions

_KEPT = "executions"


def kept_path(assignment: str, student_id: str) -> str:
    """Where, below the course's private folder, a student's kept execution is."""
    return f"{_KEPT}/{assignment}/{executions.file_key(student_id)}.json"


def _keep(run: GradeRun, student_id: str, done: Executed) -> None:
    """Keep what a submission's code did, for ``rescore``: its execution, the problems'
    inputs digest and nonce it ran on, nbgrader's flags and notes of that run, and the
    digest of the frozen submission it belongs to."""
    record.write_file(run.private, kept_path(run.assignment, student_id),
                      kept_bytes(run, done))


def kept_bytes(run: GradeRun, done: Executed) -> bytes:
    """The kept form of ``done`` (see :func:`_keep`): an execution and the problems it ran
    on."""
    ex, problems = done.execution, done.problems
    kept = {"format": executions.FORMAT, "student_id": problems.student_id,
            "assignment": run.assignment, "nonce": run.nonce, "submission": done.submission,
            "inputs": executions.inputs_digest(problems, ex.kernel_runs),
            "execution": executions.to_wire(ex), "grader_errors": done.grader_errors,
            "nbgrader": None if done.nbgrader is None else {
                "flags": list(done.nbgrader.flags), "notes": list(done.nbgrader.notes)}}
    return json.dumps(kept).encode("utf-8")


def _kept_executions(run: GradeRun, frozen, problems: grading.DrawnProblems,
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
        done = Executed(submission=_submission_digest(sub))
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


def _load_kept(run: GradeRun, problems: grading.DrawnProblems, sub: freeze.Frozen,
               done: Executed) -> str | None:
    """Fill ``done`` from the kept execution of ``sub``; None, or why it cannot be used."""
    data = _read_private(run.private, kept_path(run.assignment, sub.student_id))
    if data is None:
        return "no execution kept: never graded by this version of cobotlab, or not graded"
    return use_kept(run, problems, sub, done, data)


def use_kept(run: GradeRun, problems: grading.DrawnProblems, sub: freeze.Frozen,
             done: Executed, data: bytes, from_job: bool = False) -> str | None:
    """Fill ``done`` from ``data``, a kept execution of ``sub`` (untrusted bytes: this
    course's, or a shard job's with ``from_job``, whose nbgrader findings are its word and
    are dropped); None, or why it cannot be used: another format or submission, another
    nonce than a job runs on, problems whose inputs are not those drawn here, or not one
    outcome per problem."""
    try:
        kept = json.loads(data)
        if not isinstance(kept, dict) or kept.get("format") != executions.FORMAT:
            return "its kept execution is of another format"
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
    mine = problems.of(sub.student_id) if nonce == run.nonce else grading.draw_problems(
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


def _uneven_counts(problems: grading.Problems, execution: grading.Execution) -> list[str]:
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

    problems: grading.Problems | None
    execution: grading.Execution | None
    notebooks: dict[str, str]
    why: str | None = None


def kept_submissions(course_dir, assignment: str) -> dict[str, KeptSubmission]:
    """{student: :class:`KeptSubmission`} of every submission of ``assignment`` in
    ``course_dir/submitted``, frozen as a grade run freezes them and matched with the
    executions the last grade run kept, as ``grade --rescore`` reads them (the same checks:
    this submission's, run on the problems' inputs as the lab draws them now). Reads only:
    no student code runs, nothing is recorded. Score one with
    :func:`autograder.grading.score_execution`."""
    root, secret = _course_and_secret(course_dir, assignment)
    run = GradeRun(root, root / grading.PRIVATE_DIR, assignment, secret, None, "report",
                   grading.Limits(), [], time.monotonic())
    out: dict[str, KeptSubmission] = {}
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        frozen = _freeze(root, assignment, Path(store), freeze.Caps())
        problems = _problems(run, frozen)
        for sub in frozen:
            texts = {Path(p).name: Path(p).read_text(encoding="utf-8", errors="replace")
                     for p in sub.notebooks}
            if not (sub.accepted and sub.notebooks):
                out[sub.student_id] = KeptSubmission(None, None, texts, "refused, or no "
                                                     "notebook: it scored zero")
                continue
            done = Executed(submission=_submission_digest(sub))
            why = _load_kept(run, problems, sub, done)
            out[sub.student_id] = KeptSubmission(
                done.problems if why is None else None, done.execution, texts, why)
    return out


# ----------------------------------------------------------------- stage 5: score


def _score(run: GradeRun, sub: freeze.Frozen, done: Executed) -> grading.SubmissionGrade:
    """The grade of one submission from its execution (:func:`grading.score_execution`),
    with the freeze's flags and notes first and nbgrader's and the time-outs' after; a
    refused submission, or one without a notebook, scores zero; one the grader failed on
    every time is not graded."""
    if not sub.accepted or not sub.notebooks:
        grade = _zero_grade(sub, run.assignment)
    elif done.execution is None:
        grade = _ungraded(sub, run.assignment, done.grader_errors)
    else:
        grade = grading.score_execution(done.problems, done.execution)
        if done.grader_errors:
            grade.notes.append(f"graded after {len(done.grader_errors)} grader error(s), each "
                               f"retried in a fresh sandbox: {'; '.join(done.grader_errors)}")
    grade.flags[:0] = sub.flags
    grade.notes[:0] = sub.notes
    if sub.accepted and grade.graded:
        if done.nbgrader is not None:
            grade.notes += done.nbgrader.notes
            grade.flags += done.nbgrader.flags
        grade.flags += _timeout_flags(grade)
    return grade


def _ungraded(sub: freeze.Frozen, assignment: str, errors: list[str]):
    grade = _zero_grade(sub, assignment, ["grader_error"], [
        f"not graded: the grader failed on each of {len(errors)} attempts ("
        + "; ".join(errors) + "); no score is recorded, and the next `cobotlab grade` of "
        "this assignment grades it again"])
    grade.graded = False
    return grade


def _zero_grade(sub: freeze.Frozen, assignment: str, flags=(), notes=()):
    grade = grading.SubmissionGrade(sub.student_id, assignment, flags=list(flags),
                                    notes=list(notes))
    grade.functions = [checks.score_function(s, [], []) for s in checks.SPECS[assignment]]
    return grade


def _timeout_flags(grade: grading.SubmissionGrade) -> list[str]:
    """``timed_out:<function>`` for each function that lost problems to a time limit (a hang
    would otherwise show only as failed checks)."""
    return [Flag("timed_out", f.name, function=f.name) for f in grade.functions
            if f.lost_to_time]


# ----------------------------------------------------------------- stage 6: record


def _record_nbgrader(root: Path, assignment: str, sub: freeze.Frozen,
                     result: scratch.ScratchResult) -> None:
    """The validated cell scores and autograded notebooks of one scratch run, into the course
    (the notebooks for nbgrader's own next commands: generate_feedback, formgrader)."""
    present = {p.stem for p in sub.notebooks}
    gradebook.write_nbgrader_cells(root, assignment, sub.student_id, sub.timestamp,
                                   result.cells, present)
    _write_autograded(root, assignment, sub, result)


def _write_autograded(root: Path, assignment: str, sub: freeze.Frozen,
                      result: scratch.ScratchResult) -> None:
    for name, data in result.notebooks.items():
        record.write_file(root, f"autograded/{sub.student_id}/{assignment}/{name}.ipynb", data)
    if result.notebooks:   # what nbgrader's release_feedback reads beside them
        write_exchange_files(root, assignment, sub)


def _record(run: GradeRun, frozen, executed: dict[str, Executed],
            scored) -> tuple[list[dict], list[grading.SubmissionGrade]]:
    """(the grades.csv rows, the grades as recorded): ``scored`` written into the course.
    What recording adds (nbgrader's cross-check flags, a restored gradebook's flag, notes
    of what could not be written) goes on copies; ``scored`` is read, never changed."""
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
    nb_runs = _record_nbgrader_runs(run, frozen, executed, grades)
    damaged = _check_gradebook(root, private, run_notes)

    # A submission the grader could not grade gets nothing in the gradebook, not a zero.
    accepted = [(g, sub) for g, sub in zip(grades, frozen) if sub.accepted and g.graded]
    ledger = _load_ledger(private)
    nb_own = {} if damaged else _nbgrader_own(
        gradebook.results(root, assignment, [g.student_id for g, _ in accepted]),
        ledger.get(assignment, {}), {sub.student_id: sub.timestamp for _, sub in accepted},
        set(nb_runs))
    cell_map = _cell_to_function(root, assignment)
    for grade, sub in accepted:
        if sub.notebooks:
            _cross_check(grade, nb_own.get(grade.student_id, {}), cell_map)
    if not damaged:
        _record_cobotlab(root, private, assignment, accepted, nb_own, cell_map, ledger,
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
                write_section(root, assignment, grade, sub.timestamp)
            except (OSError, ValueError) as exc:
                grade.notes.append(f"feedback not written: {printable(exc)}")
    # every assignment graded so far, one row per student and assignment (this run's replace)
    record.update_csv(root, GRADES_CSV, GRADE_COLUMNS, rows, key=("assignment", "student_id"))
    if run.problems != "rescore":   # a rescore's executions are those it read
        _keep_all(run, frozen, executed)
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
            _record_nbgrader(run.root, run.assignment, sub, result)
        except Exception as exc:  # noqa: BLE001 - the cross-check is lost, not the grade
            by_student[sub.student_id].notes.append(
                f"could not record nbgrader's result: {printable(exc)}")
    return nb_runs


def _keep_all(run: GradeRun, frozen, executed: dict[str, Executed]) -> None:
    """Keep each execution of the run for ``rescore``; a failure to is in the run's notes."""
    for sub in frozen:
        done = executed[sub.student_id]
        if done.execution is None:
            continue
        try:
            _keep(run, sub.student_id, done)
        except (OSError, ValueError) as exc:
            note = f"executions not kept (no rescore for them): {printable(exc, 200)}"
            if note not in run.notes:
                run.notes.append(note)


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
        _keep(run, sub.student_id, done)
        kept += 1
        if done.nbgrader is not None:
            _write_autograded(run.root, run.assignment, sub, done.nbgrader)
    run.notes.append(f"shard job: {kept} execution(s) kept for the home course to score")
    _end_run(run, failed, [], executed)
    if not run.options.quiet:
        print(f"{run.assignment}: executed {kept} submission(s); nothing was scored here. "
              f"Bring back {run.root / grading.PRIVATE_DIR / _KEPT} and "
              f"{run.root / 'autograded'}, then run `cobotlab merge` at home")
        if failed:
            print(f"NOT EXECUTED ({len(failed)}): "
                  + ", ".join(printable(r["student_id"], 80) for r in failed)
                  + f" (see {run.root / grading.PRIVATE_DIR / 'last_run.log'})")
    return failed


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




# ----------------------------------------------------------------- cobotlab's score in nbgrader

GRADES_CSV = "grades.csv"
# nbgrader's own value of each cell cobotlab overwrote, so the cross-check still has it on
# the next run: {assignment: {student: {"timestamp", "cells": {grade_id: [ours, nbgrader's]}}}}
_LEDGER = "nbgrader_cells.json"


_PRIVATE_CAP = 1 << 30   # a private file read back whole (runs.jsonl grows by a line a run)


def _read_private(private: Path, name: str) -> bytes | None:
    """The bytes of ``private/name`` (``private`` itself no link either), or None: missing,
    or not a regular file (a link is not followed; the next write replaces it). One too
    big or unreadable is moved aside to ``<name>.unreadable-<time>``, not lost."""
    try:
        return read_file(private, name, _PRIVATE_CAP)
    except Refused as exc:
        if exc.why in (Why.TOO_BIG, Why.UNREADABLE) and exc.where == name:
            move_aside(private, name, f".unreadable-{int(time.time())}")
        return None


def _load_ledger(private: Path) -> dict:
    data = _read_private(private, _LEDGER)
    try:
        ledger = json.loads(data) if data is not None else {}
    except (ValueError, UnicodeDecodeError):
        ledger = {}
    return ledger if isinstance(ledger, dict) else {}


def _nbgrader_own(nb_results: dict, ledger: dict, timestamps: dict, just_run: set) -> dict:
    """nbgrader's own cell results: the gradebook's, except in cells that still hold the
    score cobotlab wrote there for the same submission, where it is the value cobotlab
    replaced (a cell nbgrader never graded is left out)."""
    for sid, entry in nb_results.items():
        mine = ledger.get(sid)
        if sid in just_run or not isinstance(mine, dict) or \
                mine.get("timestamp") != timestamps.get(sid):
            continue  # nbgrader's fresh result, or nothing of ours in the gradebook
        wrote = mine.get("cells") if isinstance(mine.get("cells"), dict) else {}
        cells = {}
        for grade_id, (score, max_score) in entry.get("cells", {}).items():
            ours = wrote.get(grade_id)
            if isinstance(ours, list) and len(ours) == 2 and isinstance(ours[0], (int, float)) \
                    and abs(score - ours[0]) < 1e-6:
                if not isinstance(ours[1], (int, float)):
                    continue
                score = float(ours[1])
            cells[grade_id] = (score, max_score)
        entry["cells"] = cells
    return nb_results


def _record_cobotlab(root, private, assignment, accepted, nb_own, cell_map, ledger,
                     run_notes) -> None:
    """Each function's score into its autograder cell(s) of gradebook.db, the findings
    into the comment of the solution cell that defines it; nbgrader's own values into the
    ledger for the next run's cross-check."""
    solution_of = _solution_cells(root, assignment)
    mapped = set(cell_map.values())
    unmapped = [s.name for s in checks.SPECS[assignment] if s.name not in mapped]
    if unmapped:
        run_notes.append(f"no autograder cell in the source notebook for {unmapped}: their "
                         "scores are in grades.csv only")
    mine = ledger.setdefault(assignment, {})
    for grade, sub in accepted:
        by_function = {f.name: f for f in grade.functions}
        fractions = {gid: by_function[name].fraction for gid, name in cell_map.items()
                     if name in by_function}
        theirs = nb_own.get(grade.student_id, {}).get("cells", {})
        comments = {solution_of[f.name]: _comment(grade, f, i == 0, [
            theirs[g] for g, name in cell_map.items() if name == f.name and g in theirs])
            for i, f in enumerate(grade.functions) if f.name in solution_of}
        try:
            written = gradebook.write_cobotlab(root, assignment, grade.student_id,
                                               sub.timestamp, fractions, comments)
        except Exception as exc:  # noqa: BLE001 - grades.csv still gets the score
            note = f"cobotlab's scores not written to gradebook.db: {printable(exc, 200)}"
            if note not in run_notes:
                run_notes.append(note)
            continue
        mine[grade.student_id] = {"timestamp": sub.timestamp, "cells": {
            gid: [score, theirs[gid][0] if gid in theirs else None]
            for gid, (_, score) in written.items()}}
    record.write_file(private, _LEDGER, json.dumps(ledger).encode("utf-8"))


def _comment(grade: grading.SubmissionGrade, f: checks.FunctionResult, first: bool,
             nbgrader_cells: list[tuple[float, float]]) -> str:
    """The auto comment formgrader shows under the function's solution cell (nbgrader's
    feedback shows it to the student: no test code or data in it)."""
    lines = [f"cobotlab: {f.points:g} / {f.max_points:g} points on {f.n_problems} hidden "
             "problems" + (f", {f.n_failed} not fully right" if f.n_failed else "") + "."]
    if f.failed_checks:
        lines.append("Failed checks: " + ", ".join(f.failed_checks) + ".")
    if nbgrader_cells:
        lines.append("nbgrader's own hidden-test cell: " + ", ".join(
            f"{s:g} / {m:g}" for s, m in nbgrader_cells) + " (cross-check; the score above "
            "is the grade).")
    own = [x for x in grade.flags if about_function(x) == f.name]
    whole = [x for x in grade.flags if about_function(x) is None]
    if own:
        lines.append("Flags: " + "; ".join(printable(x, 120) for x in own) + ".")
    if first and whole:
        lines.append("Flags on the whole submission: "
                     + "; ".join(printable(x, 120) for x in whole) + ".")
    return "\n".join(lines)


def _begin_run(root: Path, private: Path) -> list[str]:
    """Recover from an interrupted run, refuse a concurrent one, back up the gradebook."""
    notes = []
    marker = private / record.RUN_MARKER
    stamp = _read_private(private, record.RUN_MARKER)
    if stamp is not None:
        try:
            pid = int(json.loads(stamp).get("pid", 0))
        except (ValueError, AttributeError, TypeError):
            pid = 0
        if pid and pid != os.getpid() and sandbox.process_alive(pid):
            raise ValueError(f"another `cobotlab grade` (pid {pid}) is grading this course; "
                             f"wait for it, or remove {marker} if it is gone")
        problem = gradebook.problem(root / "gradebook.db")
        backup = private / "gradebook.backup.db"
        if problem and backup.is_file():
            gradebook.restore(root, backup)
            notes.append(f"the previous run was interrupted and gradebook.db was damaged "
                         f"({problem}): restored from its backup")
        else:
            notes.append("the previous run was interrupted; gradebook.db checked: "
                         + (problem or "ok"))
    removed = sandbox.remove_stale_scratch() + sandbox.remove_stale_folders()
    if removed:
        notes.append(f"removed {removed} scratch folder(s) left by an interrupted run")
    problem = gradebook.problem(root / "gradebook.db")
    if problem:
        raise ValueError(f"gradebook.db is damaged before grading ({problem}); restore it from "
                         f"{private / 'gradebook.backup.db'} or nbgrader's own backup first")
    gradebook.backup(root, private)
    record.write_file(private, record.RUN_MARKER, json.dumps(
        {"pid": os.getpid(), "started": datetime.now(timezone.utc).isoformat()}).encode())
    return notes


def _end_run(run: GradeRun, rows, grades, executed: dict[str, Executed]) -> None:
    """The run's line in runs.jsonl and its log (last_run.log); the run is over."""
    private = run.private
    # A fresh run's nonce reaches the disk only now that every worker is gone (replays use it).
    previous = _read_private(private, "runs.jsonl") or b""
    entry = {"assignment": run.assignment, "problems": run.problems, "nonce": run.nonce,
             "when": datetime.now(timezone.utc).isoformat(), "students": len(rows),
             "spec_hash": registry.spec_hash(run.assignment),
             "sandbox": sandbox.mode(), "notes": run.notes}
    record.write_file(private, "runs.jsonl", previous + (json.dumps(entry) + "\n").encode())
    log = ["sandbox: " + sandbox.mode(), *("  " + e for e in sandbox.capabilities().evidence),
           *run.notes, ""]
    for g in grades:
        log.append(f"{printable(g.student_id, 2000)}: "
                   + " | ".join(printable(n) for n in g.notes))
        nb = executed[g.student_id].nbgrader if g.student_id in executed else None
        if nb is not None and nb.log:
            log.append("  nbgrader: " + nb.log[-1500:])
    record.write_file(private, "last_run.log", "\n".join(log).encode("utf-8"))
    (private / record.RUN_MARKER).unlink(missing_ok=True)


def _announce_fallback() -> None:
    """Before any submission is graded: say on stderr (whatever ``quiet``) that student code
    will run without bubblewrap, why, and what to install or enable."""
    warning = sandbox.fallback_warning()
    if warning:
        print(f"cobotlab: {warning}", file=sys.stderr, flush=True)


def _print_summary(grades, assignment: str, elapsed: float, run_notes,
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
        print(f"{name:<{width}}  {score}  {text if g.graded else g.notes[-1]}")
    ungraded = [n for n, g in zip(names, grades) if not g.graded]
    if ungraded:
        print(f"NOT GRADED ({len(ungraded)}): {', '.join(ungraded)}: the grader failed on every "
              "attempt (see .cobotlab/last_run.log); no score was recorded for them, and the "
              "next `cobotlab grade` grades them again")
