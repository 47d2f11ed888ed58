"""Deny-by-default sandboxes for student code: bubblewrap for the view, a cgroup for the budget.

Everything a submission runs (the grader's worker and nbgrader's autograde with its kernel)
starts through :func:`command`, which builds a bubblewrap (``bwrap``) command line where:

* the root is an empty, read-only tmpfs; only the interpreter, the virtual environment and
  the named packages are bound in, read-only (so ``solutions/``, the specs, the course, the
  checkout, ``$HOME`` and the rest of the disk do not exist there);
* ``/tmp`` is the one writable place, a tmpfs of ``scratch_mb``; a throwaway directory of the
  grader's may be bound read-write in addition (nbgrader's scratch course);
* there is no network (a new network namespace holding only loopback), no view of other
  processes (a new PID namespace: when its first process ends, every process left in it is
  killed), and, when the grader runs as root, the code runs as ``nobody`` with every
  capability dropped;
* the whole process tree is charged to one cgroup with a memory and a process-count limit,
  so three forked children cannot each take the per-process budget, and with a CPU weight
  of its own, so thirty busy processes get no more of the machine than one
  (:attr:`Capabilities.cpu_share`);
* it starts in a new, empty session keyring and cannot make keyring system calls, so it
  reads neither the grader's keys nor another submission's (:mod:`autograder.inside.syscalls`,
  whose launcher starts bubblewrap).

Where bubblewrap cannot run, :func:`capabilities` says so and the caller falls back to
resource limits on each process (``rlimits only``), which it flags in every result.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from autograder.inside import syscalls

__all__ = ["Capabilities", "Jail", "Cgroup", "ScratchDir", "capabilities", "command", "mode",
           "SANDBOX_UID", "remove_stale_scratch", "private_folder", "remove_stale_folders",
           "Interrupted", "stop_all",
           "stopping", "allow_starts", "fallback_warning"]

# The unprivileged user student code runs as when the grader itself is root.
SANDBOX_UID = 65534
_CGROUP_ROOT = Path("/sys/fs/cgroup")


@dataclass(frozen=True)
class Capabilities:
    """What this machine lets the grader use, with the evidence for the run log."""

    bwrap: bool
    drop_to_uid: bool          # root: run student code as SANDBOX_UID with no capabilities
    cgroup: str | None         # "v1", "v2" or None
    evidence: tuple[str, ...] = ()
    # Without bubblewrap: why not, and what would bring it back (see fallback_warning()).
    why: str = ""
    # The sandbox denies the keyring system calls (autograder.inside.syscalls); False on a
    # machine the filter does not know, which every grade row then says.
    syscall_filter: bool = False
    # How each submission gets its own share of the CPU: "v1 cpu.shares", "v2 cpu.weight",
    # or None (its processes then compete one by one with everything else).
    cpu_share: str | None = None

    @property
    def mode(self) -> str:
        if not self.bwrap:
            return "rlimits only"
        return "bubblewrap + cgroup" if self.cgroup else "bubblewrap, per-process rlimits"


@dataclass(frozen=True)
class Jail:
    """What one sandboxed program may see: read-only host paths, read-write binds, limits.

    ``ro`` paths are bound at the same place; ``masked`` directories show only the host
    paths listed for them (:class:`autograder.views.View`); ``ro_at`` and ``rw_at`` are
    (host, inside) pairs. There is no list of places to hide: what is not listed is not
    there.
    """

    @classmethod
    def of_view(cls, view, **kwargs) -> Jail:
        """A jail showing ``view`` (an :class:`autograder.views.View`) and ``kwargs``'s rest."""
        return cls(ro=view.ro, masked=view.masked, **kwargs)

    ro: tuple[str, ...] = ()
    # (directory, the host paths inside it that stay visible): the directory is replaced by
    # an empty read-only one holding only those (an allow list inside a bound tree).
    masked: tuple[tuple[str, tuple[str, ...]], ...] = ()
    ro_at: tuple[tuple[str, str], ...] = ()
    rw_at: tuple[tuple[str, str], ...] = ()
    scratch_mb: int = 64
    chdir: str = "/tmp"
    env: dict[str, str] = field(default_factory=dict)


