"""The trusted side's one way to open what student code could have written
(autograder.safe_files), and the writes that go through it: a link at any component below
the trusted root (the root's child, a folder in the middle, the file) is refused and never
followed, a named pipe anywhere never blocks, reads are capped. Fast: no student code runs.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from autograder import record, safe_files
from autograder.safe_files import Refused, Why
from autograder.secret import SECRET_ENV, load_secret

SECRET = b"the answer key"
HONEST = b"the student's own"
# the three places a link can stand on the way to root/a/b/f.txt
COMPONENTS = ("a", "a/b", "a/b/f.txt")


@pytest.fixture
def tree(tmp_path) -> tuple[Path, Path]:
    """(root, elsewhere): root/a/b/f.txt, and outside the root the same layout holding what
    a link must never reach."""
    root, elsewhere = tmp_path / "root", tmp_path / "elsewhere"
    for top, data in ((root, HONEST), (elsewhere, SECRET)):
        (top / "a" / "b").mkdir(parents=True)
        (top / "a" / "b" / "f.txt").write_bytes(data)
    return root, elsewhere


def _link(root: Path, elsewhere: Path, component: str) -> None:
    """Swap root/<component> for a link to the same place under ``elsewhere``."""
    path = root / component
    os.rename(path, f"{path}.moved")
    path.symlink_to(elsewhere / component, target_is_directory=path.suffix != ".txt")


def _fifo(root: Path, component: str) -> None:
    path = root / component
    os.rename(path, f"{path}.moved")
    os.mkfifo(path)


def _reads(root: Path, tmp_path: Path) -> dict:
    """Every way the trusted side reads root/a/b/f.txt, each returning what it got."""
    def listing():
        with safe_files.open_folder(root, "a/b") as folder:
            return [(e.name, e.kind) for e in folder.entries()]

    def copy():
        dest = tmp_path / f"copy-{time.monotonic_ns()}"
        safe_files.copy_file(root, "a/b/f.txt", dest, 1 << 20)
        return dest.read_bytes()

    def tree_copy():
        dest = tmp_path / f"tree-{time.monotonic_ns()}"
        dest.mkdir()
        with safe_files.open_folder(root, "a") as folder:
            skipped = safe_files.copy_tree(folder, dest, safe_files.TreeCaps(1 << 20, 1 << 20,
                                                                             10, 4))
        copied = dest / "b" / "f.txt"
        return (copied.read_bytes() if copied.exists() else None,
                [(s.path, s.why) for s in skipped])

    return {"read_file": lambda: safe_files.read_file(root, "a/b/f.txt", 1 << 20),
            "list": listing, "copy_file": copy, "copy_tree": tree_copy}


def test_the_readers_give_a_plain_tree_back(tree, tmp_path):
    root, _ = tree
    got = {name: read() for name, read in _reads(root, tmp_path).items()}
    assert got == {"read_file": HONEST, "list": [("f.txt", "regular file")],
                   "copy_file": HONEST, "copy_tree": (HONEST, [])}


@pytest.mark.parametrize("component", COMPONENTS)
def test_a_link_at_any_component_is_refused_by_every_reader(tree, tmp_path, component):
    root, elsewhere = tree
    _link(root, elsewhere, component)
    for name, read in _reads(root, tmp_path).items():
        if name == "list" and component == "a/b/f.txt":
            # listing a/b shows the link as a link, never what it points at
            assert read() == [("f.txt", "symlink"), ("f.txt.moved", "regular file")]
            continue
        if name == "copy_tree" and component != "a":
            # copy_tree starts at root/a: a link below is skipped, named, not followed
            assert read() == (None, [(component.removeprefix("a/"), Why.LINK)]), component
            continue
        with pytest.raises(Refused) as caught:
            read()
        assert caught.value.why is Why.LINK, (name, caught.value)
        assert caught.value.where == component and caught.value.kind == "symlink", name
        assert "symlink" in str(caught.value) and repr(component) in str(caught.value)
    assert (elsewhere / "a" / "b" / "f.txt").read_bytes() == SECRET


def test_the_root_itself_must_be_a_real_folder(tree, tmp_path):
    root, _ = tree
    link = tmp_path / "root-link"
    link.symlink_to(root, target_is_directory=True)
    with pytest.raises(Refused) as caught:
        safe_files.read_file(link, "a/b/f.txt", 1 << 20)
    assert caught.value.why is Why.LINK and caught.value.where == ""
    with pytest.raises(Refused) as caught:
        safe_files.read_file(tmp_path / "nowhere", "f.txt", 1 << 20)
    assert caught.value.why is Why.MISSING


def _without_blocking(call) -> tuple[bool, object]:
    """(finished within 5 s, what ``call`` returned or raised)."""
    out: list = []

    def run():
        try:
            out.append(call())
        except Exception as exc:  # noqa: BLE001 - handed to the test
            out.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(5)
    return not thread.is_alive(), out[0] if out else None


@pytest.mark.parametrize("component", COMPONENTS)
def test_a_named_pipe_at_any_component_never_blocks(tree, tmp_path, component):
    root, _ = tree
    _fifo(root, component)
    try:
        for name, read in _reads(root, tmp_path).items():
            finished, got = _without_blocking(read)
            assert finished, f"{name} blocked on the named pipe at {component}"
            if name == "list" and component == "a/b/f.txt":
                assert got == [("f.txt", "named pipe"), ("f.txt.moved", "regular file")]
            elif name == "copy_tree" and component != "a":
                assert got == (None, [(component.removeprefix("a/"), Why.NOT_REGULAR)]), got
            else:
                wanted = Why.NOT_REGULAR if component.endswith(".txt") else Why.NOT_A_FOLDER
                assert isinstance(got, Refused), (name, got)
                assert got.why is wanted and got.kind == "named pipe", (name, got)
                assert got.where == component
    finally:
        # a reader that did block is let go: a writer that opens and leaves ends it
        try:
            os.close(os.open(root / component, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass


def test_reads_are_capped_and_odd_names_refused(tree, tmp_path):
    root, _ = tree
    (root / "big").write_bytes(b"x" * 5000)
    with pytest.raises(Refused) as caught:
        safe_files.read_file(root, "big", 4096)
    assert caught.value.why is Why.TOO_BIG
    assert safe_files.read_file(root, "big", 5000) == b"x" * 5000
    for name in ("..", "."):
        with pytest.raises(Refused) as caught:
            safe_files.read_file(root, ["a", name, "f.txt"], 4096)
        assert caught.value.why is Why.BAD_NAME
    with pytest.raises(Refused) as caught:
        safe_files.read_file(root, "a/b/none.txt", 4096)
    assert caught.value.why is Why.MISSING and caught.value.where == "a/b/none.txt"


@pytest.mark.parametrize("component", COMPONENTS[:2])
def test_writes_go_through_no_linked_folder(tree, component):
    root, elsewhere = tree
    _link(root, elsewhere, component)
    with pytest.raises(ValueError, match="not a plain folder") as caught:
        record.write_file(root, "a/b/f.txt", b"written")
    assert isinstance(caught.value, Refused) and caught.value.where == component
    assert (elsewhere / "a" / "b" / "f.txt").read_bytes() == SECRET
    assert sorted(p.name for p in (elsewhere / "a" / "b").iterdir()) == ["f.txt"]


def test_update_csv_reads_no_grades_csv_through_a_linked_folder(tree):
    root, elsewhere = tree
    (elsewhere / "a" / "grades.csv").write_text("assignment,student_id,score\nlab,eve,10\n")
    _link(root, elsewhere, "a")
    with pytest.raises(Refused):
        record.update_csv(root, "a/grades.csv", ["assignment", "student_id", "score"],
                          [{"assignment": "lab", "student_id": "ana", "score": 1}],
                          key=("assignment", "student_id"))
    assert (elsewhere / "a" / "grades.csv").read_text().endswith("lab,eve,10\n")


@pytest.mark.parametrize("linked", [".cobotlab", ".cobotlab/secret"])
def test_the_grading_secret_is_read_without_following_a_link(tmp_path, monkeypatch, linked):
    """load_secret reads `.cobotlab/secret` through safe_files: a link to another
    file (someone else's secret, or one chosen to be guessed) is refused with the fix."""

    monkeypatch.delenv(SECRET_ENV, raising=False)
    course, elsewhere = tmp_path / "course", tmp_path / "elsewhere"
    for top in (course, elsewhere):
        (top / ".cobotlab").mkdir(parents=True)
    (elsewhere / ".cobotlab" / "secret").write_text("chosen-by-someone-else-0123456789\n")
    (course / ".cobotlab" / "secret").write_text("the-course-s-own-secret-0123456789\n")
    assert load_secret(course) == "the-course-s-own-secret-0123456789"

    target = course / linked
    if target.is_dir():
        os.rename(target, tmp_path / "moved")
    else:
        target.unlink()
    os.symlink(elsewhere / linked, target)
    with pytest.raises(ValueError, match="grading secret .* is refused: .*symlink.*regular file"):
        load_secret(course)
    monkeypatch.setenv(SECRET_ENV, "from-the-environment-0123")   # it wins, as before
    assert load_secret(course) == "from-the-environment-0123"


def test_a_missing_or_short_secret_names_the_fix(tmp_path, monkeypatch):

    monkeypatch.delenv(SECRET_ENV, raising=False)
    with pytest.raises(ValueError, match="no grading secret .* `cobotlab course init DIR`"):
        load_secret(tmp_path)
    (tmp_path / ".cobotlab").mkdir()
    (tmp_path / ".cobotlab" / "secret").write_text("short\n")
    with pytest.raises(ValueError, match="at least 16 characters"):
        load_secret(tmp_path)
