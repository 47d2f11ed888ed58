"""`cobotlab grade` as an instructor runs it: Ctrl-C, progress, a shard of the class.

The Ctrl-C test is the real thing: the CLI in its own process, nbgrader's autograde of a
notebook whose cell sleeps (so its kernel is busy inside bubblewrap), SIGINT sent to the CLI
alone as a terminal would, and then no process the CLI started may be left.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import course_kit as kit
import pytest

from autograder import checks, executions, gradebook, record, sandbox
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import draw_problems
from autograder.pipeline.record import GRADE_COLUMNS, GRADES_CSV, grade_row
from autograder.pipeline.rescore import kept_path
from autograder.pipeline.score import score_execution
from autograder.secret import SECRET_ENV, load_secret
from autograder.shards import merge_shard, write_job
from cobotlab.cli import _student_ids

pytestmark = pytest.mark.slow
ASSIGNMENT = "lab0_frames"
REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("released"), ASSIGNMENT)


def _stat(pid: int) -> tuple[int, str, str] | None:
    """(parent pid, state, start time) of a live process, or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except OSError:
        return None
    return int(fields[1]), fields[0].decode(), fields[19].decode()


def _descendants(root: int) -> dict[int, str]:
    """{pid: start time} of every process below ``root``."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (info := _stat(int(entry))) is not None:
            parents[int(entry)] = info
    found, frontier = {}, [root]
    while frontier:
        parent = frontier.pop()
        for pid, (ppid, _, start) in parents.items():
            if ppid == parent and pid not in found:
                found[pid] = start
                frontier.append(pid)
    return found


def _still_running(seen: dict[int, str]) -> list[str]:
    left = []
    for pid, start in seen.items():
        info = _stat(pid)
        if info is not None and info[2] == start and info[1] != "Z":
            left.append(f"{pid} {kit.cmdline(pid)[:120]}")
    return left


def as_a_terminal_starts_it() -> None:
    """``preexec_fn`` for a command a test will interrupt: SIGINT at its default action, as
    for a terminal's foreground job. A shell without job control starts its background jobs
    with SIGINT ignored, which every child inherits and Python then keeps (no
    KeyboardInterrupt): a suite started that way would see the CLI ignore its Ctrl-C."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt_once_running(cli: subprocess.Popen, runner: str, seen: dict[int, str]) -> str:
    """Wait until a process named ``runner`` runs below the grading CLI (the notebook is
    then inside its sleep), send the CLI alone SIGINT, as a terminal's Ctrl-C reaches it,
    and wait for it to exit; returns its stderr. ``seen`` gets every process seen below it.
    The CLI is killed if it outlives this."""
    try:
        deadline = time.monotonic() + 180
        sleeper = None
        while sleeper is None and time.monotonic() < deadline and cli.poll() is None:
            seen.update(_descendants(cli.pid))
            sleeper = next((p for p in seen if runner in kit.cmdline(p)), None)
            time.sleep(0.3)
        assert sleeper is not None, (f"{runner} never started",
                                     cli.poll(), cli.stderr.read() if cli.poll() else "")
        time.sleep(2.0)   # the notebook is now inside time.sleep(600)
        seen.update(_descendants(cli.pid))
        assert _still_running(seen), "nothing to interrupt"
        cli.send_signal(signal.SIGINT)
        _, err = cli.communicate(timeout=20)
    finally:
        if cli.poll() is None:
            cli.kill()
            cli.communicate()
    return err.decode()


@pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="needs bubblewrap")
@pytest.mark.timeout(300)
# By default the grader's worker runs the notebook for nbgrader too; --nbgrader-kernel runs
# nbgrader's own kernel first (as for an assignment of several notebooks).
@pytest.mark.parametrize("option, runner", [(None, "autograder.inside.worker"),
                                            ("--nbgrader-kernel", "ipykernel")])
def test_ctrl_c_stops_nbgrader_its_kernel_and_every_sandbox(released, tmp_path, option, runner):
    course = kit.fresh_course(released, tmp_path)
    kit.submit(course, ASSIGNMENT, "sleeper", extra="import time\ntime.sleep(600)")
    env = {k: v for k, v in os.environ.items() if k != "COBOTLAB_GRADING_SECRET"}
    cli = subprocess.Popen([sys.executable, "-m", "cobotlab.cli", "grade", str(course),
                            ASSIGNMENT, "--no-progress", *([option] if option else [])],
                           cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           preexec_fn=as_a_terminal_starts_it)
    seen: dict[int, str] = {}
    err = interrupt_once_running(cli, runner, seen)
    assert cli.returncode == 130, err[-2000:]
    assert "interrupted" in err
    stop = time.monotonic() + 5
    while _still_running(seen) and time.monotonic() < stop:
        time.sleep(0.2)
    assert _still_running(seen) == []
    assert gradebook.problem(course / "gradebook.db") is None
    assert not (course / "grades.csv").exists()   # nothing half-recorded
    assert not sandbox.stopping()