def _system_binds() -> list[str]:
    """The read-only system part of the root: /usr and /etc, and /lib* /bin /sbin as on the
    host (symlinks into /usr on a merged-/usr system, directories otherwise)."""
    args = ["--ro-bind", "/usr", "/usr", "--ro-bind", "/etc", "/etc"]
    for top in ("/lib", "/lib64", "/lib32", "/bin", "/sbin"):
        if os.path.islink(top):
            args += ["--symlink", os.readlink(top), top]
        elif os.path.isdir(top):
            args += ["--ro-bind", top, top]
    return args


def _parents(paths) -> list[str]:
    """Every ancestor directory of ``paths`` (inside the sandbox), shallowest first."""
    out: set[str] = set()
    for p in paths:
        parent = os.path.dirname(p.rstrip("/"))
        while parent not in ("", "/"):
            out.add(parent)
            parent = os.path.dirname(parent)
    return sorted(out, key=lambda p: (p.count("/"), p))


def command(argv: list[str], jail: Jail, cgroup: Cgroup | None = None,
            caps: Capabilities | None = None, syscall_filter: bool = True) -> list[str]:
    """The command line running ``argv`` inside ``jail`` (and ``cgroup``, when given).

    ``argv`` and the paths are those inside the sandbox; the environment is ``jail.env``
    and nothing else. Requires :func:`capabilities` ``.bwrap``. The sandbox starts in a new
    session keyring and, with ``syscall_filter``, makes no keyring calls
    (:mod:`autograder.inside.syscalls`); a template passes False: each of its forks joins a
    keyring of its own, then installs the same filter.
    """
    if _STOPPING.is_set():
        raise Interrupted("grading was interrupted: no new sandbox is started")
    caps = caps or capabilities()
    kept = [p for _, paths in jail.masked for p in paths]
    inside = [*jail.ro, *(d for d, _ in jail.masked), *kept,
              *(dst for _, dst in jail.ro_at + jail.rw_at)]
    args = ["bwrap", "--unshare-pid", "--unshare-net", "--unshare-ipc", "--unshare-uts",
            "--unshare-cgroup-try", "--die-with-parent", "--new-session",
            "--tmpfs", "/"]
    args += _system_binds()
    # /tmp before the view: a virtual environment or checkout under /tmp is bound on top of
    # the scratch tmpfs instead of disappearing under it.
    args += ["--proc", "/proc", "--dev", "/dev",
             "--size", str(int(jail.scratch_mb) * 1024 * 1024), "--perms", "1777",
             "--tmpfs", "/tmp"]
    # /dev/null over procfs's key lists (a --ro-bind would be nodev: unreadable)
    args += [arg for path in syscalls.KEY_LISTS if os.path.exists(path)
             for arg in ("--dev-bind", "/dev/null", path)]
    # Mount points above the binds: traversable (0711), not listable, so the sandbox user
    # can reach a bound package without seeing what else its parent held on the host.
    system = ("/usr", "/etc", "/proc", "/dev")
    for parent in _parents(inside):
        if not parent.startswith(system) and parent != "/tmp":
            args += ["--perms", "0711", "--dir", parent]
    for path in jail.ro:
        args += ["--ro-bind", path, path]
    # Each masked directory: an empty tmpfs with only its listed paths bound in (read-only
    # once every mount point in it exists, nested masks included).
    for directory, paths in jail.masked:
        args += ["--perms", "0755", "--size", "1048576", "--tmpfs", directory]
        for path in paths:
            args += ["--ro-bind", path, path]
    for directory, _ in reversed(jail.masked):
        args += ["--remount-ro", directory]
    for src, dst in jail.rw_at:
        args += ["--bind", src, dst]
    for src, dst in jail.ro_at:  # after the read-write binds: may sit inside one
        args += ["--ro-bind", src, dst]
    args += ["--remount-ro", "/", "--chdir", jail.chdir, "--clearenv"]
    for key, value in jail.env.items():
        args += ["--setenv", key, value]
    if caps.drop_to_uid:
        args += ["--", "setpriv", f"--reuid={SANDBOX_UID}", f"--regid={SANDBOX_UID}",
                 "--clear-groups", "--inh-caps=-all", "--bounding-set=-all", "--no-new-privs"]
    else:
        args += ["--unshare-user", "--disable-userns", "--cap-drop", "ALL"]
    args += ["--", *argv]
    # The launcher joins the cgroup and a new session keyring before it starts bubblewrap,
    # so every process of the sandbox is charged to the one and never holds the grader's
    # keys; it hands bubblewrap the keyring filter.
    launcher = [sys.executable, "-I", "-m", "autograder.inside.syscalls"]
    for path in cgroup.procs_files if cgroup is not None else ():
        launcher += ["--join", str(path)]
    if syscall_filter and caps.syscall_filter:
        launcher.append("--filter")
    return [*launcher, "--", shutil.which("bwrap") or "/usr/bin/bwrap", *args[1:]]


