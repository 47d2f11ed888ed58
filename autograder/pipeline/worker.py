"""The sandboxed worker that runs one submission's code, and its limits.

The code runs in a fresh worker process (:mod:`autograder.inside.worker`) inside the sandbox
of :mod:`autograder.sandbox` (bubblewrap: a read-only root holding only the interpreter and
the lab packages, not ``solutions/``, the specs or the course; a size-limited /tmp; no
network; run as ``nobody``), all of one submission's processes in one cgroup (memory and
process count), with per-process limits (address space, CPU seconds, file size). Time limits
count the CPU seconds of the student's process, so a grade does not depend on how busy the
grading machine is; a wall clock several times longer backs each of them up with a hard
kill. The cgroup has the CPU weight of one busy process, so another submission cannot crowd
this one out; and a cell or call the wall clock stopped under its CPU limit while it waited
for a CPU most of that time was starved by the machine: the grader's failure
(:class:`GraderError`, graded again in a fresh sandbox), where one that slept is the
student's time-out (:meth:`Worker._judge`, from the kernel's counts, never the worker's
report). Where bubblewrap cannot run, rlimits alone remain and every row says so
(``sandbox:rlimits_only``). Its replies are decoded defensively (no pickle).
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

from autograder import (
    checks,
    sandbox,
)
from autograder.forbidden import ALWAYS_FORBIDDEN
from autograder.inside import wire
from autograder.inside.worker import WALL_STRETCH
from autograder.outcomes import Cause, Failed, Failure, Place


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


def sandbox_available() -> bool:
    """True when student code runs under bubblewrap here (see :mod:`autograder.sandbox`)."""
    return sandbox.capabilities().bwrap


def _worker_env(home: str) -> dict[str, str]:
    """A clean environment: nothing of the grader's (no secret), and a process that stays
    single-threaded (a template forks: a thread pool would not survive the fork): one BLAS
    and one OpenCV thread, and Mesa's software renderer, which MuJoCo's EGL rendering of a
    lab's ``connect("sim")`` cell goes through, rasterising in the calling thread with no
    shader-cache writer thread (else every lab that opens the simulator grades cold)."""
    return {"PATH": "/usr/bin:/bin", "HOME": home, "LANG": "C.UTF-8", "MPLBACKEND": "Agg",
            "MPLCONFIGDIR": home, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1",
            "LP_NUM_THREADS": "0", "MESA_SHADER_CACHE_DISABLE": "true",
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
    fault: :func:`autograder.pipeline.pipeline.grade_course` retries it in a fresh sandbox
    and, if it persists, records no score."""


class TemplateUnavailable(RuntimeError):
    """A template (:mod:`autograder.template`) could not be built or could not fork a
    sandboxed worker: the submission gets a cold worker instead."""


# Wall clock for a fresh worker to say it is ready (interpreter start and the worker's
# imports, on a machine busy with other graders).
WORKER_START_S = 60.0


class CellHang(WorkerFailure):
    """A notebook cell hung past its hard deadline while loading: ``index`` says which (the
    message does not: a note writes the cell in from ``index``)."""

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


def _reported_failure(reply: dict) -> Failure:
    """The typed failure a call's reply reports. The worker is untrusted: the kinds it may
    claim are those that only cost the submission (a raise, a time-out, no such function,
    an unusable value); an exception's type name is what the code raised, capped; its
    place is the typed ``place`` (no reply holds it in words)."""
    kind = _REPORTED.get(reply.get("failure"), Failed.RAISED)
    exception = reply.get("exception")
    exception = exception[:80] if kind is Failed.RAISED and isinstance(exception, str) else ""
    return Failure(kind, exception=exception, place=Place.claimed(reply.get("place")))


@dataclass(frozen=True)
class WorkerSetup:
    """How one :class:`Worker` starts, besides its cells and limits (each field as the class
    says): the cell indices to ``skip``, its ``cgroup``, its lifetime ``cpu_s`` limit (None:
    600 s for a worker on its own; a :class:`NotebookRunner` computes one from the specs),
    the load ``budget`` (None: a fresh one of the limits), whether it is the submission's
    ``first`` worker, the ``template`` to fork from, the ``control_fd`` that makes it a
    template, and the ``forbidden`` routines."""

    skip: frozenset[int] = frozenset()
    cgroup: sandbox.Cgroup | None = None
    cpu_s: int | None = None
    # shared, not copied: every (re)start of one submission's worker spends the same budget
    budget: LoadBudget | None = None
    first: bool = True
    template: object = None      # an autograder.template.Template
    control_fd: int | None = None
    forbidden: tuple[str, ...] = ()


class Worker:
    """A student-code worker process, spoken to over two private pipes.

    ``setup`` (a :class:`WorkerSetup`) says how it starts. Loads the notebook one cell at a
    time, skipping the indices in ``skip`` and charging each cell to ``budget``; a cell
    that hangs past its wall-clock backstop raises :class:`CellHang` so the caller can
    restart without it. ``load_report`` lists what each
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

    def __init__(self, cells: list[str], limits: Limits, setup: WorkerSetup = WorkerSetup()):
        self.limits = limits
        cgroup, template = setup.cgroup, setup.template
        self._cgroup, self._student = cgroup, None
        budget = setup.budget or LoadBudget.of(limits)
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
            self._spawn(limits, cgroup, 600 if setup.cpu_s is None else setup.cpu_s,
                        setup.control_fd)
        try:
            self._load(cells, setup.skip, budget, template, setup.first, started,
                       setup.forbidden)
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
                raise not_loaded(limits)
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
                raise CellHang(index, str(exc)) from None
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
        # the words only: the line it stopped at travels typed (failure.place), and the
        # feedback writes it in, renumbered for the student
        text = str(error)[:400] if error else "the call failed"
        return checks.TrialOutcome(error=text, failure=_reported_failure(reply), **timing)

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


def not_loaded(limits: Limits) -> WorkerFailure:
    return WorkerFailure(f"the notebook did not load within {limits.load_timeout_s:g} s of "
                         "CPU time", Failure(Failed.WORKER_STOPPED, cause=Cause.LOAD_TIME))
