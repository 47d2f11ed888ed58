"""Practice problems drawn once per machine: an on-disk memo of :mod:`autograder.practice`.

Drawing a lab's practice problems (the generators, then each problem's classic mistakes and
input-side mistake families) costs seconds of CPU per lab: ``course init`` spent about 12 s on
the six built-in labs in every process that laid out a course, and an instructor's kernel
drew them again for each ``check()`` of a source notebook. The same inputs give the same
bytes, so they are kept here, one file per graded function and seed, under a key made of
everything that decides those bytes:

* the lab's :func:`autograder.registry.spec_hash` (its public scoring and private spec);
* the source of the code that draws and encodes problems and precomputes mistakes: every
  Python file of the packages ``autograder`` (the generators' helpers, the mistake families,
  the wire encoding), ``robots`` (the pose math) and ``solutions`` (the references the
  families call);
* the versions of Python, NumPy and SciPy (their random streams and arithmetic) and the
  machine's architecture;
* the function's name and the seed.

Where: ``$COBOTLAB_PRACTICE_CACHE`` (a folder; ``off`` turns the cache off), else
``$XDG_CACHE_HOME/cobotlab/practice``, else ``~/.cache/cobotlab/practice``. A folder that is
not this user's own, or that others may write, is not used (the problems are drawn instead).

Practice data is released to students, so nothing here is secret; but what it holds becomes
what ``check()`` shows and what nbgrader's hidden tests score, so no file is used on trust.
Each carries a SHA-256 digest of its key and body; a file whose digest, size, JSON or
problems (read by the caller's checked loader, the one students' files go through) are
wrong is refused with a warning naming it, drawn again and rewritten. Every failure to
read or write the cache itself (a full disk, a read-only home) falls back to drawing.
"""

from __future__ import annotations

import functools
import gzip
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

ENV = "COBOTLAB_PRACTICE_CACHE"
# The packages whose source decides what a practice problem's file holds.
CODE_PACKAGES = ("autograder", "robots", "solutions")
# A key's folder not used for this long is removed when another key of its lab is written
# (an instructor editing a spec makes a new key on every edit).
STALE_S = 14 * 24 * 3600
_MAX_BYTES = 256 * 1024 * 1024   # far above the largest entry (lab 5's depth images)


class CacheFileDamaged(Exception):
    """A cache file that must not be used: its digest, size, encoding or content is wrong."""


def folder() -> Path | None:
    """The cache's folder, or None when it is turned off (``$COBOTLAB_PRACTICE_CACHE=off``)."""
    chosen = os.environ.get(ENV)
    if chosen == "off":
        return None
    if chosen:
        return Path(chosen)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cobotlab" / "practice"


@functools.lru_cache(maxsize=1)
def code_hash() -> str:
    """A hash of the Python source of :data:`CODE_PACKAGES` as installed here, computed
    once a process (a process that edits these packages and draws again is no use case)."""
    import importlib.util

    roots = {}
    for package in CODE_PACKAGES:
        found = importlib.util.find_spec(package)
        locations = found.submodule_search_locations if found is not None else None
        roots[package] = Path(list(locations)[0]) if locations else None
    return tree_hash(roots)


def tree_hash(roots: dict[str, Path | None]) -> str:
    """A SHA-256 of every Python source file under each ``{name: folder}`` (None: absent),
    by each file's path within its folder and its bytes. Sources only: a regular install
    leaves out data files a checkout has (the shipped captures), and its code must give the
    checkout's key."""
    digest = hashlib.sha256()
    for name, root in sorted(roots.items()):
        if root is None:
            digest.update(f"{name}: absent\0".encode())
            continue
        for path in sorted(root.rglob("*.py")):
            if "__pycache__" in path.parts or not path.is_file():
                continue
            relative = path.relative_to(root).as_posix()
            digest.update(f"{name}/{relative}\0".encode("utf-8", "surrogateescape"))
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def _versions() -> str:
    import numpy
    import scipy

    return (f"python {sys.version_info[:3]} numpy {numpy.__version__} scipy "
            f"{scipy.__version__} {platform.machine()}")


def key(assignment: str, spec_hash: str, file_format: int) -> str:
    """The key of ``assignment``'s practice problems drawn with this install's code
    (32 hex digits): the name of its folder in the cache."""
    text = "\0".join((assignment, spec_hash, str(file_format), code_hash(), _versions()))
    return hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()[:32]


def _usable(root: Path) -> bool:
    """True when ``root`` exists or can be made, is this user's own and no one else may
    write it (so no other account can plant a file in it)."""
    try:
        root.mkdir(parents=True, exist_ok=True, mode=0o700)
        info = root.stat()
    except OSError:
        return False
    return info.st_uid == os.getuid() and not info.st_mode & 0o022


def _digest(entry_key: str, body: bytes) -> bytes:
    return hashlib.sha256(entry_key.encode("utf-8", "surrogateescape") + b"\0" + body
                          ).hexdigest().encode()


