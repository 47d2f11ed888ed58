"""nbgrader's autograde for one student, in a throwaway course the student's code cannot leave.

Two ways. :func:`autograde_in_worker` (what ``cobotlab grade`` uses): nbgrader's converter in
the trusted process, the notebook's cells run once by the isolated grader's worker, which
grades the same submission in the same run. :func:`autograde_one` (nbgrader alone, and
assignments of several notebooks): nbgrader with its own kernel, as described next.

nbgrader's kernel runs the student's notebook, so it gets what that run needs and nothing
else: a scratch course (its own config, the assignment's source read-only, a gradebook that
holds only the assignment's definition, the one frozen submission) inside the sandbox of
:mod:`autograder.sandbox`, with a temporary ``HOME``, a minimal environment, no network and
a wall-clock deadline. Afterwards the trusted process reads the scratch gradebook
(:func:`autograder.gradebook.read_scratch_scores`) and keeps only cell scores it can
validate against the template it made itself (known cell, finite, ``0 <= score <= max``);
names, penalties and anything else the run wrote are ignored. What it reads back (the
gradebook, the autograded notebooks) it opens through :mod:`autograder.safe_files`: a
folder the kernel swapped for a link is never followed.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from autograder import safe_files, sandbox
from autograder.feedback import line_name
from autograder.freeze import Frozen, printable
from autograder.gradebook import CellScore, read_scratch_scores, set_duedate
from autograder.pipeline.cells import HIDDEN_MARK, hidden_tests_called

__all__ = ["ScratchResult", "make_template", "autograde_one",
           "autograde_in_worker", "put_interpreter_on_path", "speed_up_new_gradebooks"]

INSIDE = "/course"


@dataclass
class ScratchResult:
    """What one scratch autograde produced, validated: cell scores and the graded notebooks."""

    cells: list[CellScore] = field(default_factory=list)
    notebooks: dict[str, bytes] = field(default_factory=dict)   # name -> autograded .ipynb
    notes: list[str] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    log: str = ""
    seconds: float = 0.0   # wall clock of the nbgrader run itself


def put_interpreter_on_path() -> None:
    """Put this interpreter's ``bin`` folder first on ``$PATH`` (once).

    nbgrader runs ``alembic`` from ``$PATH`` whenever it creates a gradebook, so
    ``.venv/bin/cobotlab`` or ``.venv/bin/nbgrader`` without an activated virtual
    environment would fail with ``FileNotFoundError: 'alembic'``.
    """
    bin_dir = os.path.dirname(sys.executable)
    path = os.environ.get("PATH", "")
    if bin_dir not in path.split(os.pathsep):
        os.environ["PATH"] = bin_dir + (os.pathsep + path if path else "")


def speed_up_new_gradebooks() -> None:
    """Let this process create gradebooks without starting ``alembic`` each time.

    nbgrader stamps every new gradebook with the migration head it gets by running
    ``alembic heads`` in a subprocess (2.6 s here: a Python start-up and the imports of
    alembic and SQLAlchemy), and a grading run creates one per assignment; the same head
    read in process, once, costs 0.25 s. Checked against nbgrader 0.9's function name; if
    a later nbgrader lacks it, nothing is changed."""
    import nbgrader.api as api

    if getattr(api.get_alembic_version, "_cobotlab", False) or not hasattr(
            api, "get_alembic_version"):
        return
    from functools import lru_cache

    @lru_cache(maxsize=1)
    def head() -> str:
        from alembic.config import Config
        from alembic.script import ScriptDirectory
        from nbgrader.dbutil import _temp_alembic_ini

        with _temp_alembic_ini("sqlite:////tmp/gradebook.db") as ini:
            return str(ScriptDirectory.from_config(Config(ini)).get_current_head())

    head._cobotlab = True
    api.get_alembic_version = head


def _env(home: str) -> dict[str, str]:
    bin_dir = os.path.dirname(sys.executable)  # nbgrader runs `alembic` from PATH
    return {"PATH": f"{bin_dir}:/usr/bin:/bin", "HOME": home, "LANG": "C.UTF-8",
            "MPLBACKEND": "Agg", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
            "PYTHONDONTWRITEBYTECODE": "1", "JUPYTER_PLATFORM_DIRS": "1"}


def kernel_jail(course: Path, home: Path, source: Path, config: Path, assignment: str,
                scratch_mb: int = 64) -> sandbox.Jail:
    """nbgrader's view for one autograde: :func:`autograder.views.kernel_view` (an allow
    list: the interpreter, nbgrader's and a lab notebook's libraries, the public scoring)
    plus the throwaway ``course`` (read-write at /course), the assignment's ``source``
    files without its notebooks (read-only; nbgrader copies them over the submission, and
    they hold the practice data the hidden tests score on), and ``config``."""
    from autograder.practice import ENV_DIR
    from autograder.registry import notebook_packages
    from autograder.views import kernel_view

    env = _env("/home/student")
    env[ENV_DIR] = f"{INSIDE}/source/{assignment}"
    return sandbox.Jail.of_view(
        kernel_view(notebook_packages()),
        rw_at=((str(course), INSIDE), (str(home), "/home/student")),
        ro_at=((str(source), f"{INSIDE}/source/{assignment}"),
               (str(config), f"{INSIDE}/nbgrader_config.py")),
        scratch_mb=scratch_mb, chdir=INSIDE, env=env)


def copy_source_files(root: Path, assignment: str, dest: Path) -> Path:
    """The assignment's source folder without its notebooks (the answers and hidden tests
    are there: ``nbgrader autograde`` needs only the other files, and reads the notebooks'
    locked and test cells from the gradebook)."""
    shutil.copytree(root / "source" / assignment, dest, symlinks=False, dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("*.ipynb", ".ipynb_checkpoints",
                                                  "__pycache__"))
    return dest


def make_template(root: Path, assignment: str, work: Path, duedate=None) -> Path:
    """A gradebook with only ``assignment``'s definition (cells, checksums, max scores).

    Runs nbgrader's ``generate_assignment`` converter, in this process, on a copy of the
    source in ``work`` (instructor material only: no student code runs here; call it before
    any grading thread starts). Returns the gradebook's path.
    """
    if sandbox.stopping():
        raise sandbox.Interrupted("grading was interrupted")
    course = work / "template"
    (course / "source").mkdir(parents=True)
    shutil.copytree(root / "source" / assignment, course / "source" / assignment, symlinks=False,
                    ignore=shutil.ignore_patterns(".ipynb_checkpoints", "__pycache__"))
    # In this process (nbgrader is imported once for the whole run anyway), before any
    # grading thread starts: the converter's start() changes the working directory.
    speed_up_new_gradebooks()
    config = _course_config(root, course, assignment)
    log, messages = _captured_logger()
    try:
        from nbgrader.converters import GenerateAssignment
        from nbgrader.coursedir import CourseDirectory

        GenerateAssignment(coursedir=CourseDirectory(config=config), config=config,
                           log=log).start()
        error = ""
    except Exception as exc:  # noqa: BLE001 - reported below with nbgrader's log
        error = f"{type(exc).__name__}: {exc}"
    db = course / "gradebook.db"
    if error or not db.is_file():
        raise RuntimeError(f"nbgrader generate_assignment {assignment} failed on a copy of the "
                           f"source: {error} {messages.getvalue()[-1200:]}")
    if duedate is not None:
        set_duedate(db, assignment, duedate)
    return db


def _course_config(root: Path, course: Path, assignment: str, student: str | None = None):
    """The course's nbgrader configuration (the instructor's ``nbgrader_config.py``), aimed at
    the throwaway ``course`` and one ``assignment`` (and ``student``), overwriting output."""
    from traitlets.config.loader import PyFileConfigLoader

    config = PyFileConfigLoader("nbgrader_config.py", path=str(root)).load_config()
    config.CourseDirectory.root = str(course)
    config.CourseDirectory.assignment_id = assignment
    if student is not None:
        config.CourseDirectory.student_id = student
    config.BaseConverter.force = True
    return config


def _captured_logger():
    """(logger, its text): a private logger for one nbgrader converter's messages."""
    import logging

    text = io.StringIO()
    logger = logging.getLogger(f"cobotlab.nbgrader.{id(text)}")
    logger.propagate = False
    logger.setLevel(logging.INFO)
    logger.handlers = [logging.StreamHandler(text)]
    return logger, text


