"""The one roster format (autograder/roster.py), as every command that takes a roster reads
it: `cobotlab course exchange` (autograder.exchange) and `cobotlab export` (cobotlab.lms_export)."""

from __future__ import annotations

import pytest

from autograder import exchange, roster
from cobotlab import lms_export

BOM = "\ufeff"


def _write(tmp_path, text: str, encoding: str = "utf-8"):
    path = tmp_path / "roster.csv"
    path.write_bytes(text.encode(encoding))
    return path


@pytest.mark.parametrize("head", ["id", "student_id", " id "])
@pytest.mark.parametrize("bom", ["", BOM])   # Excel's "CSV UTF-8" starts with one
def test_one_format_read_the_same_by_every_command(tmp_path, head, bom):
    path = _write(tmp_path, f"{bom}{head},first_name,email\r\nana , Ana,ana@example.edu\r\n"
                            "bo,Bo,bo@example.edu\r\n")
    rows = roster.read_roster(path)
    assert rows == [{"id": "ana", "first_name": "Ana", "email": "ana@example.edu"},
                    {"id": "bo", "first_name": "Bo", "email": "bo@example.edu"}]
    assert exchange.read_roster(path) == roster.roster_ids(path) == ["ana", "bo"]
    assert lms_export.read_roster(path, "moodle") == rows


@pytest.mark.parametrize("text, why", [
    ("name,email\nana,a@x\n", "no id column"),
    ("id,student_id\nana,ana\n", "both an `id` and a `student_id`"),
    ("id,email\nana,a@x\n,b@x\n", "line 3: an empty id"),
    ("id,email\nana,a@x\nbo,b@x\nana,c@x\n", "line 4: 'ana' is listed again \\(line 2\\)"),
    ("id,email\n", "lists no student"),
    ("", "no id column"),
])
def test_a_bad_roster_is_refused_by_line_with_the_fix(tmp_path, text, why):
    path = _write(tmp_path, text)
    for read in (roster.read_roster, exchange.read_roster,
                 lambda p: lms_export.read_roster(p, "csv")):
        with pytest.raises(ValueError, match=why):
            read(path)


def test_a_roster_that_is_not_utf8_is_named(tmp_path):
    path = _write(tmp_path, "id,last_name\nana,Müller\n", encoding="latin-1")
    with pytest.raises(ValueError, match="cannot read the roster .* UTF-8"):
        roster.read_roster(path)


def test_the_lms_checks_stay_on_top_of_the_one_reader(tmp_path):
    path = _write(tmp_path, f"{BOM}id,email\nana,a@x\nbo,a@x\n")
    with pytest.raises(ValueError, match="email 'a@x' is also ana's"):
        lms_export.read_roster(path, "moodle")
    with pytest.raises(ValueError, match="lacks the column"):
        lms_export.read_roster(path, "canvas")
