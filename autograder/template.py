"""A lab's grading template: what every submission's worker would load first, loaded once.

A cold worker (:class:`autograder.pipeline.worker.Worker`) starts the interpreter in a new sandbox,
imports the lab's libraries and runs the notebook from its first cell. The first cells of
a lab are the instructor's, read-only and the same for every student (the imports, the
simulated workcell, the photographs of lab 1's first part): in a class of a hundred they
were run a hundred times with the same result. A template runs them once per grade run, in
a sandboxed worker of its own, and then forks one process per submission
(:func:`autograder.inside.worker._serve_forks`). Before any student code runs, each fork moves
into new user, mount, PID, IPC, UTS and network namespaces with an empty ``/tmp``
(:mod:`autograder.inside.isolate`), joins the submission's cgroup, drops every capability, and
leaves the template's session keyring for an empty one of its own under the keyring filter
every sandbox has (:mod:`autograder.inside.syscalls`);
it then loads the submission's own cells from the first one that differs, and answers
the grader exactly as a cold worker does.

What a submission does stays in its fork: the template never runs student code and never
hears from a fork (the grader speaks to each over pipes of its own), its memory is copied
on write, files go to the fork's own ``/tmp``, and when the fork's process 1 ends the kernel
kills everything it left. ``tests/test_grading_template.py`` checks it.

The shared cells come from the *released* notebook (no solutions in it), and only their
leading run of read-only, ungraded code cells; a submission whose first cells are not
exactly those (nbgrader restores locked cells, so only a raw, unsanitized notebook differs)
gets a cold worker, as does every submission when the template cannot be built (the run
log says why), and when the grader is not root (bubblewrap's user-namespace path forbids
the namespaces a fork would need: no template is built then).
"""

from __future__ import annotations

import ast
import json
import os
import select
import signal
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from autograder import sandbox
from autograder.nbgrader_cells import cell_role
from autograder.pipeline.cells import extract_code
from autograder.pipeline.worker import (
    GraderError,
    Limits,
    TemplateUnavailable,
    Worker,
    WorkerFailure,
    WorkerSetup,
)

__all__ = ["Template", "TemplateUnavailable", "ForkedProcess", "imported_modules",
           "leading_cells"]

# Wall clock for the template to answer a fork or status request.
CONTROL_TIMEOUT_S = 30.0


def _locked_code(cell: dict) -> bool:
    return cell.get("cell_type") == "code" and cell_role(cell).read_only


def imported_modules(notebook: Path) -> list[str]:
    """The absolute module names ``notebook``'s code cells import, in order, once each."""
    cells, _ = extract_code([notebook])
    names: list[str] = []
    for source in cells:
        try:
            tree = ast.parse(source)
        except SyntaxError:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found = [node.module]
            else:
                continue
            names += [n for n in found if n not in names]
    return names


def leading_cells(notebook: Path) -> list[str]:
    """The code of ``notebook``'s leading read-only, ungraded code cells (markdown cells
    between them allowed), as :func:`autograder.pipeline.cells.extract_code` gives it."""
    nb = json.loads(Path(notebook).read_text(encoding="utf-8"))
    lead = []
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "code":
            continue
        if not _locked_code(cell):
            break
        lead.append(cell)
    if not lead:
        return []
    with tempfile.TemporaryDirectory(prefix="cobotlab-template-") as tmp:
        path = Path(tmp) / Path(notebook).name
        path.write_text(json.dumps(dict(nb, cells=lead)), encoding="utf-8")
        cells, _ = extract_code([path])
    return cells


