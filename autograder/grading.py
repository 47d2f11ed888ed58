"""The independent grader: scores one submission without trusting anything in it.

Why not just trust nbgrader's hidden-test cells? They run in the same kernel as the student's
code, which can swallow failing asserts, patch numpy or the kernel, or find the expected
answer on the caller's stack. So here the truth and the score never enter the student's
process:

1. The submitted notebook is read as JSON (a mangled or renamed notebook still works) and
   every code cell is kept in order, except hidden-test cells and IPython magics.
2. That code runs in a fresh worker process (:mod:`autograder.inside.worker`) inside the
   sandbox of :mod:`autograder.sandbox` (bubblewrap: a read-only root holding only the
   interpreter and the lab packages, not ``solutions/``, the specs or the course; a
   size-limited /tmp; no network; run as ``nobody``), all of one submission's processes in
   one cgroup (memory and process count), with per-process limits (address space, CPU
   seconds, file size). Time limits count the CPU seconds of the student's process, so a
   grade does not depend on how busy the grading machine is; a wall clock several times
   longer backs each of them up with a hard kill. The cgroup has the CPU weight of one
   busy process, so another submission cannot crowd this one out; and a cell or call the
   wall clock stopped under its CPU limit while it waited for a CPU most of that time was
   starved by the machine: the grader's failure (:class:`GraderError`, graded again in a
   fresh sandbox), where one that slept is the student's time-out (:meth:`Worker._judge`,
   from the kernel's counts, never the worker's report). Where bubblewrap cannot run,
   rlimits alone remain and every row says so (``sandbox:rlimits_only``).
3. Problems are drawn from the secret seed, the assignment, the student id and the function
   name only (:func:`draw_problems`), so a regrade gives the same submission the same
   problems and the same score. A run that asks for fresh problems mixes in a random nonce,
   which reaches the disk (the run log, for replays) only after the workers are gone. Only
   the inputs go to the worker; its replies are decoded defensively (no pickle) into an
   :class:`Execution` (:func:`execute_notebook`: what each call came to, a value or a typed
   failure, nothing scored), which :func:`score_execution` scores here, a pure function,
   against truth that stays here. :func:`grade_notebook` is the three in a row.

A crash, hang, NaN or exception costs the student the problems it touched, nothing else; a
worker that dies is restarted for the next function. A function whose code reaches one of
its spec's forbidden routines (:mod:`autograder.forbidden`) scores zero, flagged.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import math
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from autograder import checks, safe_files, sandbox
from autograder.forbidden import ALWAYS_FORBIDDEN, static_hits
from autograder.inside import wire
from autograder.inside.worker import WALL_STRETCH
from autograder.nbgrader_cells import cell_role
from autograder.outcomes import Cause, Failed, Failure, Flag, Note

__all__ = [
    "SECRET_ENV",
    "cell_source",
    "PRIVATE_DIR",
    "Limits",
    "SubmissionGrade",
    "CellOrigin",
    "CellRun",
    "load_secret",
    "specs_of",
    "create_secret",
    "problem_rng",
    "extract_code",
    "scan_for_tampering",
    "sandbox_available",
    "Worker",
    "NotebookRunner",
    "Problems",
    "DrawnProblems",
    "draw_all",
    "draw_problems",
    "Execution",
    "FunctionRun",
    "execute_notebook",
    "score_execution",
    "kernel_verdicts",
    "GraderError",
    "TemplateUnavailable",
    "grade_notebook",
]

SECRET_ENV = "COBOTLAB_GRADING_SECRET"
PRIVATE_DIR = ".cobotlab"          # inside the course directory; never under source/ or release/
SECRET_FILE = "secret"
HIDDEN_MARK = "BEGIN HIDDEN TESTS"


@dataclass(frozen=True)
class Limits:
    """Resource limits for one submission's worker."""

    # Memory: each process's address space (numpy + matplotlib need about 1 GB of it) and,
    # under a cgroup, the resident memory of all the submission's processes together.
    memory_mb: int = 2048
    max_processes: int = 32        # processes and threads of the submission at once (cgroup)
    file_mb: int = 16              # largest file the student code may write
    scratch_mb: int = 64           # the sandbox's writable /tmp, all files together
    reply_kb: int = 1024           # largest reply of one call (a pose is about 0.3 KB)
    # Time limits are CPU seconds of the student's process, so a grade does not depend on how
    # busy the grading machine is; each has a wall-clock backstop of ``wall_factor`` times it
    # (for code that sleeps or blocks). The worker's whole life is capped (RLIMIT_CPU) at the
    # sum of its load and call limits, so a student who disables the timers gains nothing.
    # Each notebook cell while loading. Lab 4's released capture cell (40 stereo renders of
    # the simulator) takes 9-12 s of CPU: with 10 s it timed out on a loaded machine and the
    # students' feedback blamed their notebook for it (and for the NameErrors that followed).
    cell_timeout_s: float = 20.0
    load_timeout_s: float = 90.0   # loading, restarts after hung cells included
    call_timeout_s: float | None = None   # per call; None: the function spec's own limit
    wall_factor: float = checks.WALL_BACKSTOP_FACTOR
    deadline_s: float = 600.0      # the whole submission, wall clock: then it is cut off

    def call_limit_s(self, spec: checks.FunctionSpec) -> float:
        """CPU seconds one trial of ``spec`` may take (a closed loop: all of its calls)."""
        return self.call_timeout_s or spec.time_limit_s

    def worker_cpu_s(self, specs) -> int:
        """RLIMIT_CPU of one worker: loading plus every trial of every function at its limit."""
        calls = sum(spec.n_trials * self.call_limit_s(spec) for spec in specs)
        return int(math.ceil(self.load_timeout_s + calls)) + 10


@dataclass(frozen=True)
class CellRun:
    """One notebook cell as the worker first ran it: ``origin`` says where it sits; ``error``
    is empty when it ran through; ``timed_out`` when its limit stopped it; ``stdout`` and
    ``stderr`` are the first few KB it wrote to each."""

    origin: CellOrigin
    error: str = ""
    where: str = ""
    stdout: str = ""
    stderr: str = ""
    timed_out: bool = False


