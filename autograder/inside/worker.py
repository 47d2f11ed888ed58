"""The student-code worker: runs one submission's code and calls its functions on request.

Started by :mod:`autograder.pipeline.worker` as ``python -I -m autograder.inside.worker REQ_FD REPLY_FD
MEM_MB CPU_S FILE_MB``, inside the sandbox of :mod:`autograder.sandbox` where it can run
(no view of the course, the answer key or the specs; ``autograder.checks`` is replaced by a
stub so the notebook's ``from autograder.checks import check`` still works, and
``robots.viewer`` by one that draws nothing: see ``_NotDrawn``), with a clean
environment; it sets those resource limits on itself before any student code runs. It holds
no secret and no ground truth: it receives problem *inputs* only and sends back whatever the
student's function returned. Everything it sends is re-validated (and size-capped) by the
grader, so student code that patches this module gains nothing but a zero.

Requests: ``{"op": "cell", "index": i, "source": src, "timeout": s, "wall": w}`` runs one
notebook cell in the shared namespace, stopped after ``s`` CPU seconds or ``w`` wall-clock
seconds (an exception or timeout ends that cell only); the reply carries the first few KB
the cell wrote to stdout and to stderr; a failed cell or call's reply says where the
student's code stopped as ``"place": [cell index, line]`` (null when no cell of the notebook
was on the stack; never in words, which the grader writes from the place), and a raise's
``"exception"`` (its type's name) and ``"message"`` (``str(exc)``, capped);
``{"op": "forbid", "names": [...]}``, sent before any student code, takes hold of the
routines graded functions must not call (:class:`autograder.inside.tripwire.Guard`);
``{"op": "call", "name": f, "args": [...], "timeout": s, "wall": w, "forbidden": [...],
"substitutes": {name: [[args, value], ...]}}`` calls a function by name, those routines
poisoned and a tripwire on them (calls seen are reported as ``"forbidden"`` in the reply;
the grader's own static scan is the authoritative rule, the report can only add to it),
with the stand-ins of :mod:`autograder.inside.standin`; ``{"op": "calls", "name": f,
"calls": [{"args": [...], "substitutes": {...}}, ...], "timeout": s, "wall": w,
"forbidden": [...]}`` makes those calls one after another, each as a "call" (its own limits),
and replies ``{"ok": true, "replies": [...]}``, stopping after a call that timed out;
``{"op": "quit"}``.
"""

from __future__ import annotations

import builtins
import importlib
import io
import json
import os
import resource
import signal
import socket
import sys
import threading
import time
import traceback
import types

from autograder.inside import isolate, standin, syscalls, tripwire, wire

OUTPUT_KEEP = 4096


class _Timeout(BaseException):
    """Raised by the alarm; a BaseException so ``except Exception`` in student code misses it.
    ``by_cpu``: the CPU timer fired (the code used its CPU limit), not the wall clock."""

    def __init__(self, by_cpu: bool = False):
        super().__init__()
        self.by_cpu = by_cpu


class _CappedWriter(io.TextIOBase):
    """stdout or stderr replacement: counts everything, keeps the first few KB of each cell's
    output (nbgrader's view of a test cell: what it printed, and whether it wrote to stderr)."""

    def __init__(self):
        self.head, self.kept, self.total = [], 0, 0

    def write(self, s):
        s = str(s)
        if self.kept < OUTPUT_KEEP:
            self.head.append(s[: OUTPUT_KEEP - self.kept])
            self.kept += len(self.head[-1])
        self.total += len(s)
        return len(s)

    def writable(self):
        return True

    def take(self) -> str:
        """What was kept since the last call, and forget it."""
        text, self.head, self.kept = "".join(self.head), [], 0
        return text


# The wall clock is the backstop for code that sleeps or blocks, so it counts the time the
# cell or call could have run: seconds it spent runnable in the run queue, waiting for a CPU
# that other graders held, are added back, up to this many times the wall-clock limit (past
# that the grader judges it starved: see autograder.pipeline.worker.Worker._judge).
WALL_STRETCH = 3.0


class _Clock:
    """The running cell's or call's limits and the counters at its start, for the alarm."""

    active = False
    started = waited = sandbox_cpu = cpu_s = wall_s = 0.0