# --------------------------------------------------------------------------- cgroups


class Cgroup:
    """One cgroup (v1: a memory, a pids and, where they can be used, a cpu and a cpuacct
    group; v2: one group) for one submission.

    ``memory_mb`` caps resident memory plus tmpfs pages of every process in it together;
    ``max_processes`` caps how many exist at once (a fork bomb meets EAGAIN). With
    :attr:`Capabilities.cpu_share`, the group has the CPU weight of one busy process,
    however many it runs: a submission that starts thirty busy processes takes no more of
    the machine from the one graded beside it than a submission with one.
    """

    def __init__(self, memory_mb: int, max_processes: int):
        caps = capabilities()
        self.version = caps.cgroup
        if self.version is None:
            raise RuntimeError("no writable cgroup hierarchy on this machine")
        name = f"cobotlab-{uuid.uuid4().hex[:12]}"
        self.dirs: list[Path] = []
        self._cpuacct: Path | None = None
        # Registered first: a failure below still removes what was made.
        with _LIVE_LOCK:
            _LIVE_CGROUPS.add(self)
        try:
            if self.version == "v2":
                d = _v2_parent() / name
                d.mkdir()
                self.dirs = [d]
                _write(d / "memory.max", str(memory_mb * 1024 * 1024))
                _write(d / "memory.swap.max", "0", missing_ok=True)
                _write(d / "pids.max", str(max_processes))
                if caps.cpu_share:
                    _write(d / "cpu.weight", "100")
            else:
                for controller in ("memory", "pids"):
                    self.dirs.append(_v1_parent(controller) / name)
                    self.dirs[-1].mkdir()
                mem, pids = self.dirs
                _write(mem / "memory.limit_in_bytes", str(memory_mb * 1024 * 1024))
                _write(mem / "memory.memsw.limit_in_bytes", str(memory_mb * 1024 * 1024),
                       missing_ok=True)
                _write(pids / "pids.max", str(max_processes))
                if caps.cpu_share:
                    cpu, self._cpuacct = _v1_cpu_dirs(name)
                    for d in dict.fromkeys((cpu, self._cpuacct)):   # one when co-mounted
                        d.mkdir()
                        self.dirs.append(d)
                    _write(cpu / "cpu.shares", "1024")
        except BaseException:
            self.remove()
            raise

    def cpu_seconds(self) -> float | None:
        """CPU seconds every process of the group has used, by the kernel's count (which
        no process in it can change); None where the group has no CPU accounting."""
        try:
            if self.version == "v2" and self.dirs:
                for line in (self.dirs[0] / "cpu.stat").read_text().splitlines():
                    key, _, value = line.partition(" ")
                    if key == "usage_usec":
                        return int(value) / 1e6
            elif self._cpuacct is not None:
                return int((self._cpuacct / "cpuacct.usage").read_text()) / 1e9
        except (OSError, ValueError):
            pass
        return None

    @property
    def procs_files(self) -> list[Path]:
        return [d / "cgroup.procs" for d in self.dirs]

    def pids(self) -> set[int]:
        found: set[int] = set()
        for f in self.procs_files:
            try:
                found.update(int(x) for x in f.read_text().split())
            except OSError:
                pass
        return found

    def oom_kills(self) -> int:
        """How many processes the kernel killed for exceeding the memory limit."""
        name = "memory.events" if self.version == "v2" else "memory.oom_control"
        try:
            for line in (self.dirs[0] / name).read_text().splitlines():
                key, _, value = line.partition(" ")
                if key == "oom_kill":
                    return int(value)
        except (OSError, ValueError):
            pass
        return 0

    def peak_memory_mb(self) -> float:
        name = "memory.peak" if self.version == "v2" else "memory.max_usage_in_bytes"
        try:
            return int((self.dirs[0] / name).read_text()) / 2**20
        except (OSError, ValueError):
            return float("nan")

    def kill_all(self, timeout_s: float = 5.0) -> int:
        """SIGKILL every process in the group until none is left; returns how many."""
        if self.version == "v2" and (self.dirs[0] / "cgroup.kill").exists():
            _write(self.dirs[0] / "cgroup.kill", "1")
        killed, deadline = 0, time.monotonic() + timeout_s
        while (left := self.pids()) and time.monotonic() < deadline:
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                    killed += 1
                except ProcessLookupError:
                    pass
            time.sleep(0.02)
        return killed

    def remove(self) -> None:
        with _LIVE_LOCK:
            _LIVE_CGROUPS.discard(self)
        self.kill_all()
        for d in self.dirs:
            # Up to 5 s: killed processes leave the group only once they have run their exit,
            # which a core crowded with the submission's own twenty takes its time to give.
            for _ in range(250):
                try:
                    d.rmdir()
                    break
                except FileNotFoundError:
                    break
                except OSError:  # the last processes are still being reaped
                    time.sleep(0.02)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.remove()