def _lay_out(course: Path, frozen: Frozen, assignment: str, template_db: Path) -> None:
    """A throwaway course: the one frozen submission and a copy of the template gradebook."""
    dest = course / "submitted" / frozen.student_id / assignment
    dest.parent.mkdir(parents=True)
    if frozen.folder is not None:
        shutil.copytree(frozen.folder, dest, symlinks=False)
    else:
        dest.mkdir()
    shutil.copy2(template_db, course / "gradebook.db")


# What nbgrader's own run may use besides its time and memory: processes in its cgroup,
# megabytes of its scratch course, megabytes of one autograded notebook read back.
MAX_PROCESSES = 256
SCRATCH_MB = 512
NOTEBOOK_MB = 20.0


def autograde_one(frozen: Frozen, assignment: str, root: Path, template_db: Path,
                  known: dict[tuple[str, str], float], *, timeout_s: float = 300,
                  cell_timeout_s: int | None = None, memory_mb: int = 3072) -> ScratchResult:
    """Run ``nbgrader autograde`` on one frozen submission in a throwaway course.

    Never raises because of the submission: a hang past ``timeout_s`` kills every process of
    the run (cgroup, PID namespace); whatever it did, the result holds validated cell scores
    only (missing ones are 0) and the autograded notebooks if they are well-formed JSON.
    ``memory_mb`` is for all its processes together; the other caps are
    :data:`MAX_PROCESSES`, :data:`SCRATCH_MB` and :data:`NOTEBOOK_MB`.
    """
    if sandbox.stopping():
        raise sandbox.Interrupted("grading was interrupted")
    result = ScratchResult()
    caps = sandbox.capabilities()
    with sandbox.ScratchDir(SCRATCH_MB) as scratch:
        course = scratch.path / "course"
        _lay_out(course, frozen, assignment, template_db)
        (course / "source" / assignment).mkdir(parents=True)  # the read-only bind's mount point
        source = copy_source_files(root, assignment, scratch.path / "source")
        shutil.copy2(root / "nbgrader_config.py", scratch.path / "nbgrader_config.py")
        (course / "nbgrader_config.py").touch()
        (scratch.path / "home").mkdir()
        scratch.give(scratch.path)
        if not scratch.size_limited:
            result.notes.append("nbgrader's scratch course is not size-limited here (not root)")

        nbgrader = [sys.executable, "-m", "nbgrader", "autograde", assignment, "--force",
                    "--student", frozen.student_id]
        if cell_timeout_s:
            nbgrader.append(f"--Execute.timeout={int(cell_timeout_s)}")
        cgroup = None
        if caps.bwrap:
            jail = kernel_jail(course, scratch.path / "home", source,
                               scratch.path / "nbgrader_config.py", assignment)
            if caps.cgroup:
                cgroup = sandbox.Cgroup(memory_mb, MAX_PROCESSES)
            command = sandbox.command(nbgrader + [f"--CourseDirectory.root={INSIDE}"], jail,
                                      cgroup)
            env, cwd = {}, "/"
        else:  # rlimits only: the throwaway course still keeps the real one out of reach
            copy_source_files(root, assignment, course / "source" / assignment)
            shutil.copy2(root / "nbgrader_config.py", course / "nbgrader_config.py")
            command = nbgrader + [f"--CourseDirectory.root={course}"]
            env, cwd = _env(str(scratch.path / "home")), str(course)
            result.flags.append("sandbox:rlimits_only")
        started = time.monotonic()
        try:
            proc = subprocess.Popen(command, cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    start_new_session=True)
            try:
                out, _ = proc.communicate(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, 9)
                out, _ = proc.communicate()
                result.notes.append(f"nbgrader autograde was stopped after {timeout_s:g} s")
                result.flags.append("nbgrader_timed_out")
            result.log = printable((out or b"")[-4000:].decode("utf-8", "replace"), 4000)
        finally:
            if cgroup is not None:
                if cgroup.oom_kills():
                    result.notes.append("nbgrader's run hit its memory limit "
                                        f"({memory_mb} MB for all its processes)")
                cgroup.remove()
        result.seconds = time.monotonic() - started
        result.notes.append(f"nbgrader autograde: {result.seconds:.1f} s")
        if sandbox.stopping():   # killed by stop_all(): what it left is not a result
            raise sandbox.Interrupted("grading was interrupted")
        _collect(course, assignment, frozen.student_id, known, NOTEBOOK_MB, result)
    return result


