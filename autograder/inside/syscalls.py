"""What sandboxed code may ask of the kernel: no keyrings.

Linux keeps secrets in kernel keyrings: a login's session keyring (``pam_keyinit``: Kerberos,
AFS and NFS tokens, ecryptfs and fscrypt keys) and a keyring per user id. A process
possesses its session keyring's keys, whoever it runs as, and inherits that keyring from
its parent; the user keyring is shared by every process of one uid. So student code
started by the grader could read the instructor's tokens, and a key one submission put in
the sandbox user's keyring could be read by the next. Three measures, all before any
student code runs:

* every sandbox starts in a new, empty session keyring (:func:`new_session_keyring`):
  :func:`main` joins one on the host before it starts bubblewrap, and a template's fork
  joins its own before it serves a submission;
* ``/proc/keys`` and ``/proc/key-users``, which name the keys of the sandbox's uid in
  every session, are empty there (:data:`KEY_LISTS`);
* in the sandbox the keyring system calls (``add_key``, ``request_key``, ``keyctl``) fail
  with EPERM, through a seccomp filter (:func:`program`, the one builder of it): bubblewrap
  loads it (``--seccomp``) for a cold worker and nbgrader's kernel, and a template's fork
  installs it itself (:func:`install`, after ``no_new_privs``), the template having none
  so that its forks can still join keyrings of their own.

The filter reads the system call's architecture first: a 64-bit process can also make
32-bit calls (``int 0x80`` on x86-64, AArch32 code on arm64) and x32 calls, each with other
numbers, so each of those has its own rule, and a call of any other architecture kills the
process. Machines other than x86-64 and arm64 get no filter (:class:`UnsupportedMachine`:
the sandbox probe records why, and every grade row says so).

Standard library only (ctypes for the system calls): a template's fork imports it in the
worker's view, and :func:`main` runs before the sandbox exists.
"""

from __future__ import annotations

import ctypes
import errno
import os
import platform
import struct
import sys

__all__ = ["UnsupportedMachine", "program", "supported", "keyctl_number", "install",
           "new_session_keyring", "main"]

# Classic BPF, as seccomp runs it (linux/filter.h, linux/seccomp.h, linux/audit.h).
_LD_W_ABS, _JEQ_K, _AND_K, _RET_K = 0x20, 0x15, 0x54, 0x06
_NR, _ARCH = 0, 4                       # offsets in struct seccomp_data
_ALLOW, _KILL_PROCESS = 0x7FFF0000, 0x80000000
_ERRNO = 0x00050000
DENIED_ERRNO = errno.EPERM
_X32_BIT = 0x40000000

AUDIT_ARCH_X86_64, AUDIT_ARCH_I386 = 0xC000003E, 0x40000003
AUDIT_ARCH_AARCH64, AUDIT_ARCH_ARM = 0xC00000B7, 0x40000028

# Per machine: every ABI its processes can call the kernel with, as (audit arch, the
# numbers of add_key, request_key and keyctl, a mask applied to the number first). x32
# calls carry x86-64's arch with bit 30 set in the number: the mask folds them onto it.
ABIS: dict[str, tuple[tuple[int, tuple[int, int, int], int | None], ...]] = {
    "x86_64": ((AUDIT_ARCH_X86_64, (248, 249, 250), ~_X32_BIT & 0xFFFFFFFF),
               (AUDIT_ARCH_I386, (286, 287, 288), None)),
    "aarch64": ((AUDIT_ARCH_AARCH64, (217, 218, 219), None),
                (AUDIT_ARCH_ARM, (309, 310, 311), None)),
}
_ALIASES = {"amd64": "x86_64", "arm64": "aarch64"}
KEYCTL_JOIN_SESSION_KEYRING = 1
# Procfs lists every key its reader's uid may view, in any session of that uid, and every
# uid's key counts: read with no system call the filter could stop, and an unprivileged
# grader's sandbox runs as the instructor's own uid. Each sandbox sees them empty.
KEY_LISTS = ("/proc/keys", "/proc/key-users")


class UnsupportedMachine(RuntimeError):
    """No keyring filter is known for this machine's system-call numbers."""


def _machine(machine: str | None) -> str:
    name = (machine or platform.machine()).lower()
    name = _ALIASES.get(name, name)
    if name not in ABIS:
        raise UnsupportedMachine(
            f"no keyring filter for {name} (known: {', '.join(sorted(ABIS))}): sandboxed "
            "code here can reach the kernel keyrings of its session and user")
    return name


