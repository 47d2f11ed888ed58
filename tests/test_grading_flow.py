"""The adversarial corpus through the real flow: course init -> generate_assignment ->
submissions -> `cobotlab grade` -> the instructor's next nbgrader commands.

A representative slice of tests/adversarial/ (one case per layer the attacks go through:
the course via nbgrader's kernel, the host via the worker, the submission folder's layout,
the answer key); the whole corpus, side by side with plain nbgrader, is
benchmarks/adversarial_grading.py. Checked: every file in and outside the course that no
grade run should touch hashes the same after, the gradebook passes its integrity check and
nbgrader's own next commands work on it, grades.csv has one row per submission, no attacker
scores above the blank notebook, the victim keeps its honest score, no process is left.
"""

from __future__ import annotations

import csv
import hashlib
import os
import subprocess
import sys
import threading
from pathlib import Path

import course_kit as kit
import pytest

from autograder import gradebook, sandbox
from autograder.pipeline.pipeline import grade_course

ASSIGNMENT = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
# The worker-only attacks (reply_flood, geometry_invert, fork_memory_bomb, ...) have their
# own, faster tests in test_grading_sandbox.py and test_grading.py; import_solutions stays
# here because it also shows the answer key is out of reach of nbgrader's kernel.
SLICE = ("gradebook_overwrite", "config_injection", "copy_source", "overwrite_classmate",
         "neutralise_hidden_tests", "env_and_localhost", "grades_csv_symlink", "write_outside",
         "symlink_notebook", "symlink_folder", "fifo_notebook", "newline_student_id",
         "invisible_twin_student_id", "escaped_twin_student_id", "import_solutions",
         "keyring")
TOKEN = "instructor-token-5f1e"
SERVICE_PORT = 47613
ROOT = Path(__file__).resolve().parent.parent

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800),
              pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                 reason="bubblewrap cannot run here")]


def tree_hashes(top: Path, skip=()) -> dict[str, str]:
    """{relative path: sha256 (or link target / 'dir' / 'fifo')} of everything under top."""
    out = {}
    if not top.exists():
        return out
    for dirpath, dirnames, filenames in os.walk(top):
        rel_dir = os.path.relpath(dirpath, top)
        dirnames[:] = [d for d in dirnames if os.path.normpath(os.path.join(rel_dir, d))
                       not in skip and d != "__pycache__"]
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = os.path.normpath(os.path.join(rel_dir, name))
            if rel in skip:
                continue
            if path.is_symlink():
                out[rel] = "link:" + os.readlink(path)
            elif path.is_dir():
                out[rel] = "dir"
            elif path.is_file():
                out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
            else:
                out[rel] = "special"
    return out


# What a grade run may write in the course; everything else must hash the same.
OUTPUTS = ("grades.csv", "gradebook.db", "feedback_cobotlab", "autograded", ".cobotlab",
           "feedback", "export.csv")


def _orphans() -> list[str]:
    """Sandbox-user processes adopted by init: what would outlive a grade run. (Processes of
    a grade run still going, say another test's, have their sandbox as parent instead.)"""
    done = subprocess.run(["ps", "-eo", "uid=,ppid=,pid=,args="], capture_output=True,
                          text=True, check=False)
    return [line for line in done.stdout.splitlines()
            if line.split()[:2] == [str(sandbox.SANDBOX_UID), "1"]]