_GRADEBOOK_CAP = 256 * 2**20   # one assignment's definition and one student's submission


def _collect(course: Path, assignment: str, student: str, known: dict[tuple[str, str], float],
             notebook_mb: float, result: ScratchResult) -> None:
    """nbgrader's results in the scratch ``course`` into ``result``: the validated cell
    scores of its gradebook and its autograded notebooks (well-formed JSON only).

    nbgrader's kernel could have written anything there: every path is opened through
    :mod:`autograder.safe_files`, so a link anywhere on the way (``autograded/<student>/
    <lab>`` swapped for a link to the host's ``source/<lab>`` or a classmate's folder) is
    refused, noted and flagged ``nbgrader_output_refused:<name>``, never followed."""
    def refused(name: str, exc: safe_files.Refused, lost: str) -> None:
        result.notes.append(f"nbgrader's {name} not read: {printable(exc.where)} in its scratch "
                            f"course is {exc.detail}; {lost}")
        result.flags.append(f"nbgrader_output_refused:{name}")

    with tempfile.TemporaryDirectory(prefix="cobotlab-scores-") as private:
        copy = Path(private) / "gradebook.db"   # sqlite reads a path: a private copy's
        try:
            safe_files.copy_file(course, "gradebook.db", copy, _GRADEBOOK_CAP)
        except safe_files.Refused as exc:
            if exc.why is safe_files.Why.MISSING:
                result.notes.append("nbgrader's scratch gradebook is gone: its cell results "
                                    "are 0")
            else:
                refused("gradebook.db", exc, "its cell results are 0")
            result.cells = [CellScore(nb, c, 0.0, m) for (nb, c), m in sorted(known.items())]
        else:
            result.cells, notes = read_scratch_scores(copy, assignment, student, known)
            result.notes += notes
    for name in sorted({nb for nb, _ in known}):
        try:
            data = safe_files.read_file(course, ["autograded", student, assignment,
                                                 f"{name}.ipynb"], int(notebook_mb * 2**20))
            json.loads(data)
        except safe_files.Refused as exc:
            if exc.why is not safe_files.Why.MISSING:   # missing: nbgrader failed, and says so
                refused(name, exc, "its autograded notebook is not kept")
            continue
        except ValueError:
            result.notes.append(f"nbgrader's autograded notebook {name} is not JSON: not kept")
            result.flags.append(f"nbgrader_output_refused:{name}")
            continue
        result.notebooks[name] = data


