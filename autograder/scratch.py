"""nbgrader's autograde for one student, in a throwaway course the student's code cannot leave.

nbgrader's kernel runs the student's notebook, so it gets what that run needs and nothing
else: a scratch course (its own config, the assignment's source read-only, a gradebook that
holds only the assignment's definition, the one frozen submission) inside the sandbox of
:mod:`autograder.sandbox`, with a temporary ``HOME``, a minimal environment, no network and
a wall-clock deadline. Afterwards the trusted process reads the scratch gradebook and keeps
only cell scores it can validate against the template it made itself (known cell, finite,
``0 <= score <= max``); names, penalties and anything else the run wrote are ignored.
"""

from __future__ import annotations

import math
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from autograder import sandbox
from autograder.freeze import Frozen, printable

__all__ = ["CellScore", "ScratchResult", "make_template", "autograde_one",
           "put_interpreter_on_path"]

_PKG = Path(__file__).resolve().parent
_ROOT = _PKG.parent
# What nbgrader's kernel may import: the lab packages and the checks its hidden tests call.
KERNEL_PACKAGES = ("robots", "sim_backends", "autograder")
KERNEL_HIDDEN = ("autograder/course.py", "autograder/grading.py", "autograder/scratch.py")
INSIDE = "/course"


@dataclass(frozen=True)
class CellScore:
    notebook: str
    cell: str
    score: float
    max_score: float


@dataclass
class ScratchResult:
    """What one scratch autograde produced, validated: cell scores and the graded notebooks."""

    cells: list[CellScore] = field(default_factory=list)
    notebooks: dict[str, bytes] = field(default_factory=dict)   # name -> autograded .ipynb
    notes: list[str] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    log: str = ""
    seconds: float = 0.0   # wall clock of the nbgrader run itself


def put_interpreter_on_path() -> None:
    """Put this interpreter's ``bin`` folder first on ``$PATH`` (once).

    nbgrader runs ``alembic`` from ``$PATH`` whenever it creates a gradebook, so
    ``.venv/bin/cobotlab`` or ``.venv/bin/nbgrader`` without an activated virtual
    environment would fail with ``FileNotFoundError: 'alembic'``.
    """
    bin_dir = os.path.dirname(sys.executable)
    path = os.environ.get("PATH", "")
    if bin_dir not in path.split(os.pathsep):
        os.environ["PATH"] = bin_dir + (os.pathsep + path if path else "")


def _env(home: str) -> dict[str, str]:
    bin_dir = os.path.dirname(sys.executable)  # nbgrader runs `alembic` from PATH
    return {"PATH": f"{bin_dir}:/usr/bin:/bin", "HOME": home, "LANG": "C.UTF-8",
            "MPLBACKEND": "Agg", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
            "PYTHONDONTWRITEBYTECODE": "1", "JUPYTER_PLATFORM_DIRS": "1"}


def make_template(root: Path, assignment: str, work: Path, duedate=None) -> Path:
    """A gradebook with only ``assignment``'s definition (cells, checksums, max scores).

    Runs ``nbgrader generate_assignment`` on a copy of the source in ``work`` (instructor
    material only: no student code runs here). Returns the gradebook's path.
    """
    if sandbox.stopping():
        raise sandbox.Interrupted("grading was interrupted")
    course = work / "template"
    (course / "source").mkdir(parents=True)
    shutil.copytree(root / "source" / assignment, course / "source" / assignment, symlinks=False,
                    ignore=shutil.ignore_patterns(".ipynb_checkpoints", "__pycache__"))
    shutil.copy2(root / "nbgrader_config.py", course / "nbgrader_config.py")
    home = work / "template-home"
    home.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "nbgrader", "generate_assignment", assignment, "--force",
         f"--CourseDirectory.root={course}"],
        cwd=course, env=_env(str(home)), capture_output=True, text=True, timeout=300,
        check=False)
    db = course / "gradebook.db"
    if done.returncode != 0 or not db.is_file():
        raise RuntimeError(f"nbgrader generate_assignment {assignment} failed on a copy of the "
                           f"source: {done.stdout[-800:]} {done.stderr[-800:]}")
    if duedate is not None:
        from nbgrader.api import Gradebook

        with Gradebook(f"sqlite:///{db}") as gb:
            gb.update_or_create_assignment(assignment, duedate=duedate)
    return db