# --------------------------------------------------------------------------- interrupting

# Ctrl-C reaches only the grader: every sandbox runs in a session of its own, so the
# terminal's SIGINT never gets to nbgrader, its kernel or a worker. stop_all() ends them.
_STOPPING = threading.Event()
_LIVE_LOCK = threading.Lock()
_LIVE_CGROUPS: set[Cgroup] = set()


class Interrupted(KeyboardInterrupt):
    """Raised by :func:`command` after :func:`stop_all`: grading is being interrupted."""


def _parents_of_all() -> dict[int, int]:
    """{pid: parent pid} of every process (from /proc; empty where there is none)."""
    found = {}
    for entry in os.listdir("/proc") if os.path.isdir("/proc") else ():
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(fields) > 1:
            found[int(entry)] = int(fields[1])
    return found


def _children(pid: int) -> list[int]:
    """The direct children of ``pid`` (from /proc; empty where there is none)."""
    return [child for child, parent in _parents_of_all().items() if parent == pid]


def _descendants(pid: int) -> set[int]:
    """Every process below ``pid``, whatever session or process group it is in."""
    below: dict[int, list[int]] = {}
    for child, parent in _parents_of_all().items():
        below.setdefault(parent, []).append(child)
    found, todo = set(), [pid]
    while todo:
        for child in below.get(todo.pop(), ()):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def host_pid(ns_pid: int, ancestor: int) -> int | None:
    """The PID here of the process below ``ancestor`` (a bubblewrap sandbox) whose PID in
    the sandbox's namespace is ``ns_pid``; None when there is none."""
    for pid in _descendants(ancestor):
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            continue
        for line in status.splitlines():
            if line.startswith("NSpid:"):
                ids = line.split()[1:]
                if len(ids) >= 2 and ids[1] == str(ns_pid):
                    return pid
    return None


def _stop_below(pid: int) -> set[int]:
    """SIGSTOP every process below ``pid``, whatever its session, until no new one appears
    below a stopped one (so none forked meanwhile is orphaned out of reach); returns them."""
    tree: set[int] = set()
    for _ in range(10):
        new = _descendants(pid) - tree
        if not new:
            break
        _signal(new, signal.SIGSTOP)
        tree |= new
    return tree


def kill_below(pid: int) -> int:
    """Stop, then SIGKILL, every process below ``pid``; returns how many were signalled."""
    return _signal(_stop_below(pid), signal.SIGKILL)


def _signal(pids, sig: int) -> int:
    sent = 0
    for pid in pids:
        try:
            os.kill(pid, sig)
            sent += 1
        except (ProcessLookupError, PermissionError):
            pass
    return sent