class Template:
    """A sandboxed worker holding ``cells`` already run, forked once per submission.

    ``cpu_s`` is the CPU limit of one submission's worker (the template's own is the
    same: a fork's limit is what remains after the shared cells). ``preload``: modules
    imported after the shared cells, binding no name (those the notebook's later cells
    import: :func:`imported_modules`), so no fork pays for them again. Raises
    :class:`TemplateUnavailable` when the worker or one of the cells fails to load.
    """

    def __init__(self, cells: list[str], limits: Limits, cpu_s: int,
                 preload: list[str] = ()):
        caps = sandbox.capabilities()
        if not caps.bwrap:
            raise TemplateUnavailable("no bubblewrap here: a fork could not get a sandbox "
                                      "of its own")
        if not caps.drop_to_uid:
            # Checked before the template's interpreter and shared cells cost anything: a
            # grader that is not root runs bubblewrap with --disable-userns, so every fork's
            # unshare(CLONE_NEWUSER) would fail and each submission start cold anyway.
            raise TemplateUnavailable("the grader is not root: its sandbox forbids the user "
                                      "namespace each fork would isolate itself in")
        self.limits, self.cpu_s = limits, int(cpu_s)
        self.broken: str | None = None
        started = time.monotonic()
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            self.worker = Worker(cells, limits,
                                 WorkerSetup(cpu_s=cpu_s, control_fd=theirs.fileno()))
        except (WorkerFailure, GraderError) as exc:
            ours.close()
            raise TemplateUnavailable(f"the template did not load: {exc}") from None
        finally:
            theirs.close()
        self._control = ours
        self._lock = threading.Lock()
        failed = [r for r in self.worker.load_report if r.get("ok") is not True]
        if failed:
            self.close()
            raise TemplateUnavailable(f"cell {failed[0].get('index')} of the shared cells "
                                      f"failed: {str(failed[0].get('error'))[:200]}")
        if preload:
            self.worker.request({"op": "preload", "modules": list(preload),
                                 "timeout": limits.load_timeout_s,
                                 "wall": limits.wall_factor * limits.load_timeout_s},
                                limits.wall_factor * limits.load_timeout_s + 2.0)
        reply = self.worker.request({"op": "template"}, CONTROL_TIMEOUT_S)
        if reply.get("ok") is not True:
            self.close()
            raise TemplateUnavailable(f"the template cannot fork: {reply.get('error')}")
        self._pid_inside = reply.get("pid")
        self.cells = list(cells)
        self.replies = [dict(r) for r in self.worker.load_report]
        self.shared_cpu_s = sum(float(r.get("cpu_seconds", 0.0)) for r in self.replies)
        self.shared_s = sum(float(r.get("seconds", 0.0)) for r in self.replies)
        self.build_s = time.monotonic() - started

    def matches(self, cells: list[str]) -> bool:
        """True when ``cells`` (a submission's code cells) start with the shared ones."""
        return self.broken is None and cells[:len(self.cells)] == self.cells

    def peak_memory_mb(self) -> float:
        """The template's peak resident memory (MB), shared by every fork until written."""
        try:
            for line in Path(f"/proc/{self._host_pid()}/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
        except (OSError, ValueError, TypeError):
            pass
        return float("nan")

    def _host_pid(self) -> int | None:
        if not isinstance(self._pid_inside, int):
            return None
        return sandbox.host_pid(self._pid_inside, self.worker.proc.pid)

    def fork(self, stderr_fd: int, cgroup: sandbox.Cgroup | None):
        """(ForkedProcess, request pipe's write end, reply pipe's read end) of a new fork.
        Raises TemplateUnavailable (and marks the template broken) when it cannot fork."""
        if self.broken is not None:
            raise TemplateUnavailable(self.broken)
        req_r, req_w = os.pipe()
        rep_r, rep_w = os.pipe()
        passed = [req_r, rep_w, stderr_fd]
        try:
            passed += [os.open(p, os.O_WRONLY | os.O_CLOEXEC) for p in
                       (cgroup.procs_files if cgroup is not None else ())]
            request = {"op": "fork", "cpu_s": max(1, int(self.cpu_s - self.shared_cpu_s)),
                       "scratch_bytes": int(self.limits.scratch_mb) * 2**20}
            with self._lock:
                socket.send_fds(self._control, [json.dumps(request).encode()], passed)
                reply = self._reply()
            pid = reply.get("pid")
            middle = sandbox.host_pid(pid, self.worker.proc.pid) if isinstance(pid, int) else None
            if middle is None:
                raise TemplateUnavailable(f"the template did not fork ({reply})")
        except (OSError, TemplateUnavailable) as exc:
            for fd in (req_w, rep_r):
                os.close(fd)
            self.broken = f"the template stopped forking: {exc}"
            raise TemplateUnavailable(self.broken) from None
        finally:
            for fd in passed[:2] + passed[3:]:
                os.close(fd)
        return ForkedProcess(self, pid, middle), req_w, rep_r

    def status(self, pid: int, wait_s: float) -> int | None:
        """How the fork ``pid`` (the template's number for it) ended: its process 1's exit
        code, 128 + the signal that killed it, or None when not known yet."""
        try:
            with self._lock:
                self._control.send(json.dumps({"op": "status", "pid": pid,
                                               "wait": wait_s}).encode())
                return self._reply(wait_s + CONTROL_TIMEOUT_S).get("status")
        except (OSError, TemplateUnavailable):
            return None

    def _reply(self, timeout_s: float = CONTROL_TIMEOUT_S) -> dict:
        ready, _, _ = select.select([self._control], [], [], timeout_s)
        if not ready:
            raise TemplateUnavailable(f"the template did not answer within {timeout_s:g} s")
        data = self._control.recv(65536)
        if not data:
            raise TemplateUnavailable("the template has stopped")
        reply = json.loads(data)
        return reply if isinstance(reply, dict) else {}

    def close(self) -> None:
        self.broken = self.broken or "closed"
        try:
            self._control.close()
        except (OSError, AttributeError):
            pass
        self.worker.close()


def _running(pid: int) -> bool:
    """True while ``pid`` exists and has not exited (a zombie has)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            state = f.read().rsplit(b")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in (b"Z", b"X")


class ForkedProcess:
    """A submission forked from a template, handled as a ``subprocess.Popen``: ``poll``,
    ``wait``, ``kill`` and ``returncode`` (negative: the signal that ended it).

    ``middle`` is the host PID of the fork that stays outside the submission's PID
    namespace to report how it ended; the submission is its child, process 1 of that
    namespace, and killing it ends every process the submission started.
    """

    def __init__(self, template: Template, pid: int, middle: int):
        self.template, self.pid_in_template, self.pid = template, pid, middle
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None and not _running(self.pid):
            code = self.template.status(self.pid_in_template, wait_s=1.0)
            if code is None:
                self.returncode = -signal.SIGKILL
            else:
                self.returncode = -(code - 128) if code > 128 else code
        return self.returncode

    def kill(self) -> None:
        sandbox.kill_below(self.pid)

    def submission_pid(self) -> int | None:
        """The host PID of the submission's process 1 (the fork's one child), or None."""
        children = sandbox._children(self.pid)
        return children[0] if len(children) == 1 else None

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired("template fork", timeout)
            time.sleep(0.01)
        return self.returncode