def _read(path: Path, entry_key: str) -> list:
    """The list stored at ``path``, its digest and encoding checked; CacheFileDamaged."""
    with open(path, "rb") as f:
        raw = f.read(_MAX_BYTES + 1)
    if len(raw) > _MAX_BYTES:
        raise CacheFileDamaged(f"larger than {_MAX_BYTES} bytes")
    stored, _, body = raw.partition(b"\n")
    if stored != _digest(entry_key, body):
        raise CacheFileDamaged("its digest does not match its key and content")
    try:
        value = json.loads(gzip.decompress(body).decode("utf-8"))
    except (OSError, EOFError, ValueError, RecursionError) as exc:
        raise CacheFileDamaged(f"not gzipped JSON: {type(exc).__name__}") from None
    if not isinstance(value, list):
        raise CacheFileDamaged("not a list of problems")
    return value


def _write(path: Path, entry_key: str, value: list) -> None:
    body = gzip.compress(json.dumps(value, separators=(",", ":"), allow_nan=True)
                         .encode("utf-8"), compresslevel=1, mtime=0)
    _replace(path, _digest(entry_key, body) + b"\n" + body)


def _replace(path: Path, data: bytes) -> None:
    """``path`` holding ``data``, written whole under another name, then renamed: a reader
    never sees half a file."""
    handle, partial = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".partial")
    with os.fdopen(handle, "wb") as f:
        f.write(data)
    os.replace(partial, path)


def _touch(path: Path) -> None:
    try:
        os.utime(path)
    except OSError:
        pass


def _prune(parent: Path, keep: str) -> None:
    """Remove what ``parent`` holds but ``keep`` unused (untouched) for STALE_S."""
    now = time.time()
    for other in parent.iterdir():
        try:
            if other.name != keep and now - other.stat().st_mtime > STALE_S:
                if other.is_dir():
                    shutil.rmtree(other, ignore_errors=True)
                else:
                    other.unlink()
        except OSError:
            pass


def cached(assignment: str, lab_key: str, entry: str, draw: Callable[[], list],
           check: Callable[[list, str], None]) -> list:
    """``draw()``'s JSON-ready list, from the cache when it holds entry ``entry`` of
    ``assignment`` under ``lab_key`` (see :func:`key`), else drawn and stored.

    ``check(value, where)`` is the caller's checked loader: it raises on content a fresh
    draw could not have made. A stored file it (or the digest) refuses is not used: a
    warning names the file and why, and the problems are drawn again and stored over it.
    """
    root = folder()
    if root is None or not _usable(root):
        return draw()
    path = root / assignment / lab_key / f"{entry}.json.gz"
    entry_key = f"{assignment}\0{lab_key}\0{entry}"
    try:
        value = _read(path, entry_key)
        check(value, str(path))
        _touch(path.parent)   # in use: not stale
        return value
    except FileNotFoundError:
        pass
    except OSError:
        return draw()   # an unreadable cache is no cache
    except Exception as exc:  # noqa: BLE001 - damaged or planted: refused aloud, drawn again
        warnings.warn(f"{path}: a practice-problem cache file that cannot be used "
                      f"({type(exc).__name__}: {exc}); drawing these problems again and "
                      "replacing it", stacklevel=3)
    value = draw()
    try:
        fresh = not path.parent.exists()
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        _write(path, entry_key, value)
        if fresh:
            _prune(path.parent.parent, lab_key)
    except OSError:
        pass   # a full disk or a read-only home: the problems are still right
    return value


def compressed(body: bytes, compress: Callable[[bytes], bytes]) -> bytes:
    """``compress(body)``, from the cache when it holds the same body's compressed bytes.

    Kept by the body's SHA-256 and used only when it decompresses to ``body`` exactly (a
    tenth of compressing's CPU), so no damaged or planted file can change what is written:
    ``course init`` spent 2.7 s of CPU a run compressing the same practice files again.
    """
    root = folder()
    if root is None or not _usable(root):
        return compress(body)
    path = root / "compressed" / f"{hashlib.sha256(body).hexdigest()}.gz"
    try:
        with open(path, "rb") as f:
            stored = f.read(len(body) + 1024 * 1024)   # never more than the body and then some
        if gzip.decompress(stored) == body:
            _touch(path)
            return stored
    except FileNotFoundError:
        pass
    except (OSError, EOFError, ValueError) as exc:
        warnings.warn(f"{path}: a compressed practice file in the cache that cannot be used "
                      f"({type(exc).__name__}: {exc}); compressing again and replacing it",
                      stacklevel=2)
    else:
        warnings.warn(f"{path}: a compressed practice file in the cache that does not hold "
                      "what its name says; compressing again and replacing it", stacklevel=2)
    value = compress(body)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        _replace(path, value)
        _prune(path.parent, path.name)
    except OSError:
        pass
    return value