def stop_all() -> int:
    """Refuse new sandboxes, then SIGKILL every process this grader started in one.

    Kills every live :class:`Cgroup` (nbgrader, its kernels, workers and their children)
    and the process group of each direct child (bubblewrap: its PID namespace dies with
    it), and every process below this one, whatever its session: without bubblewrap and a
    cgroup (the rlimits-only fallback, an unprivileged grader) nbgrader's kernel, which
    jupyter_client starts in a session of its own, is reached only through its parent. The
    tree is stopped (SIGSTOP: it forks no more) before it is killed, so a child forked
    meanwhile is not orphaned out of reach. Call :func:`allow_starts` once the interrupted
    work has unwound. Returns how many processes were signalled.
    """
    _STOPPING.set()
    me = os.getpid()
    tree = _stop_below(me)
    killed = 0
    for pid in _children(me):
        try:
            os.killpg(pid, signal.SIGKILL)   # each sandbox leads a session of its own
        except (ProcessLookupError, PermissionError):
            try:   # not a group leader: a plain subprocess (nbgrader making the template)
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                continue
        killed += 1
    killed += _signal(tree, signal.SIGKILL)
    with _LIVE_LOCK:
        live = list(_LIVE_CGROUPS)
    for group in live:
        killed += group.kill_all(timeout_s=2.0)
    return killed


def stopping() -> bool:
    """True between :func:`stop_all` and :func:`allow_starts`."""
    return _STOPPING.is_set()


def allow_starts() -> None:
    """Undo :func:`stop_all`'s refusal (the next grading run in this process may start)."""
    _STOPPING.clear()


def _write(path: Path, value: str, missing_ok: bool = False) -> None:
    try:
        path.write_text(value)
    except FileNotFoundError:
        if not missing_ok:
            raise