@dataclass
class SubmissionGrade:
    """One student's result: per-function scores, tamper flags, and notes for the instructor."""

    student_id: str
    assignment: str
    functions: list[checks.FunctionResult] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    # Where each code cell the worker ran ("cell N" in errors: its index here) sits in the
    # notebook, so feedback can number cells as the student sees them.
    cell_origins: list[CellOrigin] = field(default_factory=list)
    # With ``run_tests``: what each cell did on the first load (nbgrader's view of the run),
    # and the verdict of each function's in-notebook hidden test (None: passed).
    cell_runs: list[CellRun] = field(default_factory=list)
    kernel_checks: dict[str, str | None] = field(default_factory=dict)
    # False when the grader itself failed on every attempt: no score is recorded (not 0),
    # the row says ``grader_error``, and the next run grades the submission again.
    graded: bool = True
    # Where the wall clock went (s): until the worker was ready (sandbox, interpreter,
    # imports; or the fork of a template), the template's shared cells (run once for the
    # class, not for this submission), the submission's own cells, the hidden problems and
    # tests; and the peak memory of its cgroup (MB; None without one).
    profile: dict = field(default_factory=lambda: {
        "start_s": 0.0, "shared_s": 0.0, "cells_s": 0.0, "hidden_s": 0.0, "peak_mb": None})

    @property
    def score(self) -> float:
        return round(sum(f.points for f in self.functions), 2)

    @property
    def max_score(self) -> float:
        return round(sum(f.max_points for f in self.functions), 2)


# --------------------------------------------------------------------------- secret and seeds


def create_secret(course_dir) -> Path:
    """Write a new random grading secret to ``<course>/.cobotlab/secret`` (mode 0600)."""
    private = Path(course_dir) / PRIVATE_DIR
    private.mkdir(mode=0o700, parents=True, exist_ok=True)
    path = private / SECRET_FILE
    if not path.exists():
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32) + "\n")
    return path


_SECRET_CAP = 4096   # bytes: a secret is 64 hex digits; anything past this is no secret


def load_secret(course_dir=None) -> str:
    """The grading secret: ``$COBOTLAB_GRADING_SECRET``, else ``<course>/.cobotlab/secret``,
    read through :mod:`autograder.safe_files` (a regular file, no link followed below the
    course: a link there could hand the grader a secret someone else chose, or leak which
    file it points at). ValueError names the problem and the fix."""
    value = os.environ.get(SECRET_ENV, "").strip()
    if not value and course_dir is not None:
        try:
            data = safe_files.read_file(Path(course_dir), [PRIVATE_DIR, SECRET_FILE],
                                        _SECRET_CAP)
        except safe_files.Refused as exc:
            if exc.why is not safe_files.Why.MISSING:
                raise ValueError(f"the grading secret {Path(course_dir) / PRIVATE_DIR / SECRET_FILE}"
                                 f" is refused: {exc.detail} ({exc.where}). Make it a regular "
                                 "file of the course (copy the content in, mode 0600), or set "
                                 f"${SECRET_ENV}") from None
            data = b""
        value = data.decode("utf-8", "replace").strip()
    if len(value) < 16:
        raise ValueError(
            f"no grading secret (at least 16 characters) found: set ${SECRET_ENV} or run "
            "init_course(DIR) / `cobotlab course init DIR`, which writes "
            f"DIR/{PRIVATE_DIR}/{SECRET_FILE}"
        )
    return value


def problem_rng(secret: str, nonce: str | None, assignment: str, student_id: str,
                function: str) -> np.random.Generator:
    """The generator for one student's hidden problems of one function.

    HMAC-SHA256 keyed by the secret over the names, so students get different problems and
    a student cannot predict theirs. ``nonce`` None (or empty): the course's fixed problems,
    the same on every regrade; a nonce (fresh problems, on request) gives other problems,
    the same again whenever that nonce is replayed.
    """
    message = "\x1f".join([nonce or "", assignment, student_id, function]).encode()
    digest = hmac.new(secret.encode(), message, hashlib.sha256).digest()
    return np.random.default_rng(int.from_bytes(digest, "big"))


# --------------------------------------------------------------------------- notebook reading


def cell_source(cell) -> str:
    """A notebook cell's source as one string ("" for anything that is not one)."""
    source = cell.get("source", "") if isinstance(cell, dict) else ""
    if isinstance(source, list):
        source = "".join(s for s in source if isinstance(s, str))
    return source if isinstance(source, str) else ""


def _strip_magics(source: str) -> str | None:
    """Drop IPython-only lines (``%...``, ``!...``); None for a cell magic (``%%...``) cell."""
    if source.lstrip().startswith("%%"):
        return None
    return "\n".join("pass  # magic removed" if line.lstrip().startswith(("%", "!")) else line
                     for line in source.splitlines())


@dataclass(frozen=True)
class CellOrigin:
    """Where an extracted code cell sits in the student's notebook: ``position`` counts every
    cell from 1 (markdown too); ``prompt`` is its ``In [n]`` after Restart and Run All (code
    cells with code in them, counted from 1; an empty cell does not advance the counter)."""

    notebook: str
    position: int
    prompt: int


def _is_test_cell(cell: dict) -> bool:
    """An nbgrader autograder-test cell (graded, not a solution), by its metadata."""
    return cell_role(cell).autograder_test


def extract_code(notebook_paths, with_origins: bool = False, tests: set[int] | None = None):
    """(code cells in order, notes) from one or more notebooks, hidden-test cells left out;
    with ``with_origins``, (cells, origins, notes), a :class:`CellOrigin` per kept cell.

    Reads raw JSON and tolerates missing metadata, deleted, duplicated or reordered cells:
    graded functions are found later by name, not by cell id.

    ``tests``: a set to fill with the indices of the kept autograder-test cells. Given it, the
    nbgrader test cells (by metadata) are kept, hidden tests included. Only pass it for a
    notebook nbgrader has sanitized (its ``OverwriteCells`` put the instructor's source back
    into every cell whose metadata says it is a test), or a student could mark a cell as one.
    """
    if isinstance(notebook_paths, (str, Path)):
        notebook_paths = [notebook_paths]
    cells, origins, notes = [], [], []
    for path in notebook_paths:
        try:
            nb = json.loads(Path(path).read_text(encoding="utf-8", errors="replace"))
            raw_cells = nb.get("cells", []) if isinstance(nb, dict) else []
        except (OSError, ValueError) as exc:
            text = f"{Path(path).name}: unreadable notebook ({type(exc).__name__})"
            notes.append(Note(text, for_student=text))
            continue
        prompt = 0
        for position, cell in enumerate(raw_cells if isinstance(raw_cells, list) else [], 1):
            if not isinstance(cell, dict) or cell.get("cell_type") != "code":
                continue
            source = cell_source(cell)
            prompt += bool(source.strip())
            is_test = tests is not None and _is_test_cell(cell)
            if HIDDEN_MARK in source and not is_test:
                continue
            source = _strip_magics(source)
            if source and source.strip():
                if is_test:
                    tests.add(len(cells))
                cells.append(source)
                origins.append(CellOrigin(Path(path).name, position, prompt))
    return (cells, origins, notes) if with_origins else (cells, notes)


