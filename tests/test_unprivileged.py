"""`cobotlab grade` as an instructor runs it: as an unprivileged user (issue 25, item 4).

CI runs as root; an instructor grades as their own user on a course server. This file makes
that user (``cobotlab-ta``, created once and reused), gives it a Python it can execute, and
runs the real command line as it (``setpriv --reuid --regid --init-groups``):

* **with user namespaces** (this machine's default): lab 0 adversarial cases through
  ``cobotlab grade`` on a course the user released and owns must score as they do for root
  (each case's score bounds and flags, the reference's code full marks, a blank 0), under
  bubblewrap's user-namespace path (no root to drop from: ``--unshare-user``);
* **without** (``user.max_user_namespaces`` set to 0 in a user namespace of the user's own,
  so bubblewrap fails there exactly as on a machine or container that forbids them): the
  rlimits-only fallback is used, ``cobotlab grade`` says so on stderr before any submission
  is graded, every row of grades.csv is flagged, and Ctrl-C still stops nbgrader's kernel,
  which jupyter_client starts in a session of its own.

The user's Python: the project's interpreter may sit where the user cannot reach it (pyenv
under root's mode-700 home), so a virtual environment is made from a system interpreter of
the same version (the same ABI), outside every private folder, holding this environment's
libraries as hard links (tests/test_course_install.py's helpers) and cobotlab from a wheel
built from the working tree: a regular install, as on a course server.

Graded as the user: the notebook-layer cases of the lab 0 corpus whose grade depends on
what differs for the user (SANDBOX_CASES: the user's limits without a cgroup, what the user's
jail shows of the user's own course and regular install), and one that fools nbgrader's own
kernel, in a first run with ``--nbgrader-kernel`` so that its cross-check flags it (the
kernel's jail as the user; tests/test_corpus_batch_a.py grades all three with it as root),
five course, host and layout cases of tests/test_grading_flow.py's slice (files outside the
scratch space, a symlinked notebook, a symlinked folder, the answer key, the keyrings: the
user's login token in the grader's session keyring), the victim they aim at and a blank.
With ``COBOTLAB_FULL_CORPUS=1`` (benchmarks/adversarial_corpus.py) every notebook-layer case
but one is graded as the user, and the reference too.
tests/test_grading_keyrings.py also runs as the user. Left to the root tests, even in the
full corpus: ``infinite_loop``, which costs over a minute of CPU at the command line's
default time limits (``cobotlab grade`` has no option to lower them) and meets only
per-process timers (the cell and call CPU timers, RLIMIT_CPU), the same for any user;
``memory_bomb`` stays, as without a cgroup its per-process limits are all that hold. The
rest of the flow slice attacks the course through the paths graded here.
"""

from __future__ import annotations

import csv
import os
import pwd
import shutil
import signal
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

import course_kit as kit
import pytest
from test_course_install import _link_tree, cobotlab_wheel
from test_grade_cli import _still_running, as_a_terminal_starts_it, interrupt_once_running

from autograder import checks, sandbox

USER = "cobotlab-ta"
ASSIGNMENT = "lab0_frames"
FUNCTIONS = tuple(s.name for s in checks.SPECS[ASSIGNMENT])
# A case that fools nbgrader's own kernel, graded with it (--nbgrader-kernel), so that its
# cross-check has something to disagree with: what is new as the user is the kernel's jail,
# which one case meets; each of the three fools the kernel its own way, and
# tests/test_corpus_batch_a.py grades all three with it as root (and so does the full
# corpus here).
KERNEL_CASES = kit.FOOL_NBGRADER if kit.full_corpus() else ("kernel_patch",)
# Graded by root only (see above): it costs its time limits, the same for every user.
ROOT_ONLY = ("infinite_loop",)
# The notebook-layer cases whose grade depends on what differs for the user: its limits
# without a cgroup (memory; threads, which RLIMIT_NPROC counts per user), what the user's
# jail shows of the user's own course (its secret) and of its regular install (the labs'
# source notebooks in site-packages). Every submission as the user starts cold, so the
# cases root's cold run already tells apart and whose target is the same for any user are
# left to root (tests/test_corpus_batch_*.py, REGRADED_COLD) and the full corpus:
# forge_protocol (the reply pipe is the grader's own, whoever runs it) and
# importlib_solutions (the answer key by another spelling: FLOW_CASES' import_solutions
# meets the user's jail, the spelling only the scan, the same for any user).
# The rest (values, the source scan, floods, a mangled notebook) grade the same under any
# sandbox: tests/test_corpus_batch_b.py grades them.
SANDBOX_CASES = ("forbidden_thread", "memory_bomb", "reader_source_notebook", "secret_hunt")
# Of tests/test_grading_flow.py's course, host and layout slice: one attack per path
# (write_outside writes beside the user's course, in the user's home and into the user's
# install: gradebook_overwrite's write into the course is the same path, left to the flow
# test and the full corpus).
FLOW_CASES = ("write_outside", "symlink_notebook", "symlink_folder", "import_solutions",
              "keyring") + (("gradebook_overwrite",) if kit.full_corpus() else ())