def _waited_s() -> float:
    """Seconds this process's threads spent runnable but not running (schedstat)."""
    total = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 0.0
    for tid in tasks:
        try:
            with open(f"/proc/self/task/{tid}/schedstat", "rb") as f:
                total += int(f.read().split()[1])
        except (OSError, ValueError, IndexError):   # a thread that just ended
            pass
    return total / 1e9


def _sandbox_cpu_s() -> float | None:
    """CPU seconds of every process in this sandbox's PID namespace, reaped children
    included; None outside one (the host's processes are not the submission's).

    A fork of the template may keep the template's ``/proc`` (see
    :func:`autograder.inside.isolate.enter_own_pid_namespace`), which lists other submissions
    too: there only this process's descendants count, which are all of its namespace's
    processes, since it is that namespace's process 1 (orphans are reparented to it).
    """
    if os.getpid() > 2:   # a sandbox's worker is process 1 (a fork) or 2 (bubblewrap's)
        return None
    stats = {}
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                with open(f"/proc/{pid}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()
                stats[int(pid)] = (int(fields[1]), [int(x) for x in fields[11:15]])
            except (OSError, ValueError, IndexError):   # a process that just ended
                pass
    try:
        me = int(os.readlink("/proc/self"))
    except (OSError, ValueError):
        return None
    ours = set(stats)   # our own /proc: every process listed is the sandbox's
    if me != os.getpid():
        ours, grew = {me}, True
        while grew:
            found = {pid for pid, (parent, _) in stats.items() if parent in ours} - ours
            ours |= found
            grew = bool(found)
    # This process's own time as the kernel keeps it for its CPU timer and for the
    # grader's cgroup (/proc's ticks are sampled, and may reach the limit first): a cell
    # stopped at its wall clock that had not reached its CPU limit must be stretched.
    mine = stats.pop(me, (0, [0, 0, 0, 0]))[1]
    ticks = sum(sum(stats[pid][1]) for pid in ours if pid in stats) + mine[2] + mine[3]
    return ticks / os.sysconf("SC_CLK_TCK") + time.process_time()


def _wall_left(now: float) -> float:
    """Seconds of wall clock the running cell or call still has: its limit less the time it
    could run, when it was starved by other processes (not by its own: their CPU counts
    against its limit) and is within :data:`WALL_STRETCH`; else 0."""
    cpu = _sandbox_cpu_s()
    if not _Clock.active or cpu is None or cpu - _Clock.sandbox_cpu >= _Clock.cpu_s:
        return 0.0
    elapsed = now - _Clock.started
    could_run = elapsed - (_waited_s() - _Clock.waited)
    left = min(_Clock.wall_s - could_run, WALL_STRETCH * _Clock.wall_s - elapsed)
    return left if left > 0.01 else 0.0


def _on_alarm(signum, frame):
    # Raised inside the tripwire's profile hook, the time-out would make CPython drop the
    # hook, which the tripwire must read as student code removing it (every forbidden
    # routine flagged). So it is put off by a millisecond, to the student's next line.
    if tripwire.Tripwire.is_hook(frame):
        signal.setitimer(signal.ITIMER_REAL, 0.001)
        return
    if signum == signal.SIGALRM:
        left = _wall_left(time.monotonic())
        if left:
            signal.setitimer(signal.ITIMER_REAL, left)
            return
    raise _Timeout(by_cpu=signum == signal.SIGPROF)


def _message(exc: BaseException) -> str:
    """``str(exc)``, capped: the exception's value as a traceback's last line shows it."""
    message = str(exc)
    return message[:300] + "..." if len(message) > 300 else message


def _describe(exc: BaseException) -> str:
    if isinstance(exc, _Timeout):
        return "timed out"
    message = _message(exc)
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def _failure(exc: BaseException) -> dict:
    """The reply for a cell or call that raised ``exc``. A time-out by the CPU timer says so:
    the grader then charges it to the submission without judging starvation (the one claim
    it takes from the worker, since it can only cost the submission that makes it)."""
    frame = _student_frame(exc)
    reply = {"ok": False, "error": _describe(exc), "place": _place(frame)}
    if isinstance(exc, _Timeout):
        reply["failure"] = "timed_out"
        if exc.by_cpu:
            reply["limit"] = "cpu"
    else:
        reply["failure"], reply["exception"] = "raised", type(exc).__name__
        reply["message"] = _message(exc)
    return reply


# The file name each cell was compiled under -> its index: a failure's place is looked up
# here, not read back out of the name (student code may compile its own "<cell ...>").
_CELL_FILES: dict[str, int] = {}


def _cell_file(index) -> str:
    """The file name cell ``index`` is compiled under, remembered for :func:`_place`."""
    name = f"<cell {index}>"
    if isinstance(index, int) and not isinstance(index, bool):
        _CELL_FILES[name] = index
    return name


def _student_frame(exc: BaseException):
    """The innermost frame of ``exc``'s traceback in a notebook cell (no grader frames)."""
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        if frame.filename.startswith("<cell"):
            return frame
    return None


def _place(frame) -> list[int] | None:
    """The student's own line that raised as ``[cell index, line]`` (a typed place for the
    grader), or None."""
    if frame is None or frame.filename not in _CELL_FILES or not frame.lineno:
        return None
    return [_CELL_FILES[frame.filename], frame.lineno]


def _run_guarded(fn, cpu_s: float, wall_s: float):
    """``fn()`` stopped by :class:`_Timeout` after ``cpu_s`` seconds of this process's CPU
    time or ``wall_s`` seconds of wall clock (less the time it waited for a CPU, see
    :data:`WALL_STRETCH`), whichever comes first.

    CPU time is the limit that counts: it does not grow when other graders share the
    machine, so the same code meets the same limit on a quiet laptop and on a loaded CI
    runner. The wall clock is the backstop for code that sleeps or blocks.
    """
    _Clock.started, _Clock.cpu_s, _Clock.wall_s = time.monotonic(), float(cpu_s), float(wall_s)
    _Clock.waited, _Clock.sandbox_cpu = _waited_s(), _sandbox_cpu_s() or 0.0
    _Clock.active = True
    signal.setitimer(signal.ITIMER_PROF, max(0.001, float(cpu_s)))
    signal.setitimer(signal.ITIMER_REAL, max(0.001, float(wall_s)))
    try:
        return fn()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.setitimer(signal.ITIMER_PROF, 0.0)
        _Clock.active = False


class _Unsendable(Exception):
    """A graded function's value that is not made of arrays, numbers, lists and the like."""


def _settled(value):
    """``value`` rebuilt from plain lists, tuples, dicts, numbers and arrays.

    Done inside the graded call, while the forbidden routines are poisoned: a returned
    object whose conversion runs code (a list subclass's ``__iter__``, an array subclass)
    runs it there, not while the reply is sent.
    """
    try:
        return wire.decode(wire.encode(value))
    except (wire.WireError, TypeError, ValueError, OverflowError) as exc:
        raise _Unsendable(str(exc)) from None


def _limits_of(request: dict) -> tuple[float, float]:
    cpu = request.get("timeout", 10.0)
    cpu = float(cpu) if isinstance(cpu, (int, float)) else 10.0
    wall = request.get("wall", 4 * cpu)
    return cpu, float(wall) if isinstance(wall, (int, float)) else 4 * cpu


def _tables(request: dict) -> dict:
    """The request's stand-in tables, {name: [(args, value), ...]}, malformed entries dropped."""
    tables = request.get("substitutes")
    if not isinstance(tables, dict):
        return {}
    return {str(name): [(tuple(e[0]), e[1]) for e in entries
                        if isinstance(e, (list, tuple)) and len(e) == 2
                        and isinstance(e[0], (list, tuple))]
            for name, entries in tables.items() if isinstance(entries, list)}


def _stub_checks() -> None:
    """A do-nothing ``autograder.checks``: notebooks import ``check`` from it, but the real
    module (and the specs behind it) is not in the sandbox, and practice scores are not
    needed while grading."""
    stub = types.ModuleType("autograder.checks")
    stub.check = stub.hidden_test = lambda *args, **kwargs: None
    sys.modules["autograder.checks"] = stub


class _NotDrawn:
    """Stands in for ``robots.viewer.WorkcellViewer`` and everything reached through it.

    The worker has no browser, so a 3-D widget is never seen; building one costs more than
    the rest of lab 0 together (importing k3d and ipywidgets, tessellating the scene, and a
    redraw after every robot move while the lab 3 servo runs). Any call, attribute or item
    gives the stand-in back, so a notebook's viewer cells run as they do in JupyterLab,
    drawing nothing. No graded function can depend on it: it returns no numbers.
    """

    def __init__(self, *args, **kwargs):
        pass

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return self

    def __call__(self, *args, **kwargs):
        return self

    def __getitem__(self, key):
        return self

    def __iter__(self):
        return iter(())

    def __repr__(self) -> str:
        return "<3-D view: not drawn while grading>"


def _stub_viewer() -> None:
    stub = types.ModuleType("robots.viewer")
    stub.WorkcellViewer = _NotDrawn
    stub.__getattr__ = lambda name: _NotDrawn  # any other name the module exports
    sys.modules["robots.viewer"] = stub


def _limit(which: int, value: int) -> None:
    # soft = hard: student code may lower a limit but never raise it again.
    resource.setrlimit(which, (value, value))


def main(argv: list[str]) -> int:
    req_fd, rep_fd = int(argv[0]), int(argv[1])
    memory_mb, cpu_s, file_mb = (int(x) for x in argv[2:5])
    control_fd = int(argv[5]) if len(argv) > 5 else None   # a template (autograder.template)
    _limit(resource.RLIMIT_AS, memory_mb * 1024 * 1024)
    _limit(resource.RLIMIT_CPU, cpu_s)
    _limit(resource.RLIMIT_FSIZE, file_mb * 1024 * 1024)
    _limit(resource.RLIMIT_CORE, 0)
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.signal(signal.SIGPROF, _on_alarm)
    # Writing past RLIMIT_FSIZE would kill us with SIGXFSZ; an OSError in the student's cell
    # is the better outcome.
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    out, err = _CappedWriter(), _CappedWriter()
    sys.stdin, sys.stdout, sys.stderr = io.StringIO(""), out, err
    namespace = {"__name__": "__main__", "__builtins__": builtins}
    _stub_checks()
    _stub_viewer()
    guard = tripwire.Guard()
    # Before any student code: the grader knows the sandbox started (a failure until here
    # is the grader's, retried in a fresh sandbox, never a student's zero).
    wire.send(rep_fd, {"op": "ready"})
    return _serve(req_fd, rep_fd, namespace, out, err, guard, control_fd)


def _serve(req_fd: int, rep_fd: int, namespace: dict, out: _CappedWriter,
           err: _CappedWriter, guard: tripwire.Guard, control_fd: int | None = None) -> int:
    """Answer requests until "quit" or the grader closes the pipe; returns the exit code."""
    # bound now: student code may patch the modules
    send, receive, tripwire_of = wire.send, wire.receive, tripwire.Tripwire
    while True:
        try:
            request = receive(req_fd)
        except wire.WireError:
            return 0
        op = request.get("op")
        if op == "quit":
            return 0
        if op == "template" and control_fd is not None:
            return _serve_forks(control_fd, req_fd, rep_fd, namespace, out, err, guard)
        if op == "forbid":
            try:
                guard.add(str(n) for n in request.get("names", []))
                send(rep_fd, {"ok": True})
            except Exception as exc:  # noqa: BLE001 - no student code yet: the grader's error
                send(rep_fd, {"ok": False, "error": _describe(exc)})
            continue
        if op == "preload" and control_fd is not None:
            send(rep_fd, _preload(request))
            continue
        if op == "cell":
            send(rep_fd, _run_cell(request, namespace, out, err))
        elif op == "call":
            reply = _called(namespace, request, request.get("args", []),
                            _tables(request), guard, out, err, tripwire_of)
            try:
                send(rep_fd, reply)
            except (wire.WireError, TypeError, ValueError, OverflowError) as exc:
                send(rep_fd, {"ok": False, "error": f"returned a value that is not an array "
                                                    f"or number ({exc})", "failure": "unusable"})
        elif op == "calls":
            # One round trip for many calls of one function (``labs verify``'s thousands of
            # reference calls); each call keeps its own limits, tripwire and stand-ins, and
            # the batch stops after a call that timed out, as the grader's loop would.
            replies = []
            for entry in request.get("calls", []):
                entry = entry if isinstance(entry, dict) else {}
                replies.append(_called(namespace, request, entry.get("args", []),
                                       _tables(entry), guard, out, err, tripwire_of))
                if replies[-1].get("failure") in ("timed_out", "not_found"):
                    break
            try:
                send(rep_fd, {"ok": True, "replies": replies})
            except (wire.WireError, TypeError, ValueError, OverflowError) as exc:
                send(rep_fd, {"ok": False, "error": f"a batch reply could not be sent ({exc})"})
        else:
            send(rep_fd, {"ok": False, "error": f"unknown request {op!r}"})


def _run_cell(request: dict, namespace: dict, out: _CappedWriter, err: _CappedWriter) -> dict:
    """The reply to a "cell" request: run its ``source`` in ``namespace`` within its limits;
    what it printed, its seconds of wall clock and of CPU, or its failure."""
    started, cpu_started = time.monotonic(), time.process_time()
    out.take(), err.take()
    try:
        code = compile(str(request.get("source", "")), _cell_file(request.get("index", 0)),
                       "exec")
        _run_guarded(lambda: exec(code, namespace), *_limits_of(request))
        reply = {"ok": True}
    except BaseException as exc:  # noqa: BLE001 - a student's cell may raise anything
        reply = _failure(exc)
    reply["seconds"] = time.monotonic() - started
    reply["cpu_seconds"] = time.process_time() - cpu_started
    reply["output_chars"] = out.total + err.total
    reply["stdout"], reply["stderr"] = out.take(), err.take()
    return reply


def _called(namespace: dict, request: dict, args, tables: dict, guard, out, err,
            tripwire_of) -> dict:
    """The reply to one call of ``request["name"]`` on ``args`` (a "call" request, or one
    entry of a "calls" batch): the value or the failure, the forbidden routines it reached,
    its seconds and CPU seconds."""
    name = str(request.get("name"))
    func = namespace.get(name)
    if not callable(func):
        return {"ok": False, "error": f"no function named {name} is defined",
                "failure": "not_found"}
    args = args if isinstance(args, list) else []
    names = [str(n) for n in request.get("forbidden", [])]
    watch = tripwire_of(names, guard=guard)
    started, cpu_started = time.monotonic(), time.process_time()
    try:
        with standin.substituted(namespace, tables), watch:
            value = _run_guarded(lambda: _settled(func(*args)), *_limits_of(request))
        reply = {"ok": True, "value": value}
    except _Unsendable as exc:
        reply = {"ok": False, "error": f"returned a value that is not an array or "
                                       f"number ({exc})", "failure": "unusable"}
    except BaseException as exc:  # noqa: BLE001 - a student's function may raise anything
        reply = _failure(exc)
    if watch.hits:
        reply["forbidden"] = sorted(watch.hits)
    reply["seconds"] = time.monotonic() - started
    reply["cpu_seconds"] = time.process_time() - cpu_started
    reply["output_chars"] = out.total + err.total
    return reply


# --------------------------------------------------------------------------- template mode
#
# A template is a worker that has run the notebook's leading read-only cells (the lab's
# imports, its simulator set-up: instructor code, the same for every student) and then
# forks one process per submission. Each fork leaves the template's namespaces for fresh
# ones (autograder.inside.isolate) before it runs any student code, and answers on the pipes the
# grader passed with the fork request, exactly as a freshly started worker would.


def _preload(request: dict) -> dict:
    """Import the modules the notebook's later cells import (the instructor's notebook, read
    by the grader), binding no name: a fork then finds them in ``sys.modules`` as a cold
    worker would after its own import. One that fails is left for the fork to import."""
    loaded = []
    for name in request.get("modules", []):
        try:
            _run_guarded(lambda name=name: importlib.import_module(str(name)),
                         *_limits_of(request))
            loaded.append(str(name))
        except BaseException:  # noqa: BLE001 - the fork's own import will say what is wrong
            pass
    return {"ok": True, "loaded": loaded}


def _single_threaded() -> str | None:
    """None when this process has one thread (fork copies only the calling thread, so a
    lock another thread held would stay locked in every child), else which ones it has."""
    for thread in threading.enumerate():
        if type(thread).__name__ == "TMonitor":   # tqdm's progress-bar monitor: display
            thread.exit()                          # only; a fork's next bar starts its own
    deadline = time.monotonic() + 2.0   # a joined thread's task outlives its join a moment
    while len(tasks := os.listdir("/proc/self/task")) > 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    if len(tasks) == 1:
        return None
    names = sorted(t.name for t in threading.enumerate())
    return f"{len(tasks)} threads after loading (Python's: {', '.join(names)})"


def _serve_forks(control_fd: int, req_fd: int, rep_fd: int, namespace: dict,
                 out: _CappedWriter, err: _CappedWriter, guard: tripwire.Guard) -> int:
    """The template's loop: one fork per request on the control socket (fds attached:
    the submission's request and reply pipes, its stderr file, its cgroups' procs files)."""
    busy = _single_threaded()
    wire.send(rep_fd, {"ok": busy is None, "error": busy or "", "pid": os.getpid()})
    if busy is not None:
        return 0
    isolate.not_dumpable()
    control = socket.socket(fileno=control_fd)
    exited: dict[int, int] = {}
    while True:
        try:
            data, fds, _, _ = socket.recv_fds(control, 65536, 8)
        except OSError:
            return 0
        if not data:
            return 0
        _reap(exited)
        try:
            request = json.loads(data)
        except ValueError:
            request = {}
        op = request.get("op")
        if op == "fork" and len(fds) >= 3:
            pid = os.fork()
            if pid == 0:
                _become_submission(control, fds, request, (req_fd, rep_fd), namespace, out,
                                   err, guard)
            for fd in fds:
                os.close(fd)
            control.send(json.dumps({"pid": pid}).encode())
        elif op == "status":
            pid = int(request.get("pid", 0))
            deadline = time.monotonic() + float(request.get("wait", 0.0))
            while pid not in exited and time.monotonic() < deadline:
                time.sleep(0.01)
                _reap(exited)
            control.send(json.dumps({"status": exited.get(pid)}).encode())
        else:
            for fd in fds:
                os.close(fd)
            control.send(json.dumps({"error": f"unknown request {op!r}"}).encode())


def _reap(exited: dict[int, int]) -> None:
    """Collect the exit codes of finished submissions (each the code of its process 1)."""
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        exited[pid] = os.waitstatus_to_exitcode(status)


def _become_submission(control, fds, request, template_fds, namespace, out, err, guard):
    """In the fork: leave the template's namespaces, fork process 1 of a PID namespace of
    its own, and serve the submission there. Never returns."""
    req_r, rep_w, err_w, *cgroups = fds
    try:
        control.close()
        for fd in template_fds:
            os.close(fd)
        for fd in cgroups:   # "0": this process; its children inherit the group
            os.write(fd, b"0")
            os.close(fd)
        isolate.leave_template(int(request.get("scratch_bytes", 64 * 2**20)))
        child = os.fork()
    except BaseException as exc:  # noqa: BLE001 - told to the grader, which starts cold
        _refuse(rep_w, exc)
    if child:   # stays outside, to report how process 1 ended
        for fd in (req_r, rep_w, err_w):
            os.close(fd)
        _, status = os.waitpid(child, 0)
        code = os.waitstatus_to_exitcode(status)
        os._exit(code if code >= 0 else 128 - code)
    try:
        isolate.enter_own_pid_namespace()
        isolate.drop_privileges()
        # The template's session keyring is every fork's: each leaves it for one of its
        # own, then may make no keyring call at all (the template has no filter, or no
        # fork could join one).
        if syscalls.supported():
            syscalls.new_session_keyring()
            syscalls.install()
        os.dup2(err_w, 2)
        _close_all_but({0, 1, 2, req_r, rep_w})   # the template's files and pipes too
        cpu_s = int(request.get("cpu_s", 60))
        _limit(resource.RLIMIT_CPU, max(1, cpu_s))
    except BaseException as exc:  # noqa: BLE001
        _refuse(rep_w, exc)
    wire.send(rep_w, {"op": "ready"})
    os._exit(_serve(req_r, rep_w, namespace, out, err, guard))


def _close_all_but(keep: set[int]) -> None:
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        if fd not in keep:
            try:
                os.close(fd)
            except OSError:   # the directory listing's own descriptor, already gone
                pass


def _refuse(rep_w: int, exc: BaseException):
    try:
        wire.send(rep_w, {"op": "isolation_failed", "error": _describe(exc)})
    finally:
        os._exit(70)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