def supported(machine: str | None = None) -> bool:
    """True when :func:`program` has a filter for ``machine`` (default: this one)."""
    try:
        _machine(machine)
    except UnsupportedMachine:
        return False
    return True


def keyctl_number(machine: str | None = None) -> int:
    """The number of ``keyctl`` in ``machine``'s own ABI (default: this one's)."""
    return ABIS[_machine(machine)][0][1][2]


def program(machine: str | None = None) -> bytes:
    """The seccomp filter (``struct sock_filter`` array, native byte order) denying the
    keyring system calls with EPERM on ``machine`` (default: this one). Raises
    :class:`UnsupportedMachine` for any other than x86-64 and arm64."""
    abis = ABIS[_machine(machine)]
    # (code, jump-if-true label, jump-if-false label, k); a label is the index it names.
    code: list[tuple[int, str | None, str | None, int]] = [(_LD_W_ABS, None, None, _ARCH)]
    for i, (arch, _, _) in enumerate(abis):
        code.append((_JEQ_K, f"abi{i}", None, arch))
    code.append((_RET_K, None, None, _KILL_PROCESS))   # an ABI this filter does not know
    labels: dict[str, int] = {}
    for i, (_, numbers, mask) in enumerate(abis):
        labels[f"abi{i}"] = len(code)
        code.append((_LD_W_ABS, None, None, _NR))
        if mask is not None:
            code.append((_AND_K, None, None, mask))
        code += [(_JEQ_K, "deny", None, nr) for nr in numbers]
        code.append((_RET_K, None, None, _ALLOW))
    labels["deny"] = len(code)
    code.append((_RET_K, None, None, _ERRNO | DENIED_ERRNO))
    out = b""
    for index, (op, true, false, k) in enumerate(code):
        jt = labels[true] - index - 1 if true else 0
        jf = labels[false] - index - 1 if false else 0
        out += struct.pack("=HBBI", op, jt, jf, k)
    return out


_libc = ctypes.CDLL(None, use_errno=True)
_libc.syscall.restype = ctypes.c_long
PR_SET_SECCOMP, SECCOMP_MODE_FILTER = 22, 2


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


def install() -> None:
    """Put this thread (and everything it starts) under :func:`program`'s filter, for
    good. Needs ``no_new_privs`` (or CAP_SYS_ADMIN); raises OSError when refused."""
    code = program()
    buffer = ctypes.create_string_buffer(code, len(code))
    fprog = _SockFprog(len(code) // 8, ctypes.cast(buffer, ctypes.c_void_p))
    if _libc.prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, ctypes.byref(fprog), 0, 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"install the keyring filter: {os.strerror(err)}")


def new_session_keyring() -> bool:
    """Join a new, empty, anonymous session keyring (this thread, and what it starts from
    now on). False where the kernel has no keyrings or a filter above this process denies
    them (then nothing below it can reach one either); raises OSError otherwise."""
    if _libc.syscall(keyctl_number(), KEYCTL_JOIN_SESSION_KEYRING, None) >= 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EPERM):
        return False
    raise OSError(err, f"join a new session keyring: {os.strerror(err)}")


def main(argv: list[str]) -> int:
    """Start a sandbox: ``[--join PROCS_FILE]... [--filter] -- BWRAP ARGS...``.

    Joins each cgroup (writes this pid to its ``cgroup.procs``) and a new session keyring,
    then executes bubblewrap, with ``--seccomp FD`` added after its path when ``--filter``
    is given, so every process in the sandbox is charged to the cgroups, starts without the
    grader's keyrings and cannot make keyring calls."""
    split = argv.index("--")
    options, command = argv[:split], argv[split + 1:]
    joins = [options[i + 1] for i, word in enumerate(options) if word == "--join"]
    try:
        for path in joins:
            with open(path, "w") as f:
                f.write(str(os.getpid()))
        if supported():
            new_session_keyring()
        if "--filter" in options:
            read, write = os.pipe()
            os.write(write, program())   # a few hundred bytes: the pipe holds them
            os.close(write)
            os.set_inheritable(read, True)
            command[1:1] = ["--seccomp", str(read)]
        os.execv(command[0], command)
    except OSError as exc:
        print(f"cobotlab sandbox launcher: {exc}", file=sys.stderr)
        return 70
    return 70   # not reached: execv does not return


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