# Patterns that have no business in a lab answer; a match is flagged for the instructor
# to look at (it does not change the score, which is computed independently anyway).
_TAMPER_PATTERNS = {
    "exception_handler": r"set_custom_exc|sys\.excepthook|showtraceback",
    "kernel_patch": r"\.kernel\b|do_execute|run_cell|ipykernel|shell_handlers",
    "sys_modules": r"sys\.modules\s*\[[^\]]*\]\s*=|sys\.modules\.(?:update|pop|__setitem__)",
    "numpy_patch": r"\b(?:np|numpy)(?:\.\w+)+\s*=(?!=)|setattr\(\s*(?:np|numpy)\b",
    # Student-facing imports are fine: check, and the practice data of autograder.datasets
    # and autograder.synthetic (lab 1 on); any other use of the package is looked at.
    "grader_patch": r"\bautograder\b(?!\.checks import check\b|\.(?:datasets|synthetic) import\b)",
    "secret_probe": r"COBOTLAB_GRADING_SECRET|\.cobotlab\b|os\.environ|getenv",
    "stack_inspection": r"_getframe|inspect\.(?:stack|currentframe)|f_back|f_locals",
    "signal_handling": r"\bsignal\.(?:signal|setitimer|alarm)|\bsetrlimit\b",
    # A lab answer reads no other files' code: searching the disk and running what it finds
    # is how a submission would reach an answer key (none is in the worker's view).
    "file_search": r"\bos\.walk\b|\bos\.scandir\b|\bos\.listdir\b|\bglob\.i?glob\b|"
                   r"\.rglob\(|\bsys\.path\b|\bsite\.getsitepackages\b",
    "code_loading": r"(?<![\w.])(?:exec|compile)\s*\(|\brunpy\b|spec_from_file_location|"
                    r"SourceFileLoader|\bimp\.load_source\b",
}


def scan_for_tampering(cells: list[str]) -> list[str]:
    """Names of suspicious patterns found in the student's code (see ``_TAMPER_PATTERNS``)."""
    code = "\n".join(cells)
    code = "\n".join(line for line in code.splitlines()
                     if "from autograder.checks import check" not in line)
    return [f"suspicious_{name}" for name, pattern in _TAMPER_PATTERNS.items()
            if re.search(pattern, code)]


# --------------------------------------------------------------------------- the worker


def sandbox_available() -> bool:
    """True when student code runs under bubblewrap here (see :mod:`autograder.sandbox`)."""
    return sandbox.capabilities().bwrap


def _worker_env(home: str) -> dict[str, str]:
    """A clean environment: nothing of the grader's (no secret), one BLAS and one OpenCV
    thread (a template forks: a thread pool would not survive the fork)."""
    return {"PATH": "/usr/bin:/bin", "HOME": home, "LANG": "C.UTF-8", "MPLBACKEND": "Agg",
            "MPLCONFIGDIR": home, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1",
            "PYTHONDONTWRITEBYTECODE": "1", "PYTHONHASHSEED": "0"}


def worker_jail(limits: Limits) -> sandbox.Jail:
    """The worker's view (:func:`autograder.views.worker_view`: an allow list of the
    interpreter, a lab notebook's libraries and the worker's own modules; never
    ``solutions/``, the specs, the checks, the course or $HOME; with the packages the
    course's cobotlab.toml adds for its labs), read-only, and a /tmp scratch."""
    from autograder.registry import notebook_packages
    from autograder.views import worker_view

    return sandbox.Jail.of_view(worker_view(notebook_packages()), scratch_mb=limits.scratch_mb,
                                chdir="/tmp", env=_worker_env("/tmp"))


class WorkerFailure(Exception):
    """The worker timed out, died or broke the protocol; it has been killed. ``failure``:
    what that was, for the problem it happened on."""

    def __init__(self, message: str, failure: Failure | None = None):
        super().__init__(message)
        self.failure = failure or Failure(Failed.WORKER_STOPPED, cause=Cause.OTHER)


class GraderError(RuntimeError):
    """The grader could not grade: its sandbox did not start, before any student code ran,
    or the machine starved a cell or call (:meth:`Worker._judge`). Never the submission's
    fault: :func:`autograder.course.grade_course` retries it in a fresh sandbox and, if it
    persists, records no score."""


class TemplateUnavailable(RuntimeError):
    """A template (:mod:`autograder.template`) could not be built or could not fork a
    sandboxed worker: the submission gets a cold worker instead."""


# Wall clock for a fresh worker to say it is ready (interpreter start and the worker's
# imports, on a machine busy with other graders).
WORKER_START_S = 60.0


class CellHang(WorkerFailure):
    """A notebook cell hung past its hard deadline while loading (``index`` says which)."""

    def __init__(self, index: int, message: str):
        super().__init__(message)
        self.index = index


@dataclass
class LoadBudget:
    """What loading the notebook may still cost, summed over every (re)start of the worker:
    CPU seconds of the cells, and the wall-clock backstop."""

    cpu_s: float
    wall_s: float

    @classmethod
    def of(cls, limits: Limits) -> LoadBudget:
        return cls(limits.load_timeout_s, limits.wall_factor * limits.load_timeout_s)

    @property
    def exhausted(self) -> bool:
        return self.cpu_s <= 0 or self.wall_s <= 0

    def spend(self, cpu_s: float, wall_s: float) -> None:
        self.cpu_s -= cpu_s
        self.wall_s -= wall_s


# A cell or call stopped by the wall clock under its CPU limit was starved, not asleep, when
# it waited in the run queue for at least this share of the wall clock and could run for
# less than its wall-clock limit. The worker adds run-queue waits back to the wall clock (up
# to WALL_STRETCH times it), so this is a machine too busy even for that, or a worker with
# no view of its run queue.
STARVED_SHARE = 0.5


@dataclass(frozen=True)
class _Usage:
    """A worker's time as the kernel counts it, read by the grader (nothing the student's
    code reports): ``cpu_s`` of its submission's cgroup (without one: of the worker
    process, its reaped children included) and ``waited_s`` its threads spent runnable
    but not running, at ``at`` (monotonic)."""

    at: float
    cpu_s: float
    waited_s: float