# ------------------------------------------------------------ nbgrader with cobotlab's executor


def autograde_in_worker(frozen: Frozen, assignment: str, root: Path, template_db: Path,
                        known: dict[tuple[str, str], float], run_tests, *,
                        notebook_mb: float = NOTEBOOK_MB):
    """nbgrader's autograde of one frozen submission, its cells run once by cobotlab's grader.

    nbgrader's own converter runs here, in the trusted process, on a throwaway course (the
    template gradebook, the one submission): it sanitizes the notebook (clears outputs,
    restores locked and test cells from the gradebook, checks the metadata), then, where its
    ``Execute`` would start a kernel, ``run_tests([path])`` runs the sanitized notebook in the
    sandboxed worker, test cells included, and on the hidden problems in the same worker; its
    cell outcomes become the cells' outputs, and nbgrader scores them, saves the scores and
    applies the late penalty as usual. No student code runs in this process: the
    submission's notebook is only read, as JSON, by nbgrader and by the grader.

    ``run_tests(paths)`` must return ``(execution, verdicts)``: the
    :class:`autograder.pipeline.execution.Execution` of a run with ``run_tests=True`` and the verdict of
    each ``hidden_test(f)`` (:func:`autograder.pipeline.score.kernel_verdicts`). Returns
    ``(ScratchResult, execution)``; ``execution`` is None when nbgrader refused the notebook
    before running it (a broken or mangled notebook): nbgrader scores it 0 then, and the
    caller runs the raw submission itself.

    What differs from a kernel: cells run as plain Python (IPython magics removed), so the
    outputs hold what the cells printed and their errors, not rich output (plots, the
    ``check()`` tables); ``hidden_test(f)`` is scored on the grader's side on the same
    problems as in a kernel, so a submission that patches it or the kernel gains nothing.
    """
    from nbgrader.coursedir import CourseDirectory

    if sandbox.stopping():
        raise sandbox.Interrupted("grading was interrupted")
    # nbgrader's gradebook code trips SQLAlchemy's session warnings on every run, and
    # nbformat announces the duplicate cell ids nbgrader then fixes: its log has what matters.
    warnings.filterwarnings("ignore", message=r".*not in session.*")
    warnings.filterwarnings("ignore", message=r"Non-unique cell id")
    result = ScratchResult()
    logger, log_text = _captured_logger()
    execute = _worker_execute_class()(run_tests=run_tests)
    with tempfile.TemporaryDirectory(prefix="cobotlab-nbgrader-") as work:
        course = Path(work) / "course"
        _lay_out(course, frozen, assignment, template_db)
        shutil.copytree(root / "source" / assignment, course / "source" / assignment,
                        ignore=shutil.ignore_patterns(".ipynb_checkpoints", "__pycache__"))
        config = _course_config(root, course, assignment, frozen.student_id)
        started = time.monotonic()
        try:
            converter = _autograde_class()(coursedir=CourseDirectory(config=config),
                                           config=config, log=logger)
            converter.autograde_preprocessors = [
                execute if _is_execute(pp) else pp for pp in converter.autograde_preprocessors]
            converter.start()
        except Exception as exc:  # noqa: BLE001 - nbgrader's verdict, not the grader's
            result.notes.append(f"nbgrader autograde failed: {type(exc).__name__}: "
                                f"{printable(exc, 300)}")
        finally:
            logger.handlers = []
        # nbgrader's own share: the grader's time inside it is counted as the grader's
        result.seconds = time.monotonic() - started - (
            execute.execution.seconds if execute.execution is not None else 0.0)
        result.log = printable(log_text.getvalue()[-4000:], 4000)
        result.notes.append(f"nbgrader autograde: {result.seconds:.1f} s of its own (its cells "
                            "run by the grader)")
        _collect(course, assignment, frozen.student_id, known, notebook_mb, result)
    return result, execute.execution