def test_the_corpus_slice_through_cobotlab_grade(tmp_path):
    cases = kit.corpus(ASSIGNMENT)
    assert set(SLICE) <= set(cases)
    home = tmp_path / "home"
    home.mkdir()
    notes = tmp_path / "instructor_notes.txt"
    notes.write_text("the instructor's own file\n")
    course = kit.released_course(tmp_path, ASSIGNMENT)
    kit.submit(course, ASSIGNMENT, "victim", replace=kit.solution_sources(ASSIGNMENT, FUNCTIONS))
    kit.submit(course, ASSIGNMENT, "blank")
    folders = {"victim", "blank"}
    for name in SLICE:
        folders.add(kit.submit_case(course, ASSIGNMENT, name, cases[name]))
    # as if an earlier, compromised run had made grades.csv a link to the instructor's file
    (course / "grades.csv").symlink_to(notes)

    watched = {"course": (course, OUTPUTS), "beside": (tmp_path, ("course", "home")),
               "home": (home, ()), "venv-bin": (Path(sys.prefix) / "bin", ())}
    before = {k: tree_hashes(p, skip) for k, (p, skip) in watched.items()}
    site_packages = next(Path(sys.prefix).glob("lib/python3*/site-packages"))
    site = sorted(os.listdir(site_packages))
    # a roster name a spreadsheet would run as a formula (no comma: nbgrader's own export
    # writes names unquoted, and a comma would shift its columns)
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        gb.update_or_create_student("victim", last_name='=HYPERLINK("http://evil.example")')
    orphans_before = _orphans()

    stop = threading.Event()
    service = kit.serve_localhost(SERVICE_PORT, b"instructor-service-secret", stop)
    env = dict(os.environ, HOME=str(home), COBOTLAB_TEST_INSTRUCTOR_TOKEN=TOKEN)
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    try:
        # the instructor's login keeps a token in its session keyring (pam_keyinit)
        with kit.instructor_keyring(TOKEN.encode()):
            done = subprocess.run([str(Path(sys.executable).parent / "cobotlab"), "grade",
                                   str(course), ASSIGNMENT, "--workers", "2"], env=env,
                                  capture_output=True, text=True, timeout=1500, check=False)
    finally:
        stop.set()
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    # nothing outside the grader's outputs changed, in the course or outside it
    after = {k: tree_hashes(p, skip) for k, (p, skip) in watched.items()}
    for key in watched:
        assert after[key] == before[key], (key, set(after[key]) ^ set(before[key]))
    assert notes.read_text() == "the instructor's own file\n"
    assert sorted(os.listdir(site_packages)) == site
    # the checkout is edited by people while this runs: look for what the attacks plant
    for top in ("autograder", "robots", "solutions", "labs"):
        planted = [p for p in (ROOT / top).rglob("*") if p.is_file() and
                   ("attack" in p.name or b"planted by a student" in p.read_bytes()[-4096:])]
        assert not planted, planted
    assert not list(Path("/tmp").glob("cobotlab-attack-*"))
    assert not (course / "grades.csv").is_symlink()

    # the gradebook is healthy and nbgrader's own next commands work on it
    assert gradebook.problem(course / "gradebook.db") is None
    kit.nbgrader(course, "export", "--CsvExportPlugin.to=export.csv")
    with open(course / "export.csv") as f:
        exported = {r["student_id"]: r for r in csv.DictReader(f)}
    log = (course / ".cobotlab" / "last_run.log").read_text()
    assert exported["victim"]["raw_score"] and float(exported["victim"]["raw_score"]) == 10.0, (
        exported["victim"], [line for line in log.splitlines() if "victim" in line][:3])
    assert all(float(r["raw_score"]) <= 10.0 and float(r["late_submission_penalty"] or 0) >= 0
               for r in exported.values())

    # one row per submission folder, in the grader's own, escaped, CSV
    with open(course / "grades.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(folders)
    grades = {r["student_id"]: r for r in rows}
    assert float(grades["victim"]["score"]) == 10.0, grades["victim"]
    assert grades["victim"]["last_name"].startswith("'="), grades["victim"]
    blank = float(grades["blank"]["score"])
    for name in SLICE:
        row = grades.get(cases[name]["student"] and
                         cases[name]["student"].encode("unicode_escape").decode() or name)
        assert row is not None, (name, sorted(grades))
        assert float(row["score"]) <= blank, (name, row)
        for wanted in cases[name]["flags"]:
            assert any(f.startswith(wanted) for f in row["flags"].split(";")), (name, row)
    assert "\n" not in "".join(r["student_id"] for r in rows)
    assert "\x1b" not in done.stdout and "forged\\nreference" in done.stdout

    # the answer key is not importable in nbgrader's kernel either
    graded = course / "autograded" / "import_solutions" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    assert "No module named 'solutions'" in graded.read_text()

    # no process of any sandbox is left behind
    assert _orphans() == orphans_before
    if service:
        assert TOKEN not in (course / ".cobotlab" / "last_run.log").read_text()


# Attacks that act where nbgrader's own kernel runs the notebook (`--nbgrader-kernel`, or an
# assignment of several notebooks): the kernel swaps its output folders for links to the
# host course's answer key and to a classmate's folder.
KERNEL_LINKS = ("autograded_link_to_source", "autograded_link_to_classmate")
VICTIM_MARK = "victim-work-5c0ffee"


def test_nbgrader_s_kernel_cannot_swap_its_output_folders_for_links(tmp_path):
    cases = kit.corpus(ASSIGNMENT)
    course = kit.released_course(tmp_path, ASSIGNMENT)
    answer_key = course / "source" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    assert "### BEGIN SOLUTION" in answer_key.read_text()
    work = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    work["invert_pose"] += f"\n# {VICTIM_MARK}\n"
    kit.submit(course, ASSIGNMENT, "victim", replace=work)
    attackers = [kit.submit_case(course, ASSIGNMENT, name, cases[name]) for name in KERNEL_LINKS]


    rows = {r["student_id"]: r for r in grade_course(
        course, ASSIGNMENT, workers=2, run_nbgrader=True, nbgrader_kernel=True,
        students=attackers, quiet=True)}
    # nbgrader's feedback pages are made from the autograded notebooks the grader recorded
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep
               + os.environ.get("PATH", ""))
    subprocess.run([sys.executable, "-m", "nbgrader", "generate_feedback", ASSIGNMENT],
                   cwd=course, env=env, capture_output=True, timeout=300, check=False)

    for name in attackers:
        for top in ("autograded", "feedback"):
            for path in (course / top / name).rglob("*"):
                assert not path.is_symlink(), path
                if path.is_file():
                    text = path.read_text(errors="replace")
                    assert "BEGIN SOLUTION" not in text, (name, path)
                    assert VICTIM_MARK not in text, (name, path)
        assert float(rows[name]["score"]) == 0.0, rows[name]
        flags = rows[name]["flags"].split(";")
        assert f"nbgrader_output_refused:{ASSIGNMENT}" in flags, (name, rows[name]["flags"])
    assert (course / "submitted" / "victim" / ASSIGNMENT).is_dir()