def _process_times(pid: int) -> tuple[int, float, float] | None:
    """(start time in ticks, CPU seconds with reaped children, run-queue wait seconds of
    its threads) of process ``pid``, from /proc; None when it is gone or unreadable."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        cpu = sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")
        start = int(fields[19])
        waited = 0
        for tid in os.listdir(f"/proc/{pid}/task"):
            try:
                with open(f"/proc/{pid}/task/{tid}/schedstat", "rb") as f:
                    waited += int(f.read().split()[1])
            except (OSError, ValueError, IndexError):   # a thread that just ended
                pass
    except (OSError, ValueError, IndexError):
        return None
    return start, cpu, waited / 1e9


def _student_process(proc) -> tuple[int, int] | None:
    """(host pid, start time) of the process that runs a worker's student code: a
    template's fork's process 1, process 2 of a bubblewrap sandbox (1 is bubblewrap's
    reaper), or the worker itself without a sandbox. Found by the grader, not told."""
    fork_pid = getattr(proc, "submission_pid", None)
    if fork_pid is not None:
        pid = fork_pid()
    elif sandbox_available():
        pid = sandbox.host_pid(2, proc.pid)
    else:
        pid = proc.pid
    times = _process_times(pid) if pid is not None else None
    return (pid, times[0]) if times is not None else None


def _reported_cpu(reply: dict, wall_s: float) -> float:
    """The CPU seconds a reply claims, clipped to [0, wall clock x cores]: the worker is
    untrusted, and a forged figure must not stretch a budget past its wall backstop."""
    cpu = reply.get("cpu_seconds")
    if not isinstance(cpu, (int, float)) or not math.isfinite(cpu):
        return wall_s
    return min(max(float(cpu), 0.0), wall_s * (os.cpu_count() or 1))


# The kinds of failure a worker may report for a call; anything else is taken as a raise.
_REPORTED = {"raised": Failed.RAISED, "timed_out": Failed.TIMED_OUT,
             "not_found": Failed.NOT_FOUND, "unusable": Failed.UNUSABLE}


def _reported_failure(reply: dict, where: str) -> Failure:
    """The typed failure a call's reply reports. The worker is untrusted: the kinds it may
    claim are those that only cost the submission (a raise, a time-out, no such function,
    an unusable value); an exception's type name is what the code raised, capped; its
    place is the typed ``place`` (``where`` is only the words of the message)."""
    from autograder.outcomes import Place  # here: grading.py's imports are being split

    kind = _REPORTED.get(reply.get("failure"), Failed.RAISED)
    exception = reply.get("exception")
    exception = exception[:80] if kind is Failed.RAISED and isinstance(exception, str) else ""
    return Failure(kind, exception=exception, place=Place.claimed(reply.get("place")))


class Worker:
    """A student-code worker process, spoken to over two private pipes.

    Loads the notebook one cell at a time, skipping the indices in ``skip`` and charging
    each cell to ``budget``; a cell that hangs past its wall-clock backstop raises
    :class:`CellHang` so the caller can restart without it. ``load_report`` lists what each
    cell did. ``cpu_s`` is the worker's lifetime CPU limit (RLIMIT_CPU).

    With ``template`` (an :class:`autograder.template.Template` whose shared cells begin
    ``cells``), the worker is a fork of it in a sandbox of its own instead of a new
    interpreter: the shared cells' reports are the template's (charged to ``budget`` as if
    run here) and loading starts after them; it raises
    :class:`TemplateUnavailable` when the template cannot fork.
    ``control_fd`` starts a template instead (its end of the control socket).
    ``forbidden``: the routines the graded functions must not call, which the worker takes
    hold of before any of the submission's cells runs (:class:`autograder.inside.tripwire.Guard`).
    ``start_s`` and ``cells_s`` are the wall-clock seconds until the worker was ready and
    of the cells it ran itself.
    """

    def __init__(self, cells: list[str], limits: Limits, skip: set[int] = frozenset(),
                 cgroup: sandbox.Cgroup | None = None, cpu_s: int = 600,
                 budget: LoadBudget | None = None, first: bool = True,
                 template=None, control_fd: int | None = None, forbidden=()):
        self.limits = limits
        self._cgroup, self._student = cgroup, None
        budget = budget or LoadBudget.of(limits)
        started = time.monotonic()
        self.workdir = str(sandbox.private_folder("cobotlab-worker-"))
        self._stderr = open(os.path.join(self.workdir, ".worker-stderr"), "w+b")
        self.load_report: list[dict] = []
        self.tripped: set[str] = set()
        self.shared = 0
        if template is not None:
            try:
                self.proc, self._req_w, self._rep_r = template.fork(self._stderr.fileno(),
                                                                    cgroup)
            except Exception:
                self._stderr.close()
                shutil.rmtree(self.workdir, ignore_errors=True)
                raise
            self.shared = len(template.cells)
        else:
            self._spawn(limits, cgroup, cpu_s, control_fd)
        try:
            self._load(cells, skip, budget, template, first, started, forbidden)
        except BaseException:
            # Whatever stopped the load (a cell that hung, a reply the grader refused, an
            # interrupt), no process or scratch folder of this worker outlives it.
            self.close()
            raise

    def _load(self, cells, skip, budget: LoadBudget, template, first: bool,
              started: float, forbidden=()) -> None:
        """Wait for the worker's hello, then run the notebook's cells (see the class)."""
        limits = self.limits
        self._wait_ready(first)
        self._student = _student_process(self.proc)
        if forbidden:   # a fork too: the template's cells are the instructor's, not student code
            self._request({"op": "forbid", "names": sorted(forbidden)}, WORKER_START_S)
        self.start_s = time.monotonic() - started
        for reply in template.replies if template is not None else ():
            seconds = float(reply.get("seconds", 0.0))
            budget.spend(_reported_cpu(reply, seconds), seconds)
            self.load_report.append(dict(reply))
        started = time.monotonic()
        for index, source in enumerate(cells):
            if index < self.shared:
                continue
            if index in skip:
                self.load_report.append({"index": index, "ok": False, "error": "skipped",
                                         "skipped": True})
                continue
            if budget.exhausted:
                raise _not_loaded(limits)
            cpu = min(limits.cell_timeout_s, budget.cpu_s)
            wall = min(limits.wall_factor * cpu, budget.wall_s)
            cell_started = time.monotonic()
            try:
                reply = self._request({"op": "cell", "index": index, "source": source,
                                       "timeout": cpu, "wall": wall},
                                      WALL_STRETCH * wall + 2.0,
                                      limits=(cpu, wall, f"cell {index}"))
            except WorkerFailure as exc:
                budget.spend(0.0, time.monotonic() - cell_started)
                raise CellHang(index, f"cell {index}: {exc}") from None
            elapsed = time.monotonic() - cell_started
            budget.spend(_reported_cpu(reply, elapsed), elapsed)
            self.load_report.append(dict(reply, index=index, skipped=False))
        self.cells_s = time.monotonic() - started

    def _spawn(self, limits: Limits, cgroup, cpu_s: int, control_fd: int | None) -> None:
        """Start a new interpreter in a new sandbox (a template's with ``control_fd``)."""
        req_r, self._req_w = os.pipe()
        self._rep_r, rep_w = os.pipe()
        python = [sys.executable, "-I", "-m", "autograder.inside.worker", str(req_r), str(rep_w),
                  str(limits.memory_mb), str(int(cpu_s)), str(limits.file_mb)]
        passed = (req_r, rep_w)
        if control_fd is not None:
            python.append(str(control_fd))
            passed += (control_fd,)
        if sandbox_available():   # a template's forks install the keyring filter themselves
            command, env = sandbox.command(python, worker_jail(limits), cgroup,
                                           syscall_filter=control_fd is None), {}
        else:  # rlimits only: the worker still starts in an empty directory with a clean env
            command, env = python, _worker_env(self.workdir)
        self.proc = subprocess.Popen(
            command, cwd=self.workdir, env=env, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=self._stderr, pass_fds=passed,
            start_new_session=True)
        os.close(req_r)
        os.close(rep_w)

    def _wait_ready(self, first: bool) -> None:
        """Wait for the worker's hello. A first worker that never says it (bubblewrap refused
        to start, the interpreter is not in the sandbox's view) is the grader's failure; a
        restarted one may be the submission's doing (processes it left in its cgroup), so
        that counts as the worker stopping, as any other death does."""
        try:
            hello = wire.receive(self._rep_r, time.monotonic() + WORKER_START_S, 4096)
            if hello.get("op") == "ready":
                return
            why = f"unexpected first message {str(hello)[:80]}"
            if hello.get("op") == "isolation_failed":   # a template's fork, before any
                self._kill()                            # student code: start cold instead
                self.close()
                raise TemplateUnavailable(f"a fork could not make its sandbox: "
                                          f"{str(hello.get('error'))[:200]}")
        except (wire.WireError, OSError) as exc:
            why = str(exc)
        self._kill()
        detail = self.stderr_tail()
        self.close()
        if self.shared:   # a fork that failed before any student code: the template's fault
            raise TemplateUnavailable(f"a fork did not start ({why}): {detail or 'no message'}")
        if first:
            raise GraderError(f"the sandboxed worker did not start ({why}): "
                              f"{detail or 'no message'}")
        raise WorkerFailure(f"the worker process did not restart ({why})")

    def stderr_tail(self, limit: int = 300) -> str:
        """The last bytes the worker (or bubblewrap) wrote to stderr, as text."""
        try:
            self._stderr.flush()
            self._stderr.seek(0)
            return self._stderr.read()[-limit:].decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""

    def _kill(self) -> None:
        """Kill the process group (a fork: its PID namespace) and reap it; stderr stays
        readable (for a message)."""
        if self.proc.poll() is None:
            if not isinstance(self.proc, subprocess.Popen):
                self.proc.kill()
            else:
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass

    def request(self, message: dict, timeout_s: float, max_bytes: int = 64 * 1024) -> dict:
        """Send ``message`` and return the reply (within ``timeout_s``, at most
        ``max_bytes``); a hang, death or malformed reply kills the worker and raises
        :class:`WorkerFailure`."""
        return self._request(message, timeout_s, max_bytes)

    def _request(self, message: dict, timeout_s: float, max_bytes: int = 64 * 1024,
                 limits: tuple[float, float, str] | None = None) -> dict:
        """:meth:`request`; with ``limits`` (CPU seconds, wall-clock seconds, what runs) a
        cell or call, which raises :class:`GraderError` when it failed at the wall clock
        because the machine starved it (see :meth:`_judge`)."""
        before = self._usage() if limits is not None else None
        try:
            wire.send(self._req_w, message)
            reply = wire.receive(self._rep_r, time.monotonic() + timeout_s, max_bytes)
        except (wire.WireError, OSError) as exc:
            if limits is not None:   # before the worker is killed: its counters go with it
                self._judge(before, *limits)
            self.close()
            code = self.proc.returncode
            if isinstance(exc, wire.WireTimeout):
                raise WorkerFailure(f"timed out after {timeout_s:g} s",
                                    Failure(Failed.TIMED_OUT)) from None
            if isinstance(exc, wire.WireTooLarge):
                raise WorkerFailure(f"the reply was too large ({exc}; the cap is "
                                    f"{max_bytes // 1024} KB)") from None
            if isinstance(exc, wire.WireError) and not isinstance(exc, wire.WireClosed):
                # Only student code in the worker can have written it: the worker's own
                # encoder refuses what the grader would.
                raise WorkerFailure(f"the worker sent a malformed reply ({exc})") from None
            reason = {-signal.SIGXCPU: "CPU time limit", -signal.SIGKILL: "killed",
                      -signal.SIGSEGV: "crashed (segmentation fault)"}.get(code, f"exit code {code}")
            raise WorkerFailure(f"the worker process stopped ({reason}; memory or CPU limits "
                                "are enforced)", Failure(Failed.WORKER_STOPPED, cause=(
                                    Cause.CPU_LIMIT if code == -signal.SIGXCPU
                                    else Cause.OTHER))) from None
        # Stopped by its CPU timer, it had its CPU: the cgroup's count, read a moment apart
        # and kept by other bookkeeping, can fall a hair short and must not overrule that.
        if limits is not None and reply.get("ok") is not True and reply.get("limit") != "cpu":
            self._judge(before, *limits)
        return reply

    def _usage(self, children: bool = False) -> _Usage | None:
        """The trusted sample :meth:`_judge` compares (None where the kernel does not say).
        Without the cgroup's count, ``children`` counts every live process of the sandbox,
        all of its CPU so far: judged at the end of a cell, a submission that crowds out
        its own worker with busy processes of its own has then used its limit."""
        if self._student is None:
            return None
        pid, start = self._student
        times = _process_times(pid)
        if times is None or times[0] != start:   # gone, or its pid reused
            return None
        cpu = self._cgroup.cpu_seconds() if self._cgroup is not None else None
        if cpu is None and children:   # everything in the sandbox, orphans included
            tree = {self.proc.pid, *sandbox._descendants(self.proc.pid)}
            cpu = sum(t[1] for t in map(_process_times, tree) if t)
        return _Usage(time.monotonic(), times[1] if cpu is None else cpu, times[2])

    def _judge(self, before: _Usage | None, cpu_s: float, wall_s: float, what: str) -> None:
        """Raise :class:`GraderError` (the worker killed) when the cell or call that began
        at ``before`` and has just failed was starved: it ran ``wall_s`` of wall clock, its
        submission used under ``cpu_s`` of CPU, and the worker waited in the run queue for
        at least :data:`STARVED_SHARE` of that time (runnable, not running) and could run
        for less than ``wall_s``. A cell that sleeps or blocks is not runnable, so its
        time-out stays the submission's."""
        after = self._usage(children=True)
        if before is None or after is None:
            return
        elapsed = after.at - before.at
        cpu = after.cpu_s - before.cpu_s
        waited = after.waited_s - before.waited_s
        if elapsed >= wall_s and cpu < cpu_s and waited >= STARVED_SHARE * elapsed \
                and elapsed - waited < wall_s:
            self.close()
            raise GraderError(
                f"{what} was stopped by the {wall_s:g} s wall clock having had {cpu:.1f} s of "
                f"its {cpu_s:g} s of CPU: it waited {waited:.0f} s for a CPU (the machine "
                "was too busy: the grader's failure, not the submission's)") from None

    def call(self, name: str, args: tuple, timeout_s: float,
             forbidden_names=(), substitutes: dict | None = None) -> checks.TrialOutcome:
        """Call ``name(*args)`` in the worker, stopped after ``timeout_s`` CPU seconds (wall
        clock: ``limits.wall_factor`` times that); a hang, death or oversized reply raises
        WorkerFailure. Calls of ``forbidden_names`` the tripwire saw go to ``tripped``;
        ``substitutes`` are the stand-in tables of :attr:`checks.FunctionSpec.substitutes`."""
        wall = self.limits.wall_factor * timeout_s
        started = time.monotonic()
        # The worker's own timers fire first; the extra seconds are for a worker that blocks them.
        reply = self._request({"op": "call", "name": name, "args": list(args),
                               "timeout": timeout_s, "wall": wall,
                               "forbidden": list(forbidden_names),
                               "substitutes": substitutes or {}},
                              WALL_STRETCH * wall + 2.0, self.limits.reply_kb * 1024,
                              limits=(timeout_s, wall, f"a call of {name}"))
        return self._outcome(reply, time.monotonic() - started, forbidden_names)

    def call_many(self, name: str, calls: list[tuple[tuple, dict | None]], timeout_s: float,
                  forbidden_names=()) -> list[checks.TrialOutcome] | None:
        """Each of ``calls`` ((args, stand-in tables)) as :meth:`call` would make it, in one
        round trip; the outcomes up to the first that timed out. None when the batch cannot
        stand for single calls: a reply that is not a batch, or a call that failed at its
        wall clock rather than its CPU timer (only a single call can be judged starved:
        make those calls one by one). A hang or death raises WorkerFailure, as for a call."""
        wall = self.limits.wall_factor * timeout_s
        started = time.monotonic()
        reply = self._request({"op": "calls", "name": name, "timeout": timeout_s, "wall": wall,
                               "forbidden": list(forbidden_names),
                               "calls": [{"args": list(args), "substitutes": tables or {}}
                                         for args, tables in calls]},
                              len(calls) * (WALL_STRETCH * wall + 2.0),
                              len(calls) * self.limits.reply_kb * 1024)
        replies = reply.get("replies")
        if reply.get("ok") is not True or not isinstance(replies, list) \
                or not 0 < len(replies) <= len(calls) \
                or not all(isinstance(r, dict) for r in replies):
            return None
        if any(r.get("ok") is not True and r.get("failure") == "timed_out"
               and r.get("limit") != "cpu" for r in replies):
            return None
        elapsed = time.monotonic() - started
        outcomes = []
        for r in replies:
            seconds = r.get("seconds")
            seconds = float(seconds) if isinstance(seconds, (int, float)) \
                and 0 <= seconds <= elapsed else elapsed
            outcomes.append(self._outcome(r, seconds, forbidden_names))
        return outcomes

    def _outcome(self, reply: dict, elapsed: float, forbidden_names) -> checks.TrialOutcome:
        """The outcome one call's ``reply`` reports (its forbidden routines go to
        ``tripped``); ``elapsed``: the call's wall-clock seconds."""
        tripped = reply.get("forbidden")
        if isinstance(tripped, list):
            self.tripped.update(str(t)[:80] for t in tripped[:8]
                                if str(t) in set(forbidden_names) | set(ALWAYS_FORBIDDEN))
        timing = {"seconds": elapsed, "cpu_seconds": _reported_cpu(reply, elapsed)}
        if reply.get("ok") is True and "value" in reply:
            return checks.TrialOutcome(value=reply["value"], **timing)
        error = reply.get("error")
        where = reply.get("where")
        where = where[:60] if isinstance(where, str) else ""
        text = str(error)[:400] if error else "the call failed"
        if where:
            text += f" ({where})"
        return checks.TrialOutcome(error=text, failure=_reported_failure(reply, where),
                                   **timing)

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        self._kill()
        for fd in (self._req_w, self._rep_r):
            try:
                os.close(fd)
            except OSError:
                pass
        self._req_w = self._rep_r = -1
        self._stderr.close()
        shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --------------------------------------------------------------------------- one submission
#
# Three steps, each a function of the one before: draw the problems (from the secret, in
# this process: the truth never leaves it), execute the notebook on them in a sandboxed
# worker (an Execution: what each call came to, nothing scored), and score (a pure function
# of the problems and the execution, which a test can call without a sandbox).


@dataclass(frozen=True)
class Problems:
    """One submission's hidden problems: ``trials[function]`` in the lab's order, truth
    included, and the public trials ``hidden_test(function)`` scores on (the kernel seeds);
    drawn on the trusted side (:class:`DrawnProblems`)."""

    assignment: str
    student_id: str
    trials: dict[str, list[checks.Trial]]
    kernel: KernelTrials

    def kernel_trials(self, name: str) -> list[checks.Trial]:
        return self.kernel.of(name)


class KernelTrials:
    """The public problems of :data:`checks.KERNEL_SEEDS` per function, drawn once for the
    class (they are the same for everyone) and when first asked for."""

    def __init__(self, assignment: str):
        self.specs = {s.name: s for s in specs_of(assignment)}
        self._drawn: dict[str, list[checks.Trial]] = {}
        self._lock = threading.Lock()

    def of(self, name: str) -> list[checks.Trial]:
        with self._lock:
            if name not in self._drawn:
                spec = self.specs[name]
                self._drawn[name] = [t for seed in checks.KERNEL_SEEDS
                                     for t in checks.public_trials(spec, seed)]
            return self._drawn[name]


class DrawnProblems:
    """Every submission's hidden problems of one run, drawn before any code runs (from the
    secret, the run's nonce, the assignment, the student id and the function name:
    :func:`problem_rng`), and read-only from then on: the draw stage's value, which the
    execute stage sends the inputs of and the score stage scores on."""

    def __init__(self, assignment: str, by_student: dict[str, Problems],
                 kernel: KernelTrials):
        self.assignment, self.kernel = assignment, kernel
        self._by_student = MappingProxyType(dict(by_student))

    def of(self, student_id: str) -> Problems:
        """The student's problems; KeyError naming the student when none were drawn."""
        try:
            return self._by_student[student_id]
        except KeyError:
            raise KeyError(f"no problems of {self.assignment} were drawn for "
                           f"{student_id!r}: it was not among this run's submissions") from None


def draw_all(assignment: str, secret: str, nonce: str | None,
             student_ids) -> DrawnProblems:
    """The hidden problems of each of ``student_ids`` (see :func:`draw_problems`), drawn now,
    all of them, with one set of public kernel-seed trials shared by all."""
    kernel = KernelTrials(assignment)
    return DrawnProblems(assignment, {sid: draw_problems(assignment, sid, secret, nonce, kernel)
                                      for sid in dict.fromkeys(student_ids)}, kernel)


def draw_problems(assignment: str, student_id: str, secret: str, nonce: str | None,
                  kernel: KernelTrials | None = None) -> Problems:
    """One student's hidden problems of ``assignment`` (see :func:`problem_rng`)."""
    trials = {spec.name: checks.make_trials(spec, problem_rng(secret, nonce, assignment,
                                                              student_id, spec.name))
              for spec in specs_of(assignment)}
    return Problems(assignment, student_id, trials, kernel or KernelTrials(assignment))


def specs_of(assignment: str):
    """The graded functions' specs of ``assignment``, in the lab's order; ValueError, naming
    the known assignments, when none is registered (the one place that says so)."""
    specs = checks.SPECS.get(assignment)
    if specs is None:
        raise ValueError(f"no graded functions are registered for assignment {assignment!r}; "
                         f"known assignments: {sorted(checks.SPECS)}")
    return specs


@dataclass
class FunctionRun:
    """What one graded function did on its problems: an outcome per problem (a value, or a
    typed failure), in order; ``forbidden``: the forbidden routines it reached (the static
    scan's, then no problem was run, or the tripwire's), which make it score zero."""

    name: str
    outcomes: list[checks.TrialOutcome] = field(default_factory=list)
    forbidden: tuple[str, ...] = ()


@dataclass
class Execution:
    """What one submission's code did, and nothing scored: per graded function a
    :class:`FunctionRun` on its hidden problems; per ``hidden_test(f)`` of nbgrader's test
    cells (``run_tests``: ``kernel_tests`` names them in order), one on the kernel seeds'
    public problems (none for a function forbidden or unknown); what each cell did on
    the first load; the flags of the static scan and of the sandbox; the notes for the
    instructor; the time it took (``profile``: see :class:`SubmissionGrade`)."""

    student_id: str
    assignment: str
    functions: list[FunctionRun] = field(default_factory=list)
    kernel_tests: list[str] = field(default_factory=list)
    kernel_runs: dict[str, FunctionRun] = field(default_factory=dict)
    suspicious: list[str] = field(default_factory=list)
    sandbox_flags: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    cell_origins: list[CellOrigin] = field(default_factory=list)
    cell_runs: list[CellRun] = field(default_factory=list)
    seconds: float = 0.0
    profile: dict = field(default_factory=lambda: {
        "start_s": 0.0, "shared_s": 0.0, "cells_s": 0.0, "hidden_s": 0.0, "peak_mb": None})


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
    cgroup = None
    if caps.bwrap and caps.cgroup:
        try:
            cgroup = sandbox.Cgroup(limits.memory_mb, limits.max_processes)
        except (OSError, RuntimeError) as exc:
            # The run's header promised a cgroup: this row says it did not get one.
            run.sandbox_flags.append(Flag("sandbox", "no_cgroup"))
            run.notes.append(f"no cgroup for this submission ({exc}): per-process limits "
                             "only")
    if template is not None and not template.matches(cells):
        run.notes.append("started cold: the notebook's first cells are not the released "
                         "notebook's read-only ones")
        template = None
    worker = NotebookRunner(cells, limits, run, tests, cgroup, template, routines,
                            limits.worker_cpu_s(specs), run_tests)
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
            profile["peak_mb"] = cgroup.peak_memory_mb()
            if cgroup.oom_kills():
                text = (f"the memory limit ({limits.memory_mb} MB for all the submission's "
                        f"processes) stopped it {cgroup.oom_kills()} time(s)")
                run.notes.append(Note(text, for_student=text))
            cgroup.remove()
    if not caps.bwrap:
        run.sandbox_flags.append(Flag("sandbox", "rlimits_only"))
    elif not caps.syscall_filter:   # a machine the keyring filter does not know
        run.sandbox_flags.append(Flag("sandbox", "no_keyring_filter"))
    run.seconds = time.monotonic() - started
    return run


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
                 tests: set[int] = frozenset(), cgroup=None, template=None, routines=(),
                 cpu_s: int | None = None, run_tests: bool = False, batch_calls: bool = False):
        run = execution if execution is not None else Execution(student_id="", assignment="")
        if cpu_s is None:
            cpu_s = limits.worker_cpu_s(specs_of(run.assignment))
        self.cells, self.limits, self.execution, self.tests = cells, limits, run, set(tests)
        self.cgroup, self.template, self.routines, self.cpu_s = cgroup, template, routines, cpu_s
        self.run_tests, self.batch_calls = run_tests, batch_calls
        self.worker: Worker | None = None
        self.skip: set[int] = set()
        # over every restart, not since the start: a worker that dies late must still be
        # able to reload
        self.budget = LoadBudget.of(limits)
        self.starts = 0
        self.noted_load = False

    def loaded(self) -> Worker:
        if self.worker is not None and self.worker.alive:
            return self.worker
        if self.worker is not None:
            self.worker.close()
        self.starts += 1
        run, profile = self.execution, self.execution.profile
        start = dict(cells=self.cells, limits=self.limits, skip=self.skip, run=run,
                     budget=self.budget, cgroup=self.cgroup, cpu_s=self.cpu_s,
                     first=self.starts == 1, forbidden=self.routines)
        try:
            self.worker = _start_worker(**start, template=self.template)
        except TemplateUnavailable as exc:
            run.notes.append(f"started without the template ({exc})")
            self.template = None
            self.worker = _start_worker(**start)
        worker = self.worker
        profile["start_s"] += worker.start_s
        profile["cells_s"] += worker.cells_s
        if worker.shared:
            profile["shared_s"] = self.template.shared_s
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


