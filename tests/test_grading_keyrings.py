"""Kernel keyrings: no sandbox reads the grader's keys or another submission's (issue 37, 1).

The grader's session keyring (where an SSH login with pam_keyinit keeps its tokens) is
inherited by every process it starts, and the user keyring is shared by every process of
one uid. Here the test process plays the instructor: a token in a session keyring of its
own and one in its user keyring; student code, in a cold worker, in a template's fork and
in nbgrader's kernel jail, must find neither, nor the key a submission before it tried to
leave, and each of its keyring calls is refused. Real bubblewrap, real forks, real keyrings;
tests/test_unprivileged.py runs the same probe as an unprivileged instructor.

The filter program itself is checked for every architecture it knows, on a small classic-BPF
interpreter: a 64-bit process can also call the kernel through the 32-bit and x32 ABIs.
"""

from __future__ import annotations

import errno
import json
import platform
import struct
import subprocess
import sys

import course_kit as kit
import pytest

from autograder import sandbox, scratch
from autograder.inside import syscalls
from autograder.pipeline.worker import Limits, Worker, WorkerSetup
from autograder.template import Template

LIMITS = Limits(cell_timeout_s=8, call_timeout_s=8, load_timeout_s=30)
TOKEN, USER_TOKEN = "cobotlab-instructor-token", "cobotlab-instructor-user-token"   # kit's
PLANTED = "cobotlab-planted-by-a-submission"

# What a submission tries, with ctypes: find and read the instructor's tokens and a key an
# earlier submission planted, in every keyring it can name; list the keys and key users
# procfs shows it (as the instructor's own uid, every key of the instructor's, in any
# session); then plant a key of its own (readable by its uid) in its session and user
# keyrings.
PROBE = f"""
import ctypes, json, platform
_NR = {{"x86_64": (248, 249, 250), "aarch64": (217, 218, 219)}}[platform.machine()]
_libc = ctypes.CDLL(None, use_errno=True)
_libc.syscall.restype = ctypes.c_long
def _call(*args):
    result = _libc.syscall(*args)
    return result if result >= 0 else -ctypes.get_errno()
def keys():
    add_key, _, keyctl = _NR
    found = {{}}
    for ring in (-3, -4, -5):   # session, user, user session
        for name in ({TOKEN!r}, {USER_TOKEN!r}, {PLANTED!r}):
            key = _call(keyctl, 10, ring, b"user", name.encode(), 0)   # KEYCTL_SEARCH
            if key > 0:
                buf = ctypes.create_string_buffer(256)
                n = _call(keyctl, 11, key, buf, 256)                   # KEYCTL_READ
                found[f"{{ring}} {{name}}"] = buf.raw[:n].decode() if n >= 0 else n
    listed = open("/proc/keys").readlines() + open("/proc/key-users").readlines()
    planted = []
    for ring in (-3, -4):
        key = _call(add_key, b"user", {PLANTED!r}.encode(), b"from a submission", 17, ring)
        if key > 0:
            _call(keyctl, 5, key, 0x3f3f3f3f)                           # KEYCTL_SETPERM
        planted.append(key)
    return {{"found": found, "listed": listed, "planted": planted,
            "session": _call(keyctl, 0, -3, 0)}}                        # GET_KEYRING_ID
"""
DENIED = -errno.EPERM
NOTHING = {"found": {}, "listed": [], "planted": [DENIED, DENIED], "session": DENIED}

pytestmark = [
    pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="bubblewrap cannot run here"),
    pytest.mark.skipif(not syscalls.supported(), reason=f"no keyring filter for "
                       f"{platform.machine()}"),
]


@pytest.fixture
def instructor_keys():
    """The test process as the instructor's login: a token in a session keyring of its
    own and one in its user keyring."""
    with kit.instructor_keyring(b"session-secret", b"user-secret"):
        yield


def _probe_twice(start) -> list[dict]:
    """The probe in two submissions, one after the other (``start(cells)``: a worker)."""
    seen = []
    for _ in range(2):
        with start([PROBE]) as worker:
            seen.append(worker.call("keys", (), 5).value)
    return seen


def test_a_cold_worker_reaches_no_keyring(instructor_keys):
    assert _probe_twice(lambda cells: Worker(cells, LIMITS)) == [NOTHING, NOTHING]


def test_a_template_fork_reaches_no_keyring(instructor_keys):
    made = Template([PROBE], LIMITS, cpu_s=60)
    try:
        seen = _probe_twice(lambda cells: Worker(cells, LIMITS, WorkerSetup(template=made)))
    finally:
        made.close()
    assert seen == [NOTHING, NOTHING]