# A user namespace of the user's own in which no further one may be made: bubblewrap's
# --unshare-user then fails as where the kernel, a sysctl, AppArmor or a container's seccomp
# profile forbids unprivileged user namespaces. The process keeps its uid; exec drops the
# capabilities it had in the new namespace.
NO_USERNS = """\
import ctypes, os, sys
libc = ctypes.CDLL(None, use_errno=True)
uid, gid = os.getuid(), os.getgid()
if libc.unshare(0x10000000) != 0:   # CLONE_NEWUSER
    raise OSError(ctypes.get_errno(), "unshare(CLONE_NEWUSER)")
for name, text in (("setgroups", "deny"), ("uid_map", f"{uid} {uid} 1"),
                   ("gid_map", f"{gid} {gid} 1")):
    with open(f"/proc/self/{name}", "w") as f:
        f.write(text)
with open("/proc/sys/user/max_user_namespaces", "w") as f:
    f.write("0")
os.execvp(sys.argv[1], sys.argv[1:])
"""


def _tools_missing() -> str:
    missing = [t for t in ("useradd", "setpriv", "bwrap") if shutil.which(t) is None]
    return ", ".join(missing)


pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.geteuid() != 0, reason="makes a user and runs as it: needs root (CI)"),
    pytest.mark.skipif(bool(_tools_missing()), reason=f"needs {_tools_missing()}"),
    pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="bubblewrap cannot run here"),
]


def run(argv, **kwargs) -> subprocess.CompletedProcess:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600, check=False,
                          **kwargs)
    assert done.returncode == 0, (argv, done.stdout[-3000:], done.stderr[-3000:])
    return done


def _user() -> pwd.struct_passwd:
    """The unprivileged user, made if missing (a system account with no login shell)."""
    try:
        return pwd.getpwnam(USER)
    except KeyError:
        run(["useradd", "--system", "--user-group", "--no-create-home",
             "--shell", "/usr/sbin/nologin", USER])
        return pwd.getpwnam(USER)