def score_execution(problems: Problems, execution: Execution) -> SubmissionGrade:
    """The grade of one submission: a pure function of its problems and of what its code
    did on them (no sandbox, no I/O, no student code). A function that reached a forbidden
    routine scores zero, flagged ``forbidden:<routine>``; each ``hidden_test(f)`` of the
    test cells gets its verdict in ``kernel_checks`` (None: passed), scored as the in-kernel
    hidden test scores it (:data:`checks.KERNEL_SEEDS`) but here."""
    specs = {s.name: s for s in specs_of(problems.assignment)}
    grade = SubmissionGrade(student_id=execution.student_id, assignment=execution.assignment,
                            notes=list(execution.notes), seconds=execution.seconds,
                            cell_origins=list(execution.cell_origins),
                            cell_runs=list(execution.cell_runs),
                            profile=dict(execution.profile))
    for run in execution.functions:
        spec = specs[run.name]
        grade.functions.append(
            checks.forbidden_result(spec, run.forbidden) if run.forbidden
            else checks.score_function(spec, problems.trials[run.name], run.outcomes))
    grade.flags = [*execution.suspicious, *(
        Flag("forbidden", name) for name in sorted({n for r in execution.functions
                                                    for n in r.forbidden})),
        *execution.sandbox_flags]
    grade.kernel_checks = kernel_verdicts(problems, execution)
    return grade