def _own_cgroup(controller: str) -> str | None:
    """This process's cgroup path for ``controller`` ("" for the v2 line) in /proc/self/cgroup."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controller in controllers.split(","):
            return path
    return None


def _v1_parent(controller: str) -> Path:
    own = _own_cgroup(controller) or "/"
    return _CGROUP_ROOT / controller / own.lstrip("/")


def _v1_cpu_dirs(name: str) -> tuple[Path, Path]:
    """Where a v1 cpu group and cpuacct group called ``name`` go (one folder when the two
    controllers share a hierarchy, as ``cpu,cpuacct`` usually does)."""
    cpu, acct = _v1_parent("cpu"), _v1_parent("cpuacct")
    if os.path.realpath(cpu) == os.path.realpath(acct):
        acct = cpu
    return cpu / name, acct / name


def _v2_parent() -> Path:
    own = _own_cgroup("") or "/"
    return _CGROUP_ROOT / own.lstrip("/")


def _probe_cgroup(evidence: list[str]) -> str | None:
    """"v2" or "v1" when this process can make a child group with memory and pids limits."""
    if (_CGROUP_ROOT / "cgroup.controllers").exists():
        parent = _v2_parent()
        wanted = {"memory", "pids"}
        try:
            enabled = set((parent / "cgroup.subtree_control").read_text().split())
        except OSError:
            enabled = set()
        if wanted <= enabled and os.access(parent, os.W_OK):
            evidence.append(f"cgroup v2 at {parent} with memory and pids delegated")
            return "v2"
        evidence.append(f"cgroup v2 at {parent}: memory/pids not delegated ({sorted(enabled)})")
    for controller in ("memory", "pids"):
        parent = _v1_parent(controller)
        # A name no other thread or process can hold: with the pid alone, two graders'
        # threads probing at once met EEXIST and the run lost its memory cap.
        probe = parent / f"cobotlab-probe-{uuid.uuid4().hex[:12]}"
        try:
            probe.mkdir()
            probe.rmdir()
        except OSError as exc:
            evidence.append(f"cgroup v1 {controller}: cannot create a group in {parent} ({exc})")
            return None
    evidence.append(f"cgroup v1: memory group under {_v1_parent('memory')}, pids group under "
                    f"{_v1_parent('pids')}")
    return "v1"


def _probe_cpu(cgroup: str | None, evidence: list[str]) -> str | None:
    """How a submission's group gets its own CPU share ("v1 cpu.shares", "v2 cpu.weight"),
    or None when the cpu controller cannot be used here."""
    if cgroup == "v2":
        parent = _v2_parent()
        try:
            enabled = set((parent / "cgroup.subtree_control").read_text().split())
        except OSError:
            enabled = set()
        if "cpu" in enabled:
            evidence.append(f"cpu share: cpu.weight of each submission's group under {parent}")
            return "v2 cpu.weight"
        evidence.append(f"cpu share: none (cpu controller not delegated at {parent}); CPU "
                        "accounted by cpu.stat")
        return None
    if cgroup != "v1":
        evidence.append("cpu share: none (no cgroup)")
        return None
    name = f"cobotlab-probe-{uuid.uuid4().hex[:12]}"
    made: list[Path] = []
    try:
        for d in dict.fromkeys(_v1_cpu_dirs(name)):
            d.mkdir()
            made.append(d)
    except OSError as exc:
        evidence.append(f"cpu share: none (cgroup v1 cpu/cpuacct: {exc})")
        return None
    finally:
        for d in made:
            d.rmdir()
    cpu, acct = _v1_cpu_dirs("")
    evidence.append(f"cpu share: cpu.shares of each submission's group under {cpu}, CPU "
                    f"accounted by cpuacct under {acct}")
    return "v1 cpu.shares"


def _probe_run_queue(evidence: list[str]) -> None:
    """Say whether the run-queue wait that tells a starved cell from a sleeping one is
    readable (/proc/<pid>/schedstat)."""
    try:
        fields = Path("/proc/self/schedstat").read_text().split()
        ok = len(fields) == 3 and int(fields[0]) > 0
    except (OSError, ValueError):
        ok = False
    evidence.append("run-queue wait: " + (
        "/proc/<pid>/schedstat (a cell starved of CPU is the grader's failure, retried)"
        if ok else "not readable here: a cell stopped by the wall clock is always charged "
                   "to the submission"))


_PROBE_LOCK = threading.Lock()
_PROBED: list[Capabilities] = []


def capabilities() -> Capabilities:
    """Probe once per process: does bubblewrap run here (and with which identity), is there
    a cgroup?

    Safe under threads (one probe; every caller waits for its answer) and processes (the
    probe's cgroup has a random name). The grader probes before any worker starts, so every
    submission of a run is graded under the isolation the run's header states.
    """
    if _PROBED:
        return _PROBED[0]
    with _PROBE_LOCK:
        if not _PROBED:
            _PROBED.append(_probe())
        return _PROBED[0]


def forget_capabilities() -> None:
    """Probe again on the next :func:`capabilities` call (tests; a machine that changed)."""
    with _PROBE_LOCK:
        _PROBED.clear()


def _probe() -> Capabilities:
    evidence: list[str] = []
    if os.environ.get("COBOTLAB_SANDBOX") == "rlimits":
        evidence.append("COBOTLAB_SANDBOX=rlimits: sandbox disabled on request")
        return Capabilities(False, False, None, tuple(evidence),
                            "the sandbox was turned off (COBOTLAB_SANDBOX=rlimits); unset it")
    bwrap, root, why = _probe_tools(evidence)
    cgroup = _probe_cgroup(evidence)
    cpu_share = _probe_cpu(cgroup, evidence)
    _probe_run_queue(evidence)
    try:
        syscalls.program()
        filtered, unfiltered_why = True, ""
    except syscalls.UnsupportedMachine as exc:
        filtered, unfiltered_why = False, str(exc)
    caps = Capabilities(bwrap, root, cgroup, tuple(evidence), why, filtered, cpu_share)
    if not bwrap:
        return caps
    ok, said, lines = _probe_bwrap(caps, evidence)
    denied = lines[1:2] == [f"-1 {syscalls.DENIED_ERRNO}"]
    if not filtered:
        evidence.append(f"keyring calls in the sandbox: not filtered ({unfiltered_why})")
    elif ok:
        evidence.append("keyring calls in the sandbox: " + (
            "denied by the seccomp filter (EPERM), in a new session keyring" if denied
            else f"NOT denied (keyctl gave {lines[1].strip()!r}): rows are flagged"))
    if not ok:
        return Capabilities(False, False, cgroup, tuple(evidence), _why_bwrap_failed(
            said, root), False, cpu_share)
    return Capabilities(True, root, cgroup, tuple(evidence), "", filtered and denied,
                        cpu_share)


def _probe_tools(evidence: list[str]) -> tuple[bool, bool, str]:
    """(bubblewrap usable as far as its tools go, running as root, why not when it is not)."""
    root = os.geteuid() == 0
    bwrap = shutil.which("bwrap") is not None
    why = ""
    if not bwrap:
        evidence.append("bwrap not found (Debian/Ubuntu: apt-get install bubblewrap)")
        why = ("bubblewrap is not installed (bwrap is not on PATH); install it: apt-get "
               "install bubblewrap (Debian, Ubuntu), dnf install bubblewrap (Fedora, RHEL)")
    if bwrap and root and not shutil.which("setpriv"):
        evidence.append("setpriv not found: cannot drop root inside the sandbox")
        why = ("setpriv is not installed, so root cannot be dropped inside the sandbox; "
               "install util-linux (apt-get install util-linux), or grade as a regular user")
        bwrap = False
    return bwrap, root, why


def _probe_bwrap(caps: Capabilities, evidence: list[str]) -> tuple[bool, str, list[str]]:
    """Run a small Python in the sandbox ``caps`` describes: (it ran, what bubblewrap said
    on stderr, its stdout's lines padded with two empty ones). Its first line is its uid
    and network interfaces; its second what keyctl(KEYCTL_GET_KEYRING_ID, session) gave."""
    from autograder.views import interpreter_view

    jail = Jail.of_view(interpreter_view(), scratch_mb=1, env={"PATH": "/usr/bin:/bin"})
    keyctl = syscalls.keyctl_number() if caps.syscall_filter else -1
    probe = [sys.executable, "-I", "-c",
             "import os,socket,ctypes; open('/tmp/p','w').write('x'); "
             "print(os.getuid(), len(socket.if_nameindex())); "
             "c=ctypes.CDLL(None,use_errno=True); c.syscall.restype=ctypes.c_long; "
             f"print(c.syscall({keyctl},0,-3,0) if {keyctl}>0 else 0, ctypes.get_errno())"]
    try:
        done = subprocess.run(command(probe, jail, caps=caps), capture_output=True,
                              text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError) as exc:
        evidence.append(f"bwrap probe failed: {exc}")
        return False, str(exc), []
    said = done.stderr.strip()
    lines = done.stdout.splitlines() + ["", ""]
    evidence.append(f"bwrap probe: exit {done.returncode}, uid and interfaces "
                    f"{lines[0].strip()!r} {said[:200]!r}")
    return done.returncode == 0, said, lines


# What bubblewrap says when the kernel (a sysctl, AppArmor, a container's seccomp profile)
# refuses an unprivileged user namespace.
_USERNS_REFUSED = ("namespace", "uid map", "ENOSPC", "No permissions to creat",
                   "Operation not permitted", "setting up uid map")


def _why_bwrap_failed(said: str, root: bool) -> str:
    """One sentence: why the probe's sandbox did not start, and what would make it start."""
    first = " ".join(said.split())[:200] or "no message"
    if not root and any(s.lower() in said.lower() for s in _USERNS_REFUSED):
        return (f"bubblewrap cannot create a user namespace for this user (bwrap: {first}); "
                "enable unprivileged user namespaces (sysctl user.max_user_namespaces=15000 "
                "and, on Debian before 11, kernel.unprivileged_userns_clone=1; on Ubuntu "
                "23.10 or later, kernel.apparmor_restrict_unprivileged_userns=0 or an "
                "AppArmor profile for bwrap; in a container, a seccomp profile that allows "
                "them), or grade as root")
    return (f"bubblewrap could not start a sandbox here (bwrap: {first}); see "
            ".cobotlab/last_run.log for the probe, and the bubblewrap documentation")


def fallback_warning(caps: Capabilities | None = None) -> str | None:
    """The line to show before grading starts when student code will run without
    bubblewrap (None when it runs in it): why, what that means, what to install or
    enable."""
    caps = caps or capabilities()
    if caps.bwrap:
        return None
    why = caps.why or "bubblewrap is not usable here (see .cobotlab/last_run.log)"
    return ("WARNING: no sandbox: student code will run with resource limits only, as "
            "yourself, able to read what you can read, and every row of grades.csv is "
            f"flagged sandbox:rlimits_only. Why: {why}.")


def mode() -> str:
    """One line for summaries: the isolation this machine gives student code."""
    return capabilities().mode


# --------------------------------------------------------------------------- scratch folders

_SCRATCH_FS = "cobotlab-scratch"


class ScratchDir:
    """A throwaway host folder for one sandboxed run, bound read-write into it.

    As root it is a tmpfs of ``size_mb`` (so the run cannot fill the disk) owned by the
    sandbox user; otherwise a plain temporary folder (``size_limited`` is then False).
    """

    def __init__(self, size_mb: int, prefix: str = "cobotlab-scratch-"):
        # The owner's pid in the name: a later run removes the folder only once it is dead.
        self.path = private_folder(prefix)
        self.size_limited = False
        caps = capabilities()
        if os.geteuid() == 0 and shutil.which("mount"):
            done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={int(size_mb)}m,mode=0755",
                                   _SCRATCH_FS, str(self.path)], capture_output=True, check=False)
            self.size_limited = done.returncode == 0
        if caps.drop_to_uid:
            os.chown(self.path, SANDBOX_UID, SANDBOX_UID)

    def give(self, path: Path) -> None:
        """Hand ``path`` (inside the folder) and everything under it to the sandbox user."""
        if not capabilities().drop_to_uid:
            return
        for dirpath, dirnames, filenames in os.walk(path):
            os.chown(dirpath, SANDBOX_UID, SANDBOX_UID)
            for name in filenames:
                os.chown(os.path.join(dirpath, name), SANDBOX_UID, SANDBOX_UID,
                         follow_symlinks=False)

    def remove(self) -> None:
        if self.size_limited:
            subprocess.run(["umount", "-l", str(self.path)], capture_output=True, check=False)
        shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.remove()


