"""A fresh sandbox for one submission, made inside the grading template's sandbox.

The template (:mod:`autograder.inside.worker` in template mode) has imported the lab's libraries
and run the notebook's leading read-only cells once; each submission is a fork of it. A
fork shares the template's mount, PID and IPC namespaces, so before any student code runs
the forked process moves into namespaces of its own:

* a user namespace (the same uid inside and out) owning the rest, so no privilege is
  needed: the template itself holds none;
* a mount namespace with its own empty ``/tmp`` and ``/dev/shm`` (tmpfs; the template's are
  out of sight) and ``/dev`` read-only: a file written there dies with the submission;
* a PID namespace in which the submission is process 1: it cannot see or signal the
  template, and when it ends the kernel kills every process it left behind;
* IPC, UTS and network namespaces (the network: loopback only, as bubblewrap's
  ``--unshare-net`` gives a cold worker), so two submissions forked from one template at
  once cannot talk to each other.

Then the process drops every capability (bounding set too), keeps ``no_new_privs`` and
may not create further user namespaces, as bubblewrap's ``--disable-userns`` has it; the
worker then gives it a session keyring of its own and the keyring filter
(:mod:`autograder.inside.syscalls`).
Standard library only (ctypes for the system calls Python 3.11 lacks): this module runs in
the worker's view.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import socket
import struct

from autograder.inside import syscalls

CLONE_NEWNS = 0x00020000
CLONE_NEWUTS = 0x04000000
CLONE_NEWIPC = 0x08000000
CLONE_NEWUSER = 0x10000000
CLONE_NEWPID = 0x20000000
CLONE_NEWNET = 0x40000000
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC = 0x1, 0x2, 0x4, 0x8
MS_REMOUNT, MS_BIND, MS_REC, MS_PRIVATE = 0x20, 0x1000, 0x4000, 0x40000
# statvfs's ST_* flags that equal the MS_* mount flags of the same name.
_KEPT_FLAGS = MS_NOSUID | MS_NODEV | MS_NOEXEC | 0x400 | 0x800 | 0x1000  # noatime nodiratime relatime
PR_SET_DUMPABLE, PR_CAPBSET_DROP, PR_SET_NO_NEW_PRIVS = 4, 24, 38
_LINUX_CAPABILITY_VERSION_3 = 0x20080522
_CAP_LAST = 63
SHM_BYTES = 8 * 1024 * 1024

_libc = ctypes.CDLL(None, use_errno=True)


class IsolationError(OSError):
    """A namespace, mount or capability step failed: the submission must not run here."""


def _check(result: int, what: str) -> None:
    if result != 0:
        code = ctypes.get_errno()
        raise IsolationError(code, f"{what}: {os.strerror(code)}")


def _mount(source: str, target: str, fstype: str | None, flags: int, data: str | None,
           what: str) -> None:
    _check(_libc.mount(source.encode(), target.encode(),
                       fstype.encode() if fstype else None, flags,
                       data.encode() if data else None), what)


def _write(path: str, text: str) -> None:
    with open(path, "w") as f:
        f.write(text)


def leave_template(scratch_bytes: int) -> None:
    """In the forked process, before its child is forked: new user, mount, PID, IPC, UTS
    and network namespaces (loopback up), a fresh ``/tmp`` of ``scratch_bytes`` and ``/dev/shm``, ``/dev`` read-only.
    The PID namespace holds the *next* child (the caller forks it: it is process 1 there)."""
    uid, gid = os.getuid(), os.getgid()
    _check(_libc.unshare(CLONE_NEWUSER | CLONE_NEWNS | CLONE_NEWPID | CLONE_NEWIPC
                         | CLONE_NEWUTS | CLONE_NEWNET),
           "unshare (user, mount, pid, ipc, uts and network namespaces)")
    # The template is not dumpable, so its /proc files are root's: a fork may write its
    # own maps only while dumpable, and is not dumpable again before anything else runs.
    _check(_libc.prctl(PR_SET_DUMPABLE, 1, 0, 0, 0), "make the fork dumpable")
    _write("/proc/self/setgroups", "deny")
    _write("/proc/self/uid_map", f"{uid} {uid} 1")
    _write("/proc/self/gid_map", f"{gid} {gid} 1")
    not_dumpable()
    _mount("none", "/", None, MS_REC | MS_PRIVATE, None, "make the mounts private")
    # A user namespace may add flags to a mount it inherited, never drop one: keep them all.
    kept = os.statvfs("/dev").f_flag & _KEPT_FLAGS
    _mount("none", "/dev", None, MS_REMOUNT | MS_BIND | MS_RDONLY | kept, None,
           "remount /dev read-only")
    _mount("tmpfs", "/dev/shm", "tmpfs", MS_NOSUID | MS_NODEV | MS_NOEXEC,
           f"size={SHM_BYTES},mode=1777", "a fresh /dev/shm")
    _mount("tmpfs", "/tmp", "tmpfs", MS_NOSUID | MS_NODEV,
           f"size={int(scratch_bytes)},mode=1777", "a fresh /tmp")
    os.chdir("/tmp")  # the old working directory is the template's /tmp
    _loopback_up()


def _loopback_up() -> None:
    siocsifflags, iff_up_loopback_running = 0x8914, 0x1 | 0x8 | 0x40
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            fcntl.ioctl(s, siocsifflags, struct.pack("16sH", b"lo", iff_up_loopback_running))
        except OSError as exc:
            raise IsolationError(exc.errno, f"bring up loopback: {exc.strerror}") from None


def enter_own_pid_namespace() -> bool:
    """In the child (process 1 of its PID namespace): its own ``/proc``; False where the
    kernel refuses it (a /proc partly covered by the outer sandbox, as bubblewrap does when
    run as root): the inherited ``/proc`` then stays, which lists the template's processes
    but gives no way to reach them (kill and ptrace take PIDs of this namespace, where they
    do not exist, and the template is not dumpable)."""
    result = _libc.mount(b"proc", b"/proc", b"proc", MS_NOSUID | MS_NODEV | MS_NOEXEC, None)
    if result == 0:
        for path in syscalls.KEY_LISTS:   # as bubblewrap's /proc has them: empty
            if os.path.exists(path):
                _mount("/dev/null", path, None, MS_BIND, None, f"hide {path}")
        return True
    code = ctypes.get_errno()
    if code not in (errno.EPERM, errno.EACCES):
        raise IsolationError(code, f"mount /proc: {os.strerror(code)}")
    return False


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32),
                ("inheritable", ctypes.c_uint32)]


def drop_privileges() -> None:
    """No further user namespaces, no capabilities (bounding set included), no new
    privileges: what bubblewrap's ``--disable-userns --cap-drop ALL`` leaves a worker."""
    _write("/proc/sys/user/max_user_namespaces", "0")
    for cap in range(_CAP_LAST + 1):
        result = _libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0)
        if result != 0 and ctypes.get_errno() != errno.EINVAL:   # EINVAL: no such cap
            _check(result, f"drop capability {cap} from the bounding set")
    _check(_libc.capset(ctypes.byref(_CapHeader(_LINUX_CAPABILITY_VERSION_3, 0)),
                        (_CapData * 2)()), "clear the capabilities")
    _check(_libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "set no_new_privs")
    with open("/proc/self/status") as f:
        status = f.read()
    if "CapEff:\t0000000000000000" not in status or "CapBnd:\t0000000000000000" not in status:
        raise IsolationError(errno.EPERM, "capabilities are left after dropping them")


def not_dumpable() -> None:
    """The template: no process of its uid may ptrace it or read its memory through /proc
    (only with CAP_SYS_PTRACE, which no sandboxed process holds)."""
    _check(_libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0), "make the template not dumpable")