def kernel_verdicts(problems: Problems, execution: Execution) -> dict[str, str | None]:
    """The verdict of each ``hidden_test(f)`` of the test cells, in order (None: passed,
    else why not), scored as the in-kernel hidden test scores it but here."""
    specs = {s.name: s for s in specs_of(problems.assignment)}
    banned = {r.name: r.forbidden for r in execution.functions if r.forbidden}
    return {name: _kernel_verdict(name, specs, banned, problems, execution)
            for name in execution.kernel_tests}


def _kernel_verdict(name: str, specs: dict, banned: dict, problems: Problems,
                    execution: Execution) -> str | None:
    """The verdict of ``hidden_test(name)`` (None: passed, else why not)."""
    spec = specs.get(name)
    if spec is None:
        return f"no graded function is named {name!r}"
    if name in banned:
        return checks.forbidden_result(spec, banned[name]).summary()
    run = execution.kernel_runs[name]
    result = (checks.forbidden_result(spec, run.forbidden) if run.forbidden else
              checks.score_function(spec, problems.kernel_trials(name), run.outcomes))
    return None if result.fraction >= 1.0 else result.summary()


def grade_notebook(notebook_paths, assignment: str, student_id: str, secret: str,
                   nonce: str | None, limits: Limits = Limits(),
                   run_tests: bool = False, template=None) -> SubmissionGrade:
    """Grade one submission on its own hidden problems: :func:`draw_problems`, then
    :func:`execute_notebook` (see it for ``run_tests`` and ``template``), then
    :func:`score_execution`. Never raises because of anything in the submission."""
    problems = draw_problems(assignment, student_id, secret, nonce)
    return score_execution(problems, execute_notebook(notebook_paths, problems, limits,
                                                      run_tests, template))


