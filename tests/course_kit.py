"""Helpers for tests that run the real nbgrader cycle on a lab (any assignment).

generate_assignment -> submissions made from the released notebook -> nbgrader autograde ->
autograder.course.grade_course. Each lab's test file uses these with its own assignment name.
"""

from __future__ import annotations

import atexit
import contextlib
import copy
import csv
import fcntl
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import nbformat
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient

from autograder import registry
from autograder.course import LABS_DIR, init_course, run_nbgrader_autograde
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.worker import Limits
from autograder.secret import PRIVATE_DIR, SECRET_ENV, load_secret


def cmdline(pid: int) -> str:
    """``pid``'s command line, its arguments joined by spaces ("" once it has ended)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def source_notebook(assignment: str) -> Path:
    """The source notebook of a built-in lab, or of the current course's own lab."""
    lab = registry.find_lab(assignment)
    return lab.notebook if lab.notebook is not None else \
        LABS_DIR / assignment / f"{assignment}.ipynb"


def nbgrader(course: Path, *args: str, home: Path | None = None) -> subprocess.CompletedProcess:
    """Run nbgrader in ``course`` without the grading secret in its environment (and with
    ``home`` as HOME: a student's own ~/.jupyter config and nbgrader cache)."""
    env = {k: v for k, v in os.environ.items() if k != SECRET_ENV}
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    if home is not None:   # Jupyter's config and data folders follow HOME, as on a hub
        env = {k: v for k, v in env.items() if not k.startswith("JUPYTER")}
        env["HOME"] = str(home)
    done = subprocess.run([sys.executable, "-m", "nbgrader", *args], cwd=course, env=env,
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    return done


# Where built_once() keeps what it builds: set by tests/conftest.py to a folder of the test
# run that every xdist worker shares; otherwise (this module used on its own) one of this
# process's, removed when it exits.
BUILT_ONCE_DIR: Path | None = None


def built_once(name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``build(folder)`` filled, built once per test run however many tests and
    workers ask for it (the first builds it, the others wait for it under a file lock). What
    it holds is shared: callers copy it, never change it. A build that raises leaves nothing
    behind, and the next caller tries again."""
    global BUILT_ONCE_DIR
    if BUILT_ONCE_DIR is None:
        BUILT_ONCE_DIR = Path(tempfile.mkdtemp(prefix="cobotlab-built-once-"))
        atexit.register(shutil.rmtree, BUILT_ONCE_DIR, True)
    BUILT_ONCE_DIR.mkdir(parents=True, exist_ok=True)
    folder = BUILT_ONCE_DIR / name
    built = BUILT_ONCE_DIR / f"{name}.built"   # written last: the build finished
    with open(BUILT_ONCE_DIR / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # released when the file closes
        if not built.exists():
            # built in place (what it writes may name its own path, as nbgrader_config.py)
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            try:
                build(folder)
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
            built.touch()
    return folder


def initialized_master() -> Path:
    """The course `init_course` laid out once in this test run (built_once; its practice
    files alone cost about 8 s of CPU): shared, to read or copy, never to change."""
    return built_once("initialized", lambda folder: init_course(folder / "course")) / "course"


def initialized_course(root: Path) -> Path:
    """A new course under ``root`` (``root/course``) as `init_course` lays it out: a copy of
    :func:`initialized_master`. Like init_course, it makes the course the one this process
    loads labs from."""
    course = fresh_course(initialized_master(), root)
    registry.use_course(course)
    return course


def _release(folder: Path, assignment: str) -> None:
    course = initialized_course(folder)
    nbgrader(course, "generate_assignment", assignment)


def released_course(root: Path, assignment: str) -> Path:
    """A new course under ``root`` (``root/course``) with ``assignment`` generated
    (released): a copy of the course that nbgrader's ``generate_assignment`` made once in
    this test run (built_once) from a copy of :func:`initialized_course`, so that the dozen
    test files grading lab 0 pay for one release, not one each. Like init_course, it makes
    the course the one this process loads labs from."""
    master = built_once(f"released-{assignment}",
                        lambda folder: _release(folder, assignment)) / "course"
    course = fresh_course(master, root)
    registry.use_course(course)
    return course


def fresh_course(released: Path, tmp_path: Path) -> Path:
    """A copy of a released course, so each test grades its own submissions."""
    course = tmp_path / "course"
    shutil.copytree(released, course)
    config = course / "nbgrader_config.py"
    config.write_text(config.read_text().replace(str(released), str(course)))
    return course


def solution_sources(assignment: str, functions) -> dict[str, str]:
    """The reference solution cell of each graded function, solution markers removed."""
    nb = json.loads(source_notebook(assignment).read_text())
    out = {}
    for cell in nb["cells"]:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if gid in functions:
            out[gid] = "".join(cell["source"]).replace("    ### BEGIN SOLUTION\n", "").replace(
                "\n    ### END SOLUTION", "")
    return out


def submit(course: Path, assignment: str, student: str, replace: dict[str, str] | None = None,
           extra: str | None = None, mangle: bool = False) -> None:
    """Write submitted/<student>/<assignment>/ from the released notebook with edits.

    ``replace`` maps grade ids to new cell sources; ``extra`` is a code cell inserted after
    the cell with grade id "imports"; ``mangle`` deletes test cells, duplicates and retypes
    solution cells (stripping their nbgrader metadata) and reverses the cell order.
    """
    nb = json.loads((course / "release" / assignment / f"{assignment}.ipynb").read_text())
    cells = nb["cells"]
    for cell in cells:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if replace and gid in replace:
            cell["source"] = replace[gid]
    if extra is not None:
        at = next(i for i, c in enumerate(cells)
                  if c["metadata"].get("nbgrader", {}).get("grade_id") == "imports") + 1
        cells.insert(at, {"cell_type": "code", "metadata": {}, "execution_count": None,
                          "outputs": [], "source": extra})
    if mangle:
        kept = []
        for cell in cells:
            meta = cell["metadata"].get("nbgrader", {})
            if meta.get("grade"):
                continue  # test cells deleted
            if meta.get("solution"):
                twin = copy.deepcopy(cell)
                twin["metadata"]["nbgrader"]["grade_id"] = "retyped_" + meta["grade_id"]
                kept.append(twin)
                cell = dict(cell, metadata={})  # nbgrader metadata stripped
            kept.append(cell)
        kept.reverse()  # reordered: the graded functions are found by name, not position
        nb["cells"] = kept
    out = course / "submitted" / student / assignment
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{assignment}.ipynb").write_text(json.dumps(nb))
    (out / "timestamp.txt").write_text("2026-11-20 10:00:00.000000 UTC")


def read_grades(course: Path) -> dict[str, dict]:
    with open(course / "grades.csv") as f:
        return {row["student_id"]: row for row in csv.DictReader(f)}


def execute_source(assignment: str, timeout_s: int = 180) -> nbformat.NotebookNode:
    """Run the source notebook (with solutions and hidden tests) top to bottom; fail on any
    error output or saved output."""
    path = source_notebook(assignment)
    nb = nbformat.read(path, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), \
        "the source notebook must be saved without outputs"
    with tempfile.TemporaryDirectory(prefix="cobotlab-kernel-") as sockets:
        # IPC sockets, not TCP ports: a port the kernel manager picked free can be taken by
        # another test's server before the kernel binds it ("Address already in use")
        km = KernelManager(kernel_name="python3", transport="ipc",
                           ip=str(Path(sockets) / "kernel"))
        try:
            NotebookClient(nb, km=km, timeout=timeout_s, kernel_name="python3",
                           resources={"metadata": {"path": str(path.parent)}}).execute()
        finally:
            # a client given its kernel manager leaves the kernel running: left, it outlived
            # the test with its sockets gone and spent a tenth of a core until the suite ended
            if km.has_kernel:
                km.shutdown_kernel(now=True)
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors, errors
    return nb


RELEASE_MARKERS = ("BEGIN SOLUTION", "END SOLUTION", "BEGIN HIDDEN", "hidden_test",
                   "from solutions", "import solutions")


def assert_release_clean(course: Path, assignment: str, n_functions: int,
                         solution_lines=()) -> None:
    """The released notebook holds no solution region, hidden test, reference import, none of
    ``solution_lines`` (lines only a solution would contain) and one stub per graded
    function; no released file holds the secret or the private folder."""
    text = (course / "release" / assignment / f"{assignment}.ipynb").read_text()
    secret = load_secret(course)
    for needle in (*RELEASE_MARKERS, *solution_lines, secret):
        assert needle not in text, needle
    assert text.count("raise NotImplementedError()") == n_functions
    released_files = [p for p in (course / "release").rglob("*") if p.is_file()]
    for path in released_files:
        assert secret not in path.read_text(errors="ignore"), path
    assert not any(PRIVATE_DIR in p.parts for p in released_files)


def output_text(nb, sep: str = "") -> str:
    """All text the code cells of an executed notebook printed or displayed (check()'s report
    is a display with a plain-text form)."""
    return sep.join(_text_of(o) for c in nb.cells if c.cell_type == "code" for o in c.outputs)


def _text_of(output) -> str:
    text = output.get("text", "")
    data = output.get("data", {})
    return text + (data.get("text/plain", "") if isinstance(data, dict) else "")


# The adversarial corpus: one student submission per item of the threat model (README there).
ADVERSARIAL = Path(__file__).parent / "adversarial"


def parse_case(path: Path) -> dict:
    """A corpus case: earned/min score, expected flags, replaced cells, extra cell, mangle."""
    text = path.read_text()
    header, _, body = text.partition('"""\n#')
    case = {"earned": None, "min": 0.0, "flags": [], "replace": {}, "extra": None,
            "mangle": False, "lab": "lab0_frames", "layer": "notebook", "layout": None,
            "student": None}
    for line in header.splitlines():
        key, _, value = line.partition(":")
        if key in ("earned", "min"):
            case[key] = float(value)
        elif key == "flags":
            case["flags"] = [v.strip() for v in value.split(",") if v.strip()]
        elif key in ("lab", "layer", "layout"):
            case[key] = value.strip()
        elif key == "student":  # escapes (\n, \x1b) spell characters a folder name can hold
            case["student"] = value.strip().encode().decode("unicode_escape")
    chunks = ("#" + body).split("# %% ")[1:]
    for chunk in chunks:
        directive, _, code = chunk.partition("\n")
        words = directive.split()
        if words[0] == "extra":
            case["extra"] = code
        elif words[0] == "replace":
            case["replace"][words[1]] = code
        elif words[0] == "mangle":
            case["mangle"] = True
    assert case["earned"] is not None, f"{path.name} has no 'earned:' line"
    return case


def submit_case(course: Path, assignment: str, name: str, case: dict) -> str:
    """Hand in corpus case ``name`` (its cells and its ``layout:``); returns its folder name.

    Layouts: ``symlink_notebook_to_source``, ``symlink_folder_to_victim`` (a student named
    ``victim`` must be submitted too), ``fifo_notebook``. ``@COURSE@`` in the case's code
    becomes the course's path on the host (what an attack would have to guess).
    """
    student = case["student"] or name
    here = str(course.resolve())
    case = dict(case, extra=case["extra"] and case["extra"].replace("@COURSE@", here),
                replace={k: v.replace("@COURSE@", here) for k, v in case["replace"].items()})
    folder = course / "submitted" / student / assignment
    layout = case["layout"]
    if layout == "symlink_folder_to_victim":
        folder.parent.mkdir(parents=True, exist_ok=True)
        folder.symlink_to(course / "submitted" / "victim" / assignment, target_is_directory=True)
        return student
    submit(course, assignment, student, replace=case["replace"], extra=case["extra"],
           mangle=case["mangle"])
    notebook = folder / f"{assignment}.ipynb"
    if layout == "symlink_notebook_to_source":
        notebook.unlink()
        notebook.symlink_to(course / "source" / assignment / f"{assignment}.ipynb")
    elif layout == "fifo_notebook":
        notebook.unlink()
        os.mkfifo(notebook)
    elif layout is not None:
        raise ValueError(f"{name}: unknown layout {layout!r}")
    return student


def corpus(lab: str = "lab0_frames") -> dict[str, dict]:
    """The adversarial cases written for ``lab``, by name."""
    cases = {p.stem: parse_case(p) for p in sorted(ADVERSARIAL.glob("*.py"))
             if not p.name.startswith("test_")}   # a test file there is no case
    return {name: case for name, case in cases.items() if case["lab"] == lab}


def serve_localhost(port: int, reply: bytes, stop) -> bool:
    """Answer every connection to 127.0.0.1:``port`` with ``reply`` until ``stop`` (a
    threading.Event) is set, in a daemon thread: an instructor's local service for attacks
    to find. False when the port is taken."""
    import socket
    import threading

    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        server.bind(("127.0.0.1", port))
    except OSError:
        server.close()
        return False
    server.listen()
    server.settimeout(0.2)

    def serve():
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            conn.sendall(reply)
            conn.close()
        server.close()

    threading.Thread(target=serve, daemon=True).start()
    return True


@contextlib.contextmanager
def instructor_keyring(session_token: bytes, user_token: bytes | None = None):
    """This thread (and what it starts from now on) as an instructor's SSH login: a new
    session keyring holding ``session_token`` (as pam_keyinit's holds a login's tokens) and,
    when given, ``user_token`` in its user keyring; both removed afterwards. Keys named
    ``cobotlab-instructor-token`` and ``cobotlab-instructor-user-token``."""
    import ctypes
    import platform

    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    add_key, keyctl = {"x86_64": (248, 250), "aarch64": (217, 219)}[platform.machine()]

    def call(*args) -> int:
        result = libc.syscall(*args)
        if result < 0:
            raise OSError(ctypes.get_errno(), "keyring call")
        return result

    call(keyctl, 1, None)   # KEYCTL_JOIN_SESSION_KEYRING, anonymous: this thread's own
    planted = [(call(add_key, b"user", b"cobotlab-instructor-token", session_token,
                     len(session_token), -3), -3)]
    if user_token is not None:
        planted.append((call(add_key, b"user", b"cobotlab-instructor-user-token", user_token,
                             len(user_token), -4), -4))
    try:
        yield
    finally:
        for key, ring in planted:
            try:
                call(keyctl, 9, key, ring)   # KEYCTL_UNLINK
            except OSError:
                pass


# nbgrader's own (trusting) autograde runs, for the cross-check, on the cases built to fool it
# and on the one built to wedge it; the other cases go through the independent grader only.
FOOL_NBGRADER = ("sys_modules", "numpy_patch", "kernel_patch")
WEDGE_NBGRADER = ("forge_protocol",)


def full_corpus() -> bool:
    """True when COBOTLAB_FULL_CORPUS=1 (benchmarks/adversarial_corpus.py sets it): the
    corpus is graded in full in every mode the suite repeats it in (each lab 0 case also
    started cold, as the unprivileged user, and on labs 3-5). A suite run grades every case
    once on lab 0 and repeats the slices below, the cases each repetition can tell apart."""
    return os.environ.get("COBOTLAB_FULL_CORPUS") == "1"


# The cases whose grade a template's forks could change, graded cold too in a suite run:
# they patch what the forks share with the template (sys.modules, numpy, the kernel, the
# exception hook, the frames on the stack), start threads, fill memory whose pages a fork
# shares, forge replies on the pipe the template opened, or hunt for secrets in what the
# forks inherit. The others never meet the template's state.
REGRADED_COLD = ("exception_handler", "forbidden_thread", "forge_protocol", "kernel_patch",
                 "memory_bomb", "numpy_patch", "secret_hunt", "stack_peek", "sys_modules")
# The cases that only burn their CPU limits: every cell and call loops until a limit stops
# it. Graded in a run of their own with SHORT_LIMITS, forked from the template only, even in
# the full corpus: a pass cost 25 s of CPU at the batch's 5 s / 3 s limits, all of it loops
# being stopped. What is tested is that each loop is stopped and charged to the student
# whatever the limit (the same bounds and flags), not the clock. A cold worker's time-outs
# are tested on their own (tests/test_grading_contention.py, both ways).
BURNS_ITS_LIMITS = ("infinite_loop",)
# tests/test_adversarial_labs.py's limits, which grade every case on labs 3-5 in the full
# corpus (benchmarks/adversarial_corpus.py)
SHORT_LIMITS = Limits(cell_timeout_s=2, call_timeout_s=1, load_timeout_s=60, wall_factor=2)


def corpus_batch_parts() -> tuple[list[str], list[str]]:
    """The lab 0 notebook-layer corpus in two parts, graded by two test files in parallel:
    the cases nbgrader's kernel runs too (FOOL_NBGRADER, WEDGE_NBGRADER: its runs cost about
    as much as grading all the others), and the rest."""
    names = sorted(n for n, c in corpus("lab0_frames").items() if c["layer"] == "notebook")
    kernel = [n for n in names if n in FOOL_NBGRADER + WEDGE_NBGRADER]
    return kernel, [n for n in names if n not in kernel]


def log_lines(course: Path, student: str) -> list[str]:
    """What the last grade run's log says of ``student`` (for a failing test's message)."""
    log = course / ".cobotlab" / "last_run.log"
    text = log.read_text() if log.exists() else ""
    return [line[:2000] for line in text.splitlines() if student in line]


def _keep_only(course: Path, students) -> Path:
    """``course`` with every submission but those of ``students`` removed."""
    for folder in (course / "submitted").iterdir():
        if folder.name not in students:
            shutil.rmtree(folder)
    return course


def grade_corpus_batch(released: Path, tmp_path: Path, names: list[str],
                       reference_cold: bool = True) -> None:
    """Submit the named lab 0 corpus cases and the reference, grade them in one batch, and
    check every case's score bounds and flags (see tests/adversarial/README.md).
    ``reference_cold``: the reference is graded cold too (one batch is enough: it meets
    nothing a batch's cases change; the full corpus grades it cold in both)."""
    lab = "lab0_frames"
    course = fresh_course(released, tmp_path)
    cases = {n: c for n, c in corpus(lab).items() if n in names}
    assert sorted(cases) == sorted(names), "unknown or non-notebook cases"
    assert set(REGRADED_COLD) <= set(corpus(lab)), "a renamed case: update REGRADED_COLD"
    for name, case in cases.items():
        submit(course, lab, name, replace=case["replace"], extra=case["extra"],
               mangle=case["mangle"])
    submit(course, lab, "reference",
           replace=solution_sources(lab, ("invert_pose", "compose_chain", "pose_from_rotvec")))
    fools = [n for n in names if n in FOOL_NBGRADER]
    if fools:
        # nbgrader's cell timeout is wall clock: the cases that fool it get its configured
        # 30 s (with 4 s, a run at load 6 lost kernel_patch's cross-check flag once). The
        # reference is not run in nbgrader's kernel here: that an honest notebook with
        # nbgrader's own results in the gradebook gets no flag is
        # tests/test_grading_record.py's (its `ref`), and a kernel run cost 5 s of CPU.
        run_nbgrader_autograde(course, lab, fools, timeout_s=300)
    wedges = [n for n in names if n in WEDGE_NBGRADER]
    if wedges:   # 4 s a cell and 60 s in all: the wedged run is killed, the grade must hold
        run_nbgrader_autograde(course, lab, wedges, timeout_s=60, cell_timeout_s=4)
    # sleepers are cut at 2x their limit: the attack is tested here, not the clock
    limits = Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=60,
                            wall_factor=2)
    # The cases that only burn their limits, in a course of their own (BURNS_ITS_LIMITS)
    burning = [n for n in cases if n in BURNS_ITS_LIMITS]
    burn = _keep_only(fresh_course(course, tmp_path / "burn"), burning) if burning else None
    for name in burning:
        shutil.rmtree(course / "submitted" / name)
    # Graded twice: each worker forked from a template (the default) and each a new
    # interpreter; the template must change no score and no flag. Twice: the reference (in
    # one batch) and the cases the template could change (REGRADED_COLD; all with
    # full_corpus()).
    twice = [n for n in cases if full_corpus() or n in REGRADED_COLD]
    if reference_cold or full_corpus():
        twice.append("reference")
    cold = _keep_only(fresh_course(course, tmp_path / "cold"), twice)
    rows = grade_course(course, lab, workers=2, limits=limits, quiet=True)
    if burn is not None:
        rows += grade_course(burn, lab, workers=2, limits=SHORT_LIMITS, quiet=True)
    cold_rows = grade_course(cold, lab, workers=2, limits=limits, quiet=True, template=False)
    assert "template: the interpreter" in (course / ".cobotlab" / "last_run.log").read_text()
    started_cold = {r["student_id"]: (r["score"], r["flags"]) for r in cold_rows}
    assert sorted(started_cold) == sorted(twice) and len(twice) > 1, sorted(started_cold)
    forked = {r["student_id"]: (r["score"], r["flags"]) for r in rows
              if (cold / "submitted" / r["student_id"]).is_dir()}
    differ = {k for k in set(forked) | set(started_cold) if forked.get(k) != started_cold.get(k)}
    assert not differ, [(k, forked.get(k), started_cold.get(k), log_lines(course, k),
                         log_lines(cold, k)) for k in sorted(differ)]
    grades = {r["student_id"]: r for r in rows}
    assert set(grades) == set(cases) | {"reference"}, "every submission gets a row"
    # without a kernel run nbgrader has no result for the reference, and says so
    assert grades["reference"]["score"] == 10.0
    assert grades["reference"]["flags"] == "nbgrader_no_result"
    for name, case in cases.items():
        row = grades[name]
        assert row["score"] <= case["earned"] + 1e-9, (name, row)
        assert row["score"] >= case["min"] - 1e-9, (name, row)
        flags = row["flags"].split(";")
        for wanted in case["flags"]:
            assert any(f.startswith(wanted) for f in flags), (name, wanted, row["flags"])
    secret = load_secret(course)
    for graded in filter(None, (course, burn)):
        for path in [graded / "grades.csv", *(graded / "feedback_cobotlab").rglob("*.html"),
                     *(graded / "feedback_cobotlab").rglob("*.json")]:   # nbgrader's section
            assert secret not in path.read_text(), path


def page_attack(where: str, base: tuple[str, ...] = (), log: bool = True) -> str:
    """JavaScript that, run in a page of a Jupyter server's origin, writes ``PWNED-<where>``
    into the server's root through its contents API (under the URL path ``base``: on a hub,
    ``("services", "cobotlab")``), with the ``_xsrf`` cookie of the page, and (``log``) logs
    ``ran:<where>``: what a student's script in a grader's page would do (issue 51). No
    ``/``, ``\\`` or ``"``: it fits in a double-quoted attribute."""
    path = "+".join(f"p+'{part}'" for part in (*base, "api", "contents", f"PWNED-{where}"))
    return ("p=String.fromCharCode(47);"
            f"fetch({path},{{method:'PUT',"
            "headers:{'X-XSRFToken':document.cookie.split('_xsrf=')[1].split(';')[0]},"
            "body:JSON.stringify({type:'file',format:'text',content:''})})"
            + (f";console.log('ran:{where}')" if log else ""))