def template_cells(template_db: Path, assignment: str) -> dict[tuple[str, str], float]:
    """{(notebook, grade cell): max score} of the assignment, from the trusted template."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{template_db}") as gb:
        return {(nb.name, cell.name): float(cell.max_score)
                for nb in gb.find_assignment(assignment).notebooks for cell in nb.grade_cells}


def _read_scores(db: Path, assignment: str, student: str,
                 known: dict[tuple[str, str], float]) -> tuple[list[CellScore], list[str]]:
    """Cell scores of ``student`` in a gradebook written next to student code: read-only,
    with plain SQL (no ORM, no triggers), and only values that pass validation."""
    notes: list[str] = []
    scores: dict[tuple[str, str], float] = {}
    uri = f"file:{db}?mode=ro&immutable=1"
    try:
        con = sqlite3.connect(uri, uri=True, timeout=2)
        try:
            con.execute("PRAGMA trusted_schema=OFF")
            rows = con.execute(
                "SELECT notebook.name, base_cell.name, grade.auto_score FROM grade "
                "JOIN submitted_notebook ON grade.notebook_id = submitted_notebook.id "
                "JOIN submitted_assignment ON submitted_notebook.assignment_id = "
                "submitted_assignment.id "
                "JOIN assignment ON submitted_assignment.assignment_id = assignment.id "
                "JOIN notebook ON submitted_notebook.notebook_id = notebook.id "
                "JOIN base_cell ON grade.cell_id = base_cell.id "
                "WHERE submitted_assignment.student_id = ? AND assignment.name = ? "
                "LIMIT 10000", (student, assignment)).fetchall()
        finally:
            con.close()
    except sqlite3.Error as exc:
        return [], [f"nbgrader's scratch gradebook is unreadable ({type(exc).__name__}): its "
                    "cell results are ignored"]
    for nb, cell, score in rows:
        key = (str(nb), str(cell))
        if key not in known:
            notes.append(f"nbgrader result for an unknown cell {printable(key, 80)} ignored")
            continue
        top = known[key]
        if isinstance(score, (int, float)) and math.isfinite(score) and 0 <= score <= top:
            # a row planted twice counts at its lowest
            scores[key] = min(float(score), scores.get(key, math.inf))
        elif score is not None:
            notes.append(f"nbgrader score {printable(score, 40)} for {key[1]} is outside 0..{top:g}:"
                         " ignored (scored 0)")
    return [CellScore(nb, cell, scores.get((nb, cell), 0.0), top)
            for (nb, cell), top in sorted(known.items())], notes


def autograde_one(frozen: Frozen, assignment: str, root: Path, template_db: Path,
                  known: dict[tuple[str, str], float], *, timeout_s: float = 300,
                  cell_timeout_s: int | None = None, memory_mb: int = 3072,
                  max_processes: int = 256, scratch_mb: int = 512,
                  notebook_mb: float = 20.0) -> ScratchResult:
    """Run ``nbgrader autograde`` on one frozen submission in a throwaway course.

    Never raises because of the submission: a hang past ``timeout_s`` kills every process of
    the run (cgroup, PID namespace); whatever it did, the result holds validated cell scores
    only (missing ones are 0) and the autograded notebooks if they are well-formed JSON.
    """
    if sandbox.stopping():
        raise sandbox.Interrupted("grading was interrupted")
    result = ScratchResult()
    caps = sandbox.capabilities()
    with sandbox.ScratchDir(scratch_mb) as scratch:
        course = scratch.path / "course"
        dest = course / "submitted" / frozen.student_id / assignment
        dest.parent.mkdir(parents=True)
        if frozen.folder is not None:
            shutil.copytree(frozen.folder, dest, symlinks=False)
        else:
            dest.mkdir()
        shutil.copy2(template_db, course / "gradebook.db")
        (course / "source" / assignment).mkdir(parents=True)  # the read-only bind's mount point
        shutil.copy2(root / "nbgrader_config.py", scratch.path / "nbgrader_config.py")
        (course / "nbgrader_config.py").touch()
        (scratch.path / "home").mkdir()
        scratch.give(scratch.path)
        if not scratch.size_limited:
            result.notes.append("nbgrader's scratch course is not size-limited here (not root)")

        nbgrader = [sys.executable, "-m", "nbgrader", "autograde", assignment, "--force",
                    "--student", frozen.student_id]
        if cell_timeout_s:
            nbgrader.append(f"--Execute.timeout={int(cell_timeout_s)}")
        cgroup = None
        if caps.bwrap:
            packages = tuple(str(_ROOT / p) for p in KERNEL_PACKAGES if (_ROOT / p).exists())
            jail = sandbox.Jail(
                ro=sandbox.python_paths() + packages,
                rw_at=((str(course), INSIDE), (str(scratch.path / "home"), "/home/student")),
                ro_at=((str(root / "source" / assignment), f"{INSIDE}/source/{assignment}"),
                       (str(scratch.path / "nbgrader_config.py"),
                        f"{INSIDE}/nbgrader_config.py")),
                hide=tuple(str(_ROOT / p) for p in KERNEL_HIDDEN),
                scratch_mb=64, chdir=INSIDE, env=_env("/home/student"))
            if caps.cgroup:
                cgroup = sandbox.Cgroup(memory_mb, max_processes)
            command = sandbox.command(nbgrader + [f"--CourseDirectory.root={INSIDE}"], jail,
                                      cgroup)
            env, cwd = {}, "/"
        else:  # rlimits only: the throwaway course still keeps the real one out of reach
            shutil.copytree(root / "source" / assignment, course / "source" / assignment,
                            dirs_exist_ok=True)
            shutil.copy2(root / "nbgrader_config.py", course / "nbgrader_config.py")
            command = nbgrader + [f"--CourseDirectory.root={course}"]
            env, cwd = _env(str(scratch.path / "home")), str(course)
            result.flags.append("sandbox:rlimits_only")
        started = time.monotonic()
        try:
            proc = subprocess.Popen(command, cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    start_new_session=True)
            try:
                out, _ = proc.communicate(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, 9)
                out, _ = proc.communicate()
                result.notes.append(f"nbgrader autograde was stopped after {timeout_s:g} s")
                result.flags.append("nbgrader_timed_out")
            result.log = printable((out or b"")[-4000:].decode("utf-8", "replace"), 4000)
        finally:
            if cgroup is not None:
                if cgroup.oom_kills():
                    result.notes.append("nbgrader's run hit its memory limit "
                                        f"({memory_mb} MB for all its processes)")
                cgroup.remove()
        result.seconds = time.monotonic() - started
        result.notes.append(f"nbgrader autograde: {result.seconds:.1f} s")
        if sandbox.stopping():   # killed by stop_all(): what it left is not a result
            raise sandbox.Interrupted("grading was interrupted")
        db = course / "gradebook.db"
        info = os.lstat(db) if os.path.lexists(db) else None
        if info is None or not os.path.isfile(db) or os.path.islink(db):
            result.notes.append("nbgrader's scratch gradebook is gone: its cell results are 0")
            result.cells = [CellScore(nb, c, 0.0, m) for (nb, c), m in sorted(known.items())]
        else:
            private = scratch.path.parent / (scratch.path.name + ".db")
            shutil.copyfile(db, private, follow_symlinks=False)
            try:
                result.cells, notes = _read_scores(private, assignment, frozen.student_id, known)
            finally:
                private.unlink()
            result.notes += notes
        graded = course / "autograded" / frozen.student_id / assignment
        for name in sorted({nb for nb, _ in known}):
            path = graded / f"{name}.ipynb"
            data = _regular_bytes(path, int(notebook_mb * 2**20))
            if data is not None:
                result.notebooks[name] = data
    return result


def _regular_bytes(path: Path, cap: int) -> bytes | None:
    """The bytes of a regular JSON file at ``path`` (no link followed), or None."""
    import json

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        import stat

        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            return None
        data = f.read(cap + 1)
    if len(data) > cap:
        return None
    try:
        json.loads(data)
    except ValueError:
        return None
    return data