_HIDDEN_TEST_CALL = re.compile(r"\bhidden_test\(\s*([A-Za-z_]\w*)")


def hidden_tests_called(test_sources) -> list[str]:
    """The functions the test cells' ``hidden_test(f)`` lines name, in order, once each.

    Read from the instructor's source (restored by nbgrader), not reported by the worker,
    so student code that patches ``hidden_test`` cannot skip one."""
    names: list[str] = []
    for source in test_sources:
        for name in _HIDDEN_TEST_CALL.findall(source):
            if name not in names:
                names.append(name)
    return names


def _timed_out(reply: dict) -> bool:
    """A cell's reply (or the grader's own entry for a skipped cell) says its time limit
    stopped it."""
    return reply.get("failure") == "timed_out"


def _cell_runs(report: list[dict], origins: list[CellOrigin], skip: set[int]) -> list[CellRun]:
    """:class:`CellRun` of every cell from a first load's report (a cell skipped after it
    hung counts as timed out; replies are the worker's, so every field is capped text)."""
    runs = []
    for entry, origin in zip(report, origins):
        error = "" if entry.get("ok") is True else str(entry.get("error") or "failed")[:400]
        timed_out = entry.get("ok") is not True and _timed_out(entry)
        if entry.get("skipped") and entry.get("index") in skip:
            error, timed_out = "timed out", True
        runs.append(CellRun(origin, error, str(entry.get("where") or "")[:80],
                            str(entry.get("stdout") or "")[:4096],
                            str(entry.get("stderr") or "")[:4096], timed_out))
    return runs