def _submit_class(course: Path) -> None:
    # ada writes every function, cy one of them, bo nothing: three different scores.
    solutions = kit.solution_sources(ASSIGNMENT, [s.name for s in checks.SPECS[ASSIGNMENT]])
    kit.submit(course, ASSIGNMENT, "ada", replace=solutions)
    kit.submit(course, ASSIGNMENT, "bo")
    kit.submit(course, ASSIGNMENT, "cy", replace={"invert_pose": solutions["invert_pose"]})


def _kept(course: Path, sid: str) -> Path:
    return course / ".cobotlab" / kept_path(ASSIGNMENT, sid)


def _forge(job: Path, sid: str, edit) -> None:
    """Edit the execution the job returns for ``sid`` as a job node an escaped sandbox
    controls could: ``edit(kept)`` changes the decoded JSON in place."""
    kept = json.loads(_kept(job, sid).read_text())
    edit(kept)
    _kept(job, sid).write_text(json.dumps(kept))


def _outcomes(kept: dict, name: str) -> list[dict]:
    return next(f for f in kept["execution"]["functions"] if f["name"] == name)["outcomes"]


def test_a_shard_job_executes_without_the_secret_and_home_scores_it(released, tmp_path,
                                                                   monkeypatch):
    monkeypatch.delenv(SECRET_ENV, raising=False)
    home = kit.fresh_course(released, tmp_path / "home")
    job = kit.fresh_course(released, tmp_path / "job")  # a cluster job's copy of the course
    for course in (home, job):
        _submit_class(course)
    # as `nbgrader submit` leaves it: release_feedback at home needs it beside ada's notebook
    (home / "submitted" / "ada" / ASSIGNMENT / "submission_secret.txt").write_text("ab" * 64)
    with pytest.raises(ValueError, match="holds the grading secret"):
        write_job(home, ASSIGNMENT, job, ["ada", "cy"])
    (job / ".cobotlab" / "secret").unlink()
    # the step docs/instructors.md gives, as a command
    written = subprocess.run([sys.executable, "-m", "cobotlab.cli", "shard", str(home),
                              ASSIGNMENT, str(job), "ada", "cy"], cwd=REPO, capture_output=True,
                             text=True, timeout=120, check=False)
    assert written.returncode == 0 and "of 2 student(s) written" in written.stdout, written
    bundle = "".join(p.read_text() for p in (job / ".cobotlab" / "job").rglob("*.json"))
    assert load_secret(home) not in bundle and '"tol"' not in bundle

    monkeypatch.setenv(SECRET_ENV, load_secret(home))
    with pytest.raises(ValueError, match="needs none and must not hold one"):
        grade_course(job, ASSIGNMENT, quiet=True, students=["ada"])
    monkeypatch.delenv(SECRET_ENV)
    with pytest.raises(ValueError, match="holds no problems of .* for bo"):
        grade_course(job, ASSIGNMENT, quiet=True, students=["ada", "bo"])
    calls = []
    failed = grade_course(job, ASSIGNMENT, workers=2, quiet=True, students=["cy", "ada"],
                          run_nbgrader=True,  # as the CLI does: autograded notebooks too
                          progress=lambda done, total, sid: calls.append((done, total, sid)))
    assert failed == [] and calls[0] == (0, 2, "") and len(calls) == 3
    assert _kept(job, "ada").is_file() and _kept(job, "cy").is_file()
    assert not (job / "grades.csv").exists()   # the job scores nothing

    # A forged grades.csv, feedback page and gradebook score in the job's copy are never read.
    points = {s.name: s.points for s in checks.SPECS[ASSIGNMENT]}
    record.write_csv(job, GRADES_CSV, GRADE_COLUMNS,
                     [grade_row(ASSIGNMENT, sid, {}, 99.0, 99.0, "") for sid in ("ada", "cy")])
    gradebook.write_cobotlab(job, ASSIGNMENT, "cy", "", {f"test_{name}": 1.0 for name in points},
                             {})   # every cell of cy's full marks in the job's gradebook
    assert gradebook.net_scores(job, ASSIGNMENT)["cy"] == sum(points.values())
    forged_page = job / "feedback_cobotlab" / "cy" / ASSIGNMENT / "feedback.html"
    forged_page.parent.mkdir(parents=True)
    forged_page.write_text("forged")
    merged = merge_shard(home, ASSIGNMENT, job, quiet=True)
    scores = {r["student_id"]: float(r["raw_score"]) for r in merged}
    assert scores == {"ada": sum(points.values()), "cy": points["invert_pose"]}
    assert {s: float(r["score"]) for s, r in kit.read_grades(home).items()} == scores
    assert gradebook.net_scores(home, ASSIGNMENT) == scores
    cells = _gradebook_cells(home, ["ada", "cy"])
    assert all(cells.values())
    for sid in ("ada", "cy"):
        page = home / "feedback_cobotlab" / sid / ASSIGNMENT / "feedback.html"
        assert "forged" not in page.read_text() and "points" in page.read_text()
        notebook = home / "autograded" / sid / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
        assert notebook.read_bytes() == (job / notebook.relative_to(home)).read_bytes()
    secret = home / "autograded" / "ada" / ASSIGNMENT / "submission_secret.txt"
    assert secret.read_text() == "ab" * 64   # from HOME's submission, not the job's
    assert gradebook.problem(home / "gradebook.db") is None
    assert not (home / ".cobotlab" / record.RUN_MARKER).exists()
    # what home kept is rescored again at home, with no student code run
    assert {r["student_id"]: float(r["raw_score"]) for r in grade_course(
        home, ASSIGNMENT, quiet=True, students=["ada", "cy"], rescore=True)} == scores

    # Returned values earn what they earn against the truth drawn at home: ada's answers
    # (to ada's problems) pasted into cy's execution raise cy's grade by nothing.
    ada = json.loads(_kept(job, "ada").read_text())
    _forge(job, "cy", lambda kept: kept["execution"].update(functions=[
        f if f["name"] == "invert_pose" else next(
            a for a in ada["execution"]["functions"] if a["name"] == f["name"])
        for f in kept["execution"]["functions"]]))
    forged = json.loads(_kept(job, "cy").read_text())
    expected = score_execution(
        draw_problems(ASSIGNMENT, "cy", load_secret(home), None),
        executions.from_wire(forged["execution"], ASSIGNMENT, "cy")).score
    merged = merge_shard(home, ASSIGNMENT, job, quiet=True)
    assert {r["student_id"]: float(r["raw_score"]) for r in merged}["cy"] == expected
    assert expected <= points["invert_pose"] + 1e-9

    # Executions that do not answer the problems sent, or are another submission's, are
    # refused by name, and nothing of the shard is merged.
    before = (home / "gradebook.db").read_bytes(), (home / "grades.csv").read_bytes()
    forgeries = {
        "one outcome dropped": (
            "cy", lambda kept: _outcomes(kept, "invert_pose").pop(),
            "not one outcome per problem of invert_pose"),
        "ada's execution as bo's, who got no problems": (
            "bo", lambda kept: kept.update(ada, student_id="bo", execution={
                **ada["execution"], "student_id": "bo"}),
            "altered the problems' inputs|submitted again"),
        "another submission's digest": (
            "cy", lambda kept: kept.update(submission="0" * 64), "submitted again"),
        "a nonce of its own": (
            "cy", lambda kept: kept.update(nonce="ab" * 16), "names a nonce"),
        "an infinite time": (
            "cy", lambda kept: kept["execution"].update(seconds=float("inf")), "seconds"),
    }
    saved = _kept(job, "cy").read_bytes()
    for what, (sid, edit, why) in forgeries.items():
        if sid == "bo":
            _kept(job, "bo").parent.mkdir(parents=True, exist_ok=True)
            _kept(job, "bo").write_text(json.dumps(ada))
        _forge(job, sid, edit)
        with pytest.raises(ValueError, match=why):
            merge_shard(home, ASSIGNMENT, job, quiet=True)
        assert ((home / "gradebook.db").read_bytes(), (home / "grades.csv").read_bytes()) \
            == before, what
        _kept(job, "bo").unlink(missing_ok=True)
        _kept(job, "cy").write_bytes(saved)
    # an execution of a student HOME has no submission of is never looked at
    (_kept(job, "dee")).write_text(json.dumps({**ada, "student_id": "dee"}))
    assert {r["student_id"] for r in merge_shard(home, ASSIGNMENT, job, quiet=True)} == \
        {"ada", "cy"}
    with pytest.raises(ValueError, match="the course itself"):
        merge_shard(home, ASSIGNMENT, home, quiet=True)


def _gradebook_cells(course: Path, students: list[str]) -> dict:
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        out = {}
        for sid in students:
            sub = gb.find_submission(ASSIGNMENT, sid)
            out[sid] = sorted((g.name, g.auto_score, g.max_score) for nb in sub.notebooks
                              for g in nb.grades) + sorted(
                (c.name, c.auto_comment) for nb in sub.notebooks for c in nb.comments)
        return out


def test_student_list_from_the_command_line_or_a_file(tmp_path):
    assert _student_ids(None) is None
    assert _student_ids("a, b,,c") == ["a", "b", "c"]
    listing = tmp_path / "shard.txt"
    listing.write_text("# shard 1 of 3\nada\n  bo  # late\n\n")
    assert _student_ids(f"@{listing}") == ["ada", "bo"]
    with pytest.raises(ValueError, match="names no student"):
        _student_ids(" , ")
