"""The practice-problem cache (autograder/practice_cache.py): a hit gives the bytes a fresh
draw gives, and a damaged, planted or misplaced file is refused aloud and drawn again.

Lab 0's invert_pose on one seed, drawn for real (its generator and mistake families), so
each test costs a fraction of a second.
"""

from __future__ import annotations

import gzip
import json
import warnings
from pathlib import Path

import pytest

from autograder import practice, practice_cache, registry

LAB, NAME, SEED = "lab0_frames", "invert_pose", 0


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A cache of this test's own, with no entry in this process's memory."""
    folder = tmp_path / "cache"
    monkeypatch.setenv(practice_cache.ENV, str(folder))
    practice._built_for.cache_clear()
    yield folder
    practice._built_for.cache_clear()


def _built() -> tuple:
    practice._built_for.cache_clear()   # the disk, not this process's memory
    return practice._built(LAB, NAME, SEED)


def _entry(cache: Path) -> Path:
    (path,) = cache.glob(f"{LAB}/*/{NAME}-{SEED}.json.gz")
    return path


def _no_draw(monkeypatch) -> None:
    def refuse(*args):
        raise AssertionError("drawn again although the cache holds the problems")
    monkeypatch.setattr(practice, "drawn", refuse)


def test_a_hit_is_what_a_fresh_draw_gives_and_draws_nothing(cache, monkeypatch):
    fresh = practice.drawn(LAB, NAME, SEED)
    assert _built() == fresh          # stored on the way
    _no_draw(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # a good file is used without a word
        assert _built() == fresh
    assert _entry(cache).parent.parent.parent == cache


def test_a_released_practice_file_has_the_same_bytes_from_the_cache(cache, tmp_path,
                                                                     monkeypatch):
    monkeypatch.setenv(practice_cache.ENV, "off")
    uncached = practice.write_practice(LAB, tmp_path / "off", seeds=[SEED]).read_bytes()
    assert not cache.exists()
    monkeypatch.setenv(practice_cache.ENV, str(cache))
    practice._built_for.cache_clear()
    first = practice.write_practice(LAB, tmp_path / "a", seeds=[SEED]).read_bytes()
    practice._built_for.cache_clear()
    _no_draw(monkeypatch)
    second = practice.write_practice(LAB, tmp_path / "b", seeds=[SEED]).read_bytes()
    assert uncached == first == second
    assert len(list((cache / "compressed").glob("*.gz"))) == 1


def test_a_damaged_file_is_refused_aloud_drawn_again_and_replaced(cache):
    fresh = _built()
    path = _entry(cache)
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0x40
    path.write_bytes(bytes(raw))
    with pytest.warns(UserWarning, match=r"cannot be used .*digest does not match") as seen:
        assert _built() == fresh
    assert str(path) in str(seen[0].message)   # names the file
    assert path.read_bytes() != bytes(raw)   # replaced by a good one
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _built() == fresh


def test_a_planted_file_with_a_good_digest_is_checked_as_a_students_file_is(cache):
    fresh = _built()
    path = _entry(cache)
    planted = [{"__pickle__": "Y29zCnN5c3RlbQ=="}]   # not a wire type: never unpickled
    body = gzip.compress(json.dumps(planted).encode())
    lab_key = path.parent.name
    entry_key = f"{LAB}\0{lab_key}\0{NAME}-{SEED}"
    path.write_bytes(practice_cache._digest(entry_key, body) + b"\n" + body)
    with pytest.warns(UserWarning, match=r"PracticeDataError: .* is damaged"):
        assert _built() == fresh


def test_a_file_moved_from_another_entry_is_refused(cache):
    _built()
    other = practice._built(LAB, NAME, 1)   # seed 1's problems
    path = _entry(cache)
    path.write_bytes((path.parent / f"{NAME}-1.json.gz").read_bytes())
    with pytest.warns(UserWarning, match="digest does not match"):
        assert _built() != other


def test_a_compressed_file_that_holds_another_body_is_not_used(cache, tmp_path):
    path = practice.write_practice(LAB, tmp_path / "a", seeds=[SEED])
    good = path.read_bytes()
    (stored,) = (cache / "compressed").glob("*.gz")
    stored.write_bytes(gzip.compress(b"[]", mtime=0))
    with pytest.warns(UserWarning, match="does not hold what its name says"):
        again = practice.write_practice(LAB, tmp_path / "b", seeds=[SEED]).read_bytes()
    assert again == good and stored.read_bytes() == good


def test_a_folder_others_may_write_is_not_used(cache):
    cache.mkdir(mode=0o700)
    cache.chmod(0o777)
    fresh = practice.drawn(LAB, NAME, SEED)
    assert _built() == fresh
    assert list(cache.iterdir()) == []


def test_off_turns_it_off(tmp_path, monkeypatch):
    monkeypatch.setenv(practice_cache.ENV, "off")
    monkeypatch.chdir(tmp_path)
    assert practice_cache.folder() is None
    assert _built() == practice.drawn(LAB, NAME, SEED)


def test_the_key_follows_the_spec_the_code_and_the_lab(tmp_path):
    spec_hash = registry.spec_hash(LAB)
    key = practice_cache.key(LAB, spec_hash, practice.FORMAT)
    assert key == practice_cache.key(LAB, spec_hash, practice.FORMAT)
    assert key != practice_cache.key(LAB, "0" * 16, practice.FORMAT)
    assert key != practice_cache.key("lab1_flange", spec_hash, practice.FORMAT)
    assert key != practice_cache.key(LAB, spec_hash, practice.FORMAT + 1)
    # the code's hash: every file of the packages, by path and bytes
    root = tmp_path / "pkg"
    (root / "families").mkdir(parents=True)
    (root / "families" / "sign.py").write_text("A = 1\n")
    before = practice_cache.tree_hash({"autograder": root})
    (root / "families" / "sign.py").write_text("A = 2\n")
    edited = practice_cache.tree_hash({"autograder": root})
    (root / "families" / "sign.py").rename(root / "families" / "sign2.py")
    renamed = practice_cache.tree_hash({"autograder": root})
    (root / "__pycache__").mkdir()
    (root / "__pycache__" / "x.pyc").write_bytes(b"\0")
    (root / "data.npz").write_bytes(b"\0")   # data files: a regular install has fewer
    assert len({before, edited, renamed}) == 3
    assert practice_cache.tree_hash({"autograder": root}) == renamed
    assert practice_cache.tree_hash({"autograder": None}) != renamed


def test_only_the_released_seeds_are_kept(cache):
    assert practice._built(LAB, NAME, 12345) == practice.drawn(LAB, NAME, 12345)
    assert not cache.exists() or not list(cache.rglob(f"{NAME}-12345*"))