def test_nbgraders_kernel_jail_reaches_no_keyring(instructor_keys, tmp_path):
    # scratch.autograde_one's jail, with nbgrader's shape: a process in it starts a child
    # in a session of its own (jupyter_client starts the kernel so); both probe.
    course, home, source = tmp_path / "course", tmp_path / "home", tmp_path / "source"
    for folder in (course / "source" / "lab0_frames", home, source):
        folder.mkdir(parents=True)
    config = tmp_path / "nbgrader_config.py"
    config.touch()
    (course / "nbgrader_config.py").touch()
    jail = scratch.kernel_jail(course, home, source, config, "lab0_frames")
    code = PROBE + (
        "\nimport subprocess, sys\n"
        "child = subprocess.run([sys.executable, '-I', '-c', sys.argv[1] + "
        "'\\nprint(json.dumps(keys()))'], capture_output=True, text=True, "
        "start_new_session=True)\n"
        "print(json.dumps([keys(), json.loads(child.stdout or 'null'), child.stderr]))\n")
    seen = []
    for _ in range(2):
        done = subprocess.run(sandbox.command([sys.executable, "-I", "-c", code, PROBE],
                                              jail), capture_output=True, text=True,
                              timeout=120, check=False)
        assert done.returncode == 0, done.stderr[-2000:]
        outer, inner, said = json.loads(done.stdout)
        seen += [outer, inner]
    assert seen == [NOTHING] * 4, said


# --------------------------------------------------------------------------- the program

SECCOMP_DATA = struct.Struct("=iIQ6Q")   # nr, arch, instruction pointer, args


def _run_filter(program: bytes, arch: int, nr: int) -> int:
    """What seccomp answers for system call ``nr`` of ABI ``arch`` (classic BPF, the few
    instructions the filter uses)."""
    code = [struct.unpack_from("=HBBI", program, i) for i in range(0, len(program), 8)]
    data = SECCOMP_DATA.pack(nr, arch, 0, *[0] * 6)
    acc, pc = 0, 0
    while True:
        op, jt, jf, k = code[pc]
        pc += 1
        if op == 0x20:                  # ld [k]
            acc = struct.unpack_from("=I", data, k)[0]
        elif op == 0x54:                # and #k
            acc &= k
        elif op == 0x15:                # jeq #k
            pc += jt if acc == k else jf
        elif op == 0x06:                # ret #k
            return k
        else:
            raise AssertionError(f"unexpected instruction {op:#x}")


ALLOW, KILL, EPERM = 0x7FFF0000, 0x80000000, 0x00050000 | errno.EPERM
# (machine, audit arch, keyring call numbers, a few others that must pass)
ABIS = [("x86_64", 0xC000003E, (248, 249, 250), (0, 1, 59, 231, 251, 247)),
        ("x86_64", 0xC000003E, (0x40000000 | 248, 0x40000000 | 249, 0x40000000 | 250),
         (0x40000000, 0x40000000 | 59)),                                     # x32
        ("x86_64", 0x40000003, (286, 287, 288), (1, 3, 11, 250)),             # i386
        ("aarch64", 0xC00000B7, (217, 218, 219), (63, 64, 93, 220, 250)),
        ("aarch64", 0x40000028, (309, 310, 311), (1, 3, 219, 250))]          # AArch32


@pytest.mark.parametrize("machine, arch, keyring, others", ABIS)
def test_the_filter_denies_keyring_calls_in_every_abi_of_its_machine(machine, arch, keyring,
                                                                     others):
    program = syscalls.program(machine)
    assert len(program) % 8 == 0 and len(program) // 8 < 256   # jumps are 8-bit
    assert [_run_filter(program, arch, nr) for nr in keyring] == [EPERM] * 3
    assert [_run_filter(program, arch, nr) for nr in others] == [ALLOW] * len(others)
    # an ABI the machine has no rule for (another machine's) ends the process
    foreign = 0xC00000B7 if machine == "x86_64" else 0xC000003E
    assert _run_filter(program, foreign, 0) == KILL


def test_an_unknown_machine_is_refused_by_name():
    with pytest.raises(syscalls.UnsupportedMachine, match="no keyring filter for riscv64"):
        syscalls.program("riscv64")
    assert syscalls.supported("arm64") and not syscalls.supported("ppc64le")
