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

from autograder import checks, gradebook, record, sandbox
from autograder.course import grade_course
from autograder.shards import merge_shard
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


def test_a_shard_grades_only_its_students_and_merges_back_into_the_home_course(released,
                                                                              tmp_path):
    shard = kit.fresh_course(released, tmp_path / "job")  # a cluster job's copy of the course
    home = kit.fresh_course(released, tmp_path / "home")
    for course in (shard, home):
        _submit_class(course)
    # as `nbgrader submit` leaves it: release_feedback at home needs it beside ada's notebook
    (shard / "submitted" / "ada" / ASSIGNMENT / "submission_secret.txt").write_text("ab" * 64)
    calls = []
    rows = grade_course(shard, ASSIGNMENT, workers=2, quiet=True, students=["cy", "ada"],
                        run_nbgrader=True,  # as the CLI does: autograded notebooks too
                        progress=lambda done, total, sid: calls.append((done, total, sid)))
    assert sorted(r["student_id"] for r in rows) == ["ada", "cy"]
    assert calls[0] == (0, 2, "")
    assert sorted(calls[1:]) == [(1, 2, calls[1][2]), (2, 2, calls[2][2])]
    assert {calls[1][2], calls[2][2]} == {"ada", "cy"}
    with pytest.raises(ValueError, match="no submission .* by dee"):
        grade_course(shard, ASSIGNMENT, quiet=True, students=["ada", "dee"])

    # Back home: the gradebook (where formgrader and nbgrader export look), grades.csv, the
    # feedback pages and the cross-check ledger hold what the job graded, bo untouched.
    merged = merge_shard(home, ASSIGNMENT, shard, quiet=True)
    by_id = {r["student_id"]: r for r in rows}
    assert {r["student_id"]: float(r["raw_score"]) for r in merged} == {
        sid: float(r["raw_score"]) for sid, r in by_id.items()}
    assert float(by_id["ada"]["raw_score"]) > float(by_id["cy"]["raw_score"]) > 0
    ours, theirs = (_gradebook_cells(c, ["ada", "cy"]) for c in (home, shard))
    assert ours == theirs and all(ours.values())
    assert set(kit.read_grades(home)) == {"ada", "cy"}
    for sid in ("ada", "cy"):
        assert float(kit.read_grades(home)[sid]["score"]) == float(by_id[sid]["score"])
        page = home / "feedback_cobotlab" / sid / ASSIGNMENT / "feedback.html"
        assert page.read_bytes() == (shard / page.relative_to(home)).read_bytes()
        notebook = home / "autograded" / sid / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
        assert notebook.read_bytes() == (shard / notebook.relative_to(home)).read_bytes()
        for copied in (page.with_name("nbgrader_section.json"),
                       notebook.with_name("timestamp.txt")):
            assert copied.read_bytes() == (shard / copied.relative_to(home)).read_bytes()
    secret = home / "autograded" / "ada" / ASSIGNMENT / "submission_secret.txt"
    assert secret.read_text() == "ab" * 64
    assert not (home / "autograded" / "cy" / ASSIGNMENT / "submission_secret.txt").exists()
    ledger = json.loads((home / ".cobotlab" / "nbgrader_cells.json").read_text())
    assert set(ledger[ASSIGNMENT]) == {"ada", "cy"}
    assert gradebook.problem(home / "gradebook.db") is None
    assert not (home / ".cobotlab" / record.RUN_MARKER).exists()

    # A shard whose grades.csv was tampered with (or graded another lab version) is refused,
    # and nothing of it is written.
    before = (home / "gradebook.db").read_bytes()
    text = (shard / "grades.csv").read_text()
    (shard / "grades.csv").write_text(text.replace(f",{by_id['ada']['raw_score']},",
                                                   ",99.0,", 1))
    with pytest.raises(ValueError, match="scores 99"):
        merge_shard(home, ASSIGNMENT, shard, quiet=True)
    assert (home / "gradebook.db").read_bytes() == before
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