def remove_stale_scratch() -> int:
    """Unmount scratch tmpfs left by an interrupted run (safe to call at any start)."""
    if os.geteuid() != 0:
        return 0
    count = 0
    try:
        mounts = Path("/proc/self/mounts").read_text().splitlines()
    except OSError:
        return 0
    for line in mounts:
        fields = line.split()
        if len(fields) > 2 and fields[0] == _SCRATCH_FS and fields[2] == "tmpfs":
            target = fields[1].encode().decode("unicode_escape")
            owner = _owner_pid(Path(target).name, "cobotlab-scratch-")
            if owner is not None and process_alive(owner):
                continue
            if subprocess.run(["umount", "-l", target], capture_output=True,
                              check=False).returncode == 0:
                shutil.rmtree(target, ignore_errors=True)
                count += 1
    return count


# The temporary folders a grading process makes for itself (a worker's pipes and stderr, a
# cluster task's copy of the student's notebook), named for it by private_folder.
PRIVATE_PREFIXES = ("cobotlab-worker-", "cobotlab-cluster-")


def private_folder(prefix: str) -> Path:
    """A new temporary folder (mode 700) named ``<prefix><pid>-<random>`` for this process,
    so that a later run can tell when its owner is gone (:func:`remove_stale_folders`)."""
    import tempfile

    return Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-"))