def _is_execute(preprocessor) -> bool:
    from nbgrader.preprocessors import Execute

    if isinstance(preprocessor, str):
        return preprocessor.rsplit(".", 1)[-1] == "Execute"
    return isinstance(preprocessor, type) and issubclass(preprocessor, Execute)


_ENV_LOCK = threading.Lock()
_ENV_USERS: dict[str, int] = {}
_ENV_SAVED: dict[str, str | None] = {}


@contextlib.contextmanager
def _shared_setenv(**values):
    """``nbgrader.utils.setenv`` for threads: the variables are set while any thread is
    inside, and put back when the last one leaves. nbgrader's own deletes the variable when
    each conversion ends, so with two conversions at once (``--workers 2``) the second one
    to finish raised KeyError, and nbgrader removed that student's autograded notebook."""
    with _ENV_LOCK:
        for key, value in values.items():
            if not _ENV_USERS.get(key):
                _ENV_SAVED[key] = os.environ.get(key)
            _ENV_USERS[key] = _ENV_USERS.get(key, 0) + 1
            os.environ[key] = value
    try:
        yield
    finally:
        with _ENV_LOCK:
            for key in values:
                _ENV_USERS[key] -= 1
                if _ENV_USERS[key] == 0:
                    saved = _ENV_SAVED.pop(key)
                    if saved is None:
                        os.environ.pop(key, None)
                    else:
                        os.environ[key] = saved


