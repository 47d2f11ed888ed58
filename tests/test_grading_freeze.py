"""Freezing submissions as data, and the trusted side's writes: fast, no student code runs.

Links, named pipes, oversize and non-JSON notebooks, hostile student ids; atomic writes that
follow no link; CSV formula escaping; the gradebook's backup, integrity check and restore.
"""

from __future__ import annotations

import csv
import json
import os
import sqlite3
import time

import course_kit as kit
import pytest

from autograder import freeze, gradebook, record
from autograder.pipeline.begin import _begin_run
from autograder.pipeline.pipeline import grade_course

ASSIGNMENT = "lab0_frames"
NOTEBOOK = f"{ASSIGNMENT}.ipynb"
EXPECTED = {NOTEBOOK}


def _nb(cells=1) -> str:
    return json.dumps({"cells": [{"cell_type": "code", "source": "x = 1", "metadata": {},
                                  "outputs": []}] * cells, "metadata": {}, "nbformat": 4,
                       "nbformat_minor": 5})


@pytest.fixture
def course(tmp_path):
    (tmp_path / "source" / ASSIGNMENT).mkdir(parents=True)
    (tmp_path / "source" / ASSIGNMENT / NOTEBOOK).write_text(_nb(3))
    return tmp_path


def _hand_in(course, student, text=None):
    folder = course / "submitted" / student / ASSIGNMENT
    folder.mkdir(parents=True)
    if text is not None:
        (folder / NOTEBOOK).write_text(text)
    return folder


def _freeze(course, tmp_path, caps=freeze.Caps()):
    store = tmp_path / "store"
    store.mkdir(exist_ok=True)
    return {f.student_id: f for f in freeze.freeze_submissions(course / "submitted", ASSIGNMENT,
                                                                EXPECTED, store, caps)}


def test_links_pipes_and_junk_are_skipped_never_followed(course, tmp_path):
    _hand_in(course, "honest", _nb())
    (_hand_in(course, "link") / NOTEBOOK).symlink_to(course / "source" / ASSIGNMENT / NOTEBOOK)
    (course / "submitted" / "folder_link").mkdir()
    (course / "submitted" / "folder_link" / ASSIGNMENT).symlink_to(
        course / "submitted" / "honest" / ASSIGNMENT)
    os.mkfifo(_hand_in(course, "fifo") / NOTEBOOK)  # opening it for reading would block
    _hand_in(course, "junk", "this is not JSON")
    started = time.monotonic()
    frozen = _freeze(course, tmp_path)
    assert time.monotonic() - started < 5
    assert [p.name for p in frozen["honest"].notebooks] == [NOTEBOOK]
    assert frozen["link"].notebooks == [] and "not_a_regular_file:" + NOTEBOOK in \
        frozen["link"].flags
    assert frozen["folder_link"].notebooks == [] and frozen["folder_link"].flags == [
        "not_a_folder:symlink"]
    assert frozen["fifo"].notebooks == [] and any("named pipe" in n for n in frozen["fifo"].notes)
    assert frozen["junk"].notebooks == [] and frozen["junk"].flags == [
        f"unreadable_notebook:{NOTEBOOK}"]
    # the frozen copies are plain files in the store, not links
    for f in frozen.values():
        for path in f.notebooks:
            assert not path.is_symlink() and str(path).startswith(str(tmp_path / "store"))


def test_huge_notebooks_cost_seconds_not_minutes(course, tmp_path):
    big = _hand_in(course, "big") / NOTEBOOK
    with open(big, "wb") as f:  # 228 MB, sparse: costs nothing to make
        f.truncate(228 * 2**20)
    _hand_in(course, "many_cells", _nb(100_000))
    started = time.monotonic()
    frozen = _freeze(course, tmp_path)
    assert time.monotonic() - started < 10
    assert frozen["big"].notebooks == [] and "over the 20 MB cap" in " ".join(frozen["big"].notes)
    assert frozen["many_cells"].notebooks == []
    assert "100000 cells" in " ".join(frozen["many_cells"].notes)


@pytest.mark.parametrize("student, accepted", [
    ("alice", True), ("o'brien", True), ("bad\nid", False), ("esc\x1b[2J", False),
    ("-rf", False), ("=HYPERLINK(1)", False), ("back\\\\slash", False), ("rtl\u202eevil", False),
    (" padded", False)])
def test_student_ids_with_control_characters_or_formulas_are_refused(course, tmp_path, student,
                                                                     accepted):
    _hand_in(course, student, _nb())
    (entry,) = _freeze(course, tmp_path).values()
    assert entry.accepted is accepted
    assert "\n" not in entry.student_id and "\x1b" not in entry.student_id
    if not accepted:
        assert entry.flags == ["rejected_student_id"] and entry.notebooks == []


def test_printable_escapes_what_a_terminal_or_log_would_act_on():
    assert freeze.printable("a\nb\x1b[2J\u202ec") == "a\\nb\\x1b[2J\\u202ec"
    assert freeze.printable("x" * 500, 10) == "x" * 10 + "..."


def test_csv_cells_that_start_a_formula_are_escaped(tmp_path):
    rows = [{"student_id": "alice", "last_name": '=HYPERLINK("http://e.x","y")',
             "first_name": "+cmd", "email": "@SUM(1)", "score": -1.5, "flags": "-x"}]
    record.write_csv(tmp_path, "grades.csv", list(rows[0]), rows)
    with open(tmp_path / "grades.csv", newline="") as f:
        (row,) = csv.DictReader(f)
    assert row["last_name"].startswith("'=") and row["first_name"] == "'+cmd"
    assert row["email"] == "'@SUM(1)" and row["flags"] == "'-x" and row["score"] == "-1.5"