def remove_stale_folders() -> int:
    """Remove this user's :data:`PRIVATE_PREFIXES` folders in the temporary folder whose
    owning process is gone: a grader or a Dask worker killed before its clean-up (SIGKILL,
    the OOM killer, a preempted node) leaves them, one of them with a copy of a student's
    notebook. A folder whose pid is alive, or reused by another process, is kept. Safe to
    call at any start; returns how many were removed."""
    import tempfile

    top = Path(tempfile.gettempdir())
    removed = 0
    try:
        entries = list(os.scandir(top))
    except OSError:
        return 0
    for entry in entries:
        prefix = next((p for p in PRIVATE_PREFIXES if entry.name.startswith(p)), None)
        if prefix is None:
            continue
        owner = _owner_pid(entry.name, prefix)
        try:
            mine = entry.is_dir(follow_symlinks=False) and \
                entry.stat(follow_symlinks=False).st_uid == os.geteuid()
        except OSError:
            continue
        if mine and owner is not None and not _running(owner):
            shutil.rmtree(entry.path, ignore_errors=True)
            removed += not os.path.lexists(entry.path)
    return removed


def _owner_pid(name: str, prefix: str) -> int | None:
    """The pid a ``<prefix><pid>-<random>`` folder (private_folder's naming) is named for;
    None when its name holds none."""
    owner = name.removeprefix(prefix).split("-")[0]
    return int(owner) if owner.isdigit() else None


def _running(pid: int) -> bool:
    """Alive and not a zombie (a killed process its parent has not reaped yet is gone)."""
    if not process_alive(pid):
        return False
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")


def process_alive(pid: int) -> bool:
    """True while process ``pid`` exists (also when it belongs to another user)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