def _autograde_class():
    """nbgrader's ``Autograde`` converter, minus the ``os.chdir`` of its ``start``: several
    submissions are graded at once in threads of one process, and the working directory
    is the process's (nothing here needs it: every path is absolute). For the same reason
    its environment variable is set with ``_shared_setenv``."""
    import nbgrader.utils
    from nbconvert.writers import FilesWriter
    from nbgrader.converters import Autograde

    nbgrader.utils.setenv = _shared_setenv  # autograde looks it up as utils.setenv per call

    class InProcessAutograde(Autograde):
        def start(self) -> None:
            self.init_notebooks()
            self.writer = FilesWriter(parent=self, config=self.config)
            self.exporter = self.exporter_class(parent=self, config=self.config)
            for pp in self.preprocessors:
                self.exporter.register_preprocessor(pp)
            self.convert_notebooks()

    return InProcessAutograde


def _worker_execute_class():
    """The preprocessor that stands where nbgrader's ``Execute`` does (nbgrader imported
    only when the cross-check runs)."""
    import nbformat
    from nbformat.v4 import new_output
    from nbgrader.preprocessors import NbGraderPreprocessor
    from nbgrader.utils import is_grade, is_solution

    class WorkerExecute(NbGraderPreprocessor):
        """Run the notebook in cobotlab's worker (and grade it there) instead of a kernel."""

        def __init__(self, run_tests=None, **kwargs):
            super().__init__(**kwargs)
            self.run_tests = run_tests
            self.execution = None

        def preprocess(self, nb, resources):
            with tempfile.TemporaryDirectory(prefix="cobotlab-sanitized-") as tmp:
                path = Path(tmp) / f"{resources['nbgrader']['notebook']}.ipynb"
                nbformat.write(nb, str(path))
                self.execution, verdicts = self.run_tests([path])
            ran = self.execution
            runs = {run.origin.position: run for run in ran.cell_runs}
            for position, cell in enumerate(nb.cells, 1):
                if cell.cell_type != "code":
                    continue
                run = runs.get(position)
                cell.outputs = []
                if run is None:
                    if not ran.cell_runs and cell.source.strip():
                        cell.outputs.append(_error_output(
                            "WorkerError", "the notebook did not load in cobotlab's worker"))
                    continue
                cell.execution_count = run.origin.prompt
                if run.stdout:
                    cell.outputs.append(new_output("stream", name="stdout", text=run.stdout))
                if run.stderr:
                    cell.outputs.append(new_output("stream", name="stderr", text=run.stderr))
                if run.error:
                    cell.outputs.append(_cell_error(run, ran.cell_origins))
                elif is_grade(cell) and not is_solution(cell) and HIDDEN_MARK in cell.source:
                    for name in hidden_tests_called([cell.source]):
                        verdict = verdicts.get(name, "not scored")
                        if verdict is not None:
                            cell.outputs.append(_error_output("AssertionError", verdict))
                            break   # the kernel would stop at the first failing assert
            return nb, resources

    def _cell_error(run, origins):
        """The error output of a cell that failed, as the kernel's would read: the
        exception's type and value, then the student's line it stopped at."""
        ename, evalue = run.exception or "Error", run.message
        if run.timed_out:
            ename, evalue = "CellTimeoutError", "stopped at its time limit"
        where = f" ({line_name(run.place, origins)})" if run.place is not None else ""
        return _error_output(ename, evalue + where)

    def _error_output(ename: str, evalue: str):
        return new_output("error", ename=ename, evalue=evalue,
                          traceback=[f"{ename}: {evalue}"])

    return WorkerExecute