def _interpreter(python: str, *user: str) -> tuple[str, str] | None:
    """(version, standard library) of ``python`` as run by root, or by ``user``."""
    drop = ["setpriv", f"--reuid={user[0]}", f"--regid={user[0]}", "--init-groups"] if user \
        else []
    try:
        done = subprocess.run([*drop, python, "-I", "-c", "import sys, sysconfig; print("
                               "'%d.%d' % sys.version_info[:2], sysconfig.get_paths()"
                               "['stdlib'])"], capture_output=True, text=True, timeout=30,
                              check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    words = done.stdout.split()
    return (words[0], words[1]) if done.returncode == 0 and len(words) == 2 else None


def _base_python() -> str:
    """A system interpreter of this one's version (the same ABI as the linked libraries)
    that the user runs as root does: its own standard library, not a fallback's."""
    version = "{}.{}".format(*sys.version_info[:2])
    for candidate in (os.path.realpath(sys._base_executable), "/usr/bin/python3",
                      f"/usr/bin/python{version}", "/usr/local/bin/python3"):
        if not os.path.isfile(candidate):
            continue
        mine = _interpreter(candidate)
        if mine and mine[0] == version and _interpreter(candidate, USER) == mine:
            return candidate
    pytest.skip(f"no Python {version} the user can run")


def _give(path: Path, user: pwd.struct_passwd) -> None:
    """``path`` and everything under it to ``user`` (links themselves, never their targets)."""
    os.chown(path, user.pw_uid, user.pw_gid, follow_symlinks=False)
    for dirpath, dirnames, filenames in os.walk(path):
        for name in dirnames + filenames:
            os.chown(os.path.join(dirpath, name), user.pw_uid, user.pw_gid,
                     follow_symlinks=False)


class Instructor:
    """The unprivileged user with its Python and its course; runs commands as it."""

    def __init__(self, base: Path, user: pwd.struct_passwd):
        self.base, self.user = base, user
        self.env_dir = base / "env"
        self.home = base / "home"
        self.work = base / "work"
        self.released: Path | None = None   # the user's released course (the fixture's)
        self.env = {"HOME": str(self.home), "USER": USER, "LOGNAME": USER, "LANG": "C.UTF-8",
                    "PATH": f"{self.env_dir / 'bin'}:/usr/bin:/bin",
                    "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}

    def argv(self, argv, userns: bool = True) -> list[str]:
        prefix = ["setpriv", f"--reuid={USER}", f"--regid={USER}", "--init-groups", "--"]
        if not userns:
            prefix += [str(self.env_dir / "bin" / "python"), str(self.base / "no_userns.py")]
        return prefix + [str(a) for a in argv]

    def run(self, argv, userns: bool = True, cwd=None, check: bool = True):
        done = subprocess.run(self.argv(argv, userns), env=self.env, cwd=cwd or self.work,
                              capture_output=True, text=True, timeout=900, check=False)
        if check:
            assert done.returncode == 0, (argv, done.stdout[-3000:], done.stderr[-3000:])
        return done

    def cobotlab(self, *args, userns: bool = True, check: bool = True):
        return self.run([self.env_dir / "bin" / "cobotlab", *args], userns=userns, check=check)

    def course(self, released: Path, name: str) -> Path:
        """A copy of the user's released course (as the user: its own files)."""
        course = self.work / name
        self.run(["cp", "-a", released, course])
        config = course / "nbgrader_config.py"
        self.run(["sed", "-i", f"s|{released}|{course}|g", config])
        return course


@pytest.fixture(scope="module")
def ta(tmp_path_factory) -> Instructor:
    user = _user()
    python = _base_python()
    # Not under pytest's own (mode 700) temporary folder: the user must reach it.
    base = Path(tempfile.mkdtemp(prefix="cobotlab-unprivileged-", dir="/var/tmp"))
    try:
        os.chmod(base, 0o755)
        me = Instructor(base, user)
        for folder in (me.home, me.work):
            folder.mkdir()
            os.chown(folder, user.pw_uid, user.pw_gid)
        (base / "no_userns.py").write_text(NO_USERNS)
        # the environment: the system interpreter, this one's libraries (hard links), and
        # cobotlab from a wheel of the working tree, the regular way
        run([python, "-m", "venv", "--without-pip", str(me.env_dir)])
        site = Path(run([str(me.env_dir / "bin" / "python"), "-c", "import sysconfig; "
                         "print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
        _link_tree(Path(sysconfig.get_paths()["purelib"]), site)
        run([str(me.env_dir / "bin" / "python"), "-m", "pip", "install", "--quiet",
             "--no-deps", "--no-index", str(cobotlab_wheel())])
        found = me.run(["python", "-c", "import sys, numpy, scipy, cv2, pybullet, nbgrader, "
                        "autograder; print(sys.executable); print(autograder.__file__)"])
        assert found.stdout.splitlines() == [str(me.env_dir / "bin" / "python"),
                                             str(site / "autograder" / "__init__.py")]
        # the course: the run's one `course init` (course_kit.initialized_master), given to
        # the user, who releases lab 0 as an instructor does. `course init` run by an
        # unprivileged account from a regular install is docs/hub.md's step, run as written
        # by tests/test_hub_term.py's grading account; one more here cost 11.7 s of CPU.
        me.released = kit.fresh_course(kit.initialized_master(), me.work / "init")
        _give(me.work / "init", user)
        me.run(["python", "-m", "nbgrader", "generate_assignment", ASSIGNMENT],
               cwd=me.released)
        yield me
    finally:
        shutil.rmtree(base, ignore_errors=True)


def _hand_in(ta: Instructor, course: Path, cases: dict, names,
             full_marks=("victim", "reference")) -> set[str]:
    """Submit the named corpus cases, a blank and the reference's code under each name of
    ``full_marks`` (the victim: what the corpus's classmate attacks aim at) (as root, then
    given to the user, as nbgrader collect would leave them); returns the folder names."""
    reference = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    for name in full_marks:
        kit.submit(course, ASSIGNMENT, name, replace=reference)
    kit.submit(course, ASSIGNMENT, "blank")
    folders = {"blank", *full_marks}
    for name in names:
        folders.add(kit.submit_case(course, ASSIGNMENT, name, cases[name]))
    _give(course / "submitted", ta.user)
    return folders


def _grades(course: Path) -> dict[str, dict]:
    with open(course / "grades.csv", newline="") as f:
        return {r["student_id"]: r for r in csv.DictReader(f)}


def _students_file(ta: Instructor, course: Path, name: str, students) -> str:
    path = course.parent / f"{course.name}-{name}.txt"
    path.write_text("".join(f"{s}\n" for s in students))
    os.chown(path, ta.user.pw_uid, ta.user.pw_gid)
    return f"@{path}"


@pytest.mark.timeout(600)
def test_the_corpus_grades_as_for_root_under_bubblewraps_user_namespace(ta):
    cases = kit.corpus(ASSIGNMENT)
    notebook = sorted(n for n, c in cases.items()
                      if c["layer"] == "notebook" and n not in ROOT_ONLY)
    assert len(notebook) >= 15 and set(KERNEL_CASES) | set(SANDBOX_CASES) <= set(notebook)
    assert set(FLOW_CASES) <= set(cases)
    if not kit.full_corpus():
        notebook = sorted({*KERNEL_CASES, *SANDBOX_CASES})
    names = sorted(set(notebook) | set(FLOW_CASES))
    course = ta.course(ta.released, "course")
    # the victim is the reference's code: its full marks are the reference's (the full
    # corpus grades the reference too, with nbgrader's kernel)
    folders = _hand_in(ta, course, cases, names, ("victim", "reference") if kit.full_corpus()
                       else ("victim",))
    assert os.stat(course).st_uid == ta.user.pw_uid

    in_kernel = [*(["reference"] if kit.full_corpus() else []), *KERNEL_CASES]
    kernel = _students_file(ta, course, "kernel", in_kernel)
    rest = _students_file(ta, course, "rest", sorted(folders - set(in_kernel)))
    # the user's login session keeps a token in its session keyring (pam_keyinit)
    with kit.instructor_keyring(b"the user's login token"):
        first = ta.cobotlab("grade", course, ASSIGNMENT, "--workers", "2", "--no-progress",
                            "--nbgrader-kernel", "--students", kernel)
        second = ta.cobotlab("grade", course, ASSIGNMENT, "--workers", "2", "--no-progress",
                             "--students", rest)
    for done in (first, second):
        header = done.stdout.splitlines()[0]
        assert "sandbox: bubblewrap" in header and "rlimits only" not in header, header
        assert "WARNING" not in done.stderr, done.stderr[-2000:]
    # bubblewrap's user-namespace path: the sandbox runs as the user itself, not nobody
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert log.startswith("sandbox: bubblewrap"), log[:500]
    assert f"uid and interfaces '{ta.user.pw_uid} 1'" in log, log[:1000]
    # no template is built as the user (its forks could not make their namespaces)
    assert "no template, every submission started cold: the grader is not root" in log, \
        log[:3000]

    grades = _grades(course)
    assert len(grades) == len(folders), sorted(grades)
    assert all("sandbox:" not in r["flags"] for r in grades.values()), grades
    if kit.full_corpus():
        assert float(grades["reference"]["score"]) == 10.0, grades["reference"]
    assert float(grades["victim"]["score"]) == 10.0, grades["victim"]
    assert float(grades["blank"]["score"]) == 0.0, grades["blank"]
    for name in names:
        row = grades[name]
        case = cases[name]
        assert case["min"] - 1e-9 <= float(row["score"]) <= case["earned"] + 1e-9, (name, row)
        flags = row["flags"].split(";")
        for wanted in case["flags"]:
            assert any(f.startswith(wanted) for f in flags), (name, wanted, row["flags"])
    # nothing of the user's grading is owned by anyone else
    strangers = [str(p) for p in course.rglob("*") if p.lstat().st_uid != ta.user.pw_uid]
    assert not strangers, strangers[:10]
    graded = course / "autograded" / "import_solutions" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    if graded.exists():   # graded in the worker: nbgrader's notebook holds its cells' errors
        assert "solutions" in graded.read_text()


@pytest.mark.timeout(300)
def test_without_user_namespaces_the_fallback_is_announced_and_flagged(ta):
    course = ta.course(ta.released, "fallback")
    cases = kit.corpus(ASSIGNMENT)
    # no classmate attack here: the reference alone has full marks to keep
    _hand_in(ta, course, cases, ["geometry_invert"], ("reference",))
    done = ta.cobotlab("grade", course, ASSIGNMENT, "--workers", "2", userns=False)
    # said before any submission is graded (the progress bar comes after it), with why and
    # what to do about it
    warning = next((line for line in done.stderr.splitlines() if "WARNING" in line), "")
    assert warning, done.stderr[-2000:]
    assert done.stderr.index(warning) < done.stderr.index(f"grading {ASSIGNMENT}")
    assert "user namespaces" in warning and "sandbox:rlimits_only" in warning, warning
    assert "max_user_namespaces" in warning, warning
    assert "rlimits only" in done.stdout.splitlines()[0]
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert log.startswith("sandbox: rlimits only") and "ENOSPC" in log, log[:1000]

    grades = _grades(course)
    assert set(grades) == {"reference", "blank", "geometry_invert"}
    for row in grades.values():
        assert "sandbox:rlimits_only" in row["flags"].split(";"), row
    assert float(grades["reference"]["score"]) == 10.0
    assert float(grades["blank"]["score"]) == 0.0
    assert float(grades["geometry_invert"]["score"]) == 0.0
    assert "forbidden:robots.geometry.invert" in grades["geometry_invert"]["flags"]


# Run as the user, against its installed cobotlab: the keys of the user's own login
# session and user keyring. Not the template's forks: bubblewrap's --disable-userns leaves
# the user's template no user namespace to fork a sandbox into, so the user's grading starts
# every submission cold. tests/test_grading_contention.py is not repeated as the user: its
# cold worker runs without a cgroup as root too (the submission's CPU read from its
# processes, its wait for a CPU from their schedstat, as in the user's grading), and
# bubblewrap's user-namespace path, the one difference, is the corpus test's above.
AS_THE_USER = ("test_grading_keyrings.py",)
NOT_AS_THE_USER = "not template_fork"


@pytest.mark.timeout(300)
def test_keyrings_as_the_user(ta):
    """tests/test_grading_keyrings.py (cold worker and nbgrader's kernel jail: the user's
    own keys, in any session, unlisted), run by the user."""
    tests = ta.base / "tests"
    tests.mkdir(exist_ok=True)
    for name in (*AS_THE_USER, "course_kit.py", "conftest.py"):
        shutil.copy2(Path(__file__).with_name(name), tests / name)
    _give(tests, ta.user)
    done = ta.run(["python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k",
                   NOT_AS_THE_USER, *AS_THE_USER], cwd=tests)
    assert " passed" in done.stdout and "skipped" not in done.stdout, done.stdout[-3000:]


# A notebook that sleeps, in a kernel that outlives its parent (ipykernel's parent poller
# leaves with os._exit) and with a child in a session of its own: without a cgroup or a PID
# namespace, only a grader that stops every process below it ends them.
SLEEPER = """\
import os, time
os._exit = lambda *args: None
if os.fork() == 0:
    os.setsid()
    time.sleep(600)
time.sleep(600)
"""


@pytest.mark.timeout(300)
@pytest.mark.parametrize("option, runner", [(None, "autograder.inside.worker"),
                                            ("--nbgrader-kernel", "ipykernel")])
def test_ctrl_c_stops_every_process_in_the_fallback(ta, option, runner):
    """tests/test_grade_cli.py's Ctrl-C test, as the user and without user namespaces: no
    PID namespace and no cgroup to kill, nbgrader's kernel leads a session of its own, and
    the notebook's child another."""
    course = ta.course(ta.released, f"ctrl-c-{runner}")
    kit.submit(course, ASSIGNMENT, "sleeper", extra=SLEEPER)
    _give(course / "submitted", ta.user)
    argv = [ta.env_dir / "bin" / "cobotlab", "grade", course, ASSIGNMENT, "--no-progress",
            *([option] if option else [])]
    cli = subprocess.Popen(ta.argv(argv, userns=False), cwd=ta.work, env=ta.env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           preexec_fn=as_a_terminal_starts_it)
    seen: dict[int, str] = {}
    try:
        err = interrupt_once_running(cli, runner, seen)
        assert cli.returncode == 130, err[-2000:]
        assert "interrupted" in err and "WARNING" in err
        stop = time.monotonic() + 5
        while _still_running(seen) and time.monotonic() < stop:
            time.sleep(0.2)
        assert _still_running(seen) == []
        assert not (course / "grades.csv").exists()   # nothing half-recorded
    finally:
        for entry in _still_running(seen):   # never leave the user's processes behind
            try:
                os.kill(int(entry.split()[0]), signal.SIGKILL)
            except ProcessLookupError:
                pass