def test_writes_replace_a_link_or_a_folder_and_never_write_through_one(tmp_path):
    victim = tmp_path / "instructor.txt"
    victim.write_text("mine")
    course = tmp_path / "course"
    course.mkdir()
    (course / "grades.csv").symlink_to(victim)
    record.write_file(course, "grades.csv", b"rows")
    assert victim.read_text() == "mine" and (course / "grades.csv").read_text() == "rows"
    assert not (course / "grades.csv").is_symlink()
    (course / "grades.csv").unlink()
    (course / "grades.csv").mkdir()
    record.write_file(course, "grades.csv", b"rows")
    assert (course / "grades.csv").read_text() == "rows"
    assert list(course.glob("grades.csv.moved-*"))
    (course / "feedback_cobotlab").symlink_to(tmp_path, target_is_directory=True)
    with pytest.raises(ValueError, match="not a plain folder"):
        record.write_file(course, "feedback_cobotlab/alice/lab0/feedback.html", b"x")
    assert not (tmp_path / "alice").exists()


def _gradebook(path):
    con = sqlite3.connect(path)
    con.executescript("CREATE TABLE assignment (id TEXT); CREATE TABLE grade "
                      "(auto_score FLOAT, manual_score FLOAT); INSERT INTO grade VALUES (3, NULL);")
    con.commit()
    con.close()


def test_a_damaged_gradebook_is_detected_and_restored(tmp_path):
    course, private = tmp_path / "course", tmp_path / "course" / ".cobotlab"
    private.mkdir(parents=True)
    db = course / "gradebook.db"
    _gradebook(db)
    assert gradebook.problem(db) is None
    backup = gradebook.backup(course, private)
    db.write_bytes(b"not a database any more" * 100)
    assert gradebook.problem(db) is not None
    gradebook.restore(course, backup)
    assert gradebook.problem(db) is None
    con = sqlite3.connect(db)
    assert con.execute("SELECT auto_score FROM grade").fetchone() == (3.0,)
    con.close()


def test_a_rerun_after_an_interrupted_run_restores_and_says_so(tmp_path):

    course, private = tmp_path / "course", tmp_path / "course" / ".cobotlab"
    private.mkdir(parents=True)
    _gradebook(course / "gradebook.db")
    _begin_run(course, private)  # a run starts, backs up, then dies half-way
    (course / "gradebook.db").write_bytes(b"\0" * 4096)
    marker = private / record.RUN_MARKER
    marker.write_text(json.dumps({"pid": 2**22 + 12345}))  # a pid that is gone
    notes = _begin_run(course, private)
    assert any("interrupted" in n and "restored" in n for n in notes), notes
    assert gradebook.problem(course / "gradebook.db") is None
    marker.write_text(json.dumps({"pid": os.getpid() + 0}))
    assert _begin_run(course, private) == [
        "the previous run was interrupted; gradebook.db checked: ok"]


# Pairs of refused folder names that shared one grades.csv row when a refused id's row was
# keyed by its printable form cut at 200 characters (then spreadsheet-escaped): an invisible
# character and its escaped spelling, two long names alike for their first 200 characters,
# and a formula-like name against an accepted name with the apostrophe a spreadsheet cell
# gets; and a name that is not UTF-8 (it could not be written to grades.csv at all).
TWINS = {"a\u202eb": "a\\u202eb", "a\\u202eb": "a\\\\u202eb",
         "x" * 200 + "1": "x" * 200 + "1", "x" * 200 + "2": "x" * 200 + "2",
         "=ben": "\\x3dben", os.fsdecode(b"caf\xe9"): "caf\\udce9"}
ACCEPTED = ("ana", "'=ben")


def test_every_refused_folder_gets_a_row_of_its_own_and_accepted_rows_stay(tmp_path, capsys):

    course = kit.initialized_course(tmp_path)
    for student in ACCEPTED:   # handed in nothing to run: no student code in this test
        (_hand_in(course, student) / "timestamp.txt").write_text("2026-11-20 10:00:00 UTC")
    grade_course(course, ASSIGNMENT, quiet=True)
    before = (course / "grades.csv").read_text().splitlines()

    for name in TWINS:
        _hand_in(course, name, _nb())
    (tmp_path / "store").mkdir()
    frozen = {f.student_id: f for f in freeze.freeze_submissions(
        course / "submitted", ASSIGNMENT, EXPECTED, tmp_path / "store")}
    assert sorted(frozen) == sorted([*TWINS.values(), *ACCEPTED])
    grade_course(course, ASSIGNMENT, quiet=False)
    summary = capsys.readouterr().out

    with open(course / "grades.csv", newline="", encoding="utf-8") as f:
        rows = {r["student_id"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == sorted([*TWINS.values(), *ACCEPTED])
    for name, key in TWINS.items():
        assert rows[key]["flags"] == "rejected_student_id", rows[key]
        assert rows[key]["score"] == "0.0" and not frozen[key].accepted
        # the key gives the folder's name back
        assert key.encode("ascii", "backslashreplace").decode("unicode_escape") == name
    for student in ACCEPTED:
        assert frozen[student].accepted and rows[student]["flags"] == ""
    # accepted rows are byte for byte what they were
    after = (course / "grades.csv").read_text().splitlines()
    assert [line for line in after if ",ana," in line] == \
        [line for line in before if ",ana," in line]
    assert [line for line in after if ",'=ben," in line] == \
        [line for line in before if ",'=ben," in line]
    # the summary cuts a long id to fit, but still tells the two apart
    long = [line.split()[0] for line in summary.splitlines() if line.startswith("x" * 40)]
    assert len(long) == 2 and long[0] != long[1], summary