def _start_worker(cells, limits: Limits, skip: set[int], run: Execution,
                  budget: LoadBudget, cgroup: sandbox.Cgroup | None, cpu_s: int,
                  first: bool, template=None, forbidden=()) -> Worker:
    """A loaded worker (a fork of ``template`` when given); cells that hang or time out are
    skipped on every later restart. ``first``: no worker of this submission has started
    yet (see :class:`GraderError`)."""
    while True:
        if budget.exhausted:
            raise _not_loaded(limits)
        try:
            worker = Worker(cells, limits, skip, cgroup, cpu_s, budget, first=first,
                            template=template, forbidden=forbidden)
        except CellHang as exc:
            first = False
            skip.add(exc.index)
            run.notes.append(cell_error_note(f"{exc} (skipped from then on)"))
            continue
        # A cell stopped by its timer would only cost the same seconds again next restart.
        skip.update(r["index"] for r in worker.load_report
                    if r.get("ok") is not True and _timed_out(r))
        return worker


def cell_error_note(error: str, where: str | None = None) -> Note:
    """The note of a notebook cell that failed while loading: ``error`` and, when given,
    the student's line it stopped at ("cell 4, line 7"); the student reads it too."""
    text = f"  cell error: {error}" + (f" ({where})" if where is not None else "")
    return Note(text, for_student=f"{error} ({where})" if where else error)


def _not_loaded(limits: Limits) -> WorkerFailure:
    return WorkerFailure(f"the notebook did not load within {limits.load_timeout_s:g} s of "
                         "CPU time", Failure(Failed.WORKER_STOPPED, cause=Cause.LOAD_TIME))


def _note_load(run: Execution, report: list[dict], tests: set[int]) -> None:
    """Note what the first load did; errors of the test cells are nbgrader's result, not
    notes."""
    failed = [c for c in report if isinstance(c, dict) and not c.get("ok")
              and not c.get("skipped") and c.get("index") not in tests]
    run.notes.append(f"notebook loaded: {len(report)} code cells, {len(failed)} raised")
    for c in failed[:5]:
        run.notes.append(cell_error_note(str(c.get("error"))[:200], str(c.get("where") or "")))
    chars = max([c.get("output_chars", 0) for c in report if isinstance(c, dict)
                 and isinstance(c.get("output_chars"), int)] or [0])
    if chars > 100_000:
        run.notes.append(f"printed {chars} characters while loading (output discarded)")
