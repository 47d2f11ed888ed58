"""Open paths below a trusted folder one component at a time, never following a link.

The trusted side of grading reads files that student code could have replaced: the
submissions in ``submitted/``, nbgrader's scratch course after its kernel ran (the
autograded notebooks, the scratch gradebook), a shard job's copy of the course, and the
grader's own ``.cobotlab/`` files. A check on the whole path (``os.path.islink``, or
``O_NOFOLLOW``, which looks at the last component only) misses a folder above the file
that was swapped for a link: ``autograded/<student>/<lab>`` pointing at the host's
``source/<lab>`` hands over the answer key. So every component here is opened from its
parent's descriptor (``openat`` with ``O_NOFOLLOW``), folders with ``O_DIRECTORY``, files
after an ``lstat`` and checked again with ``fstat`` on the open descriptor; a link, a named
pipe, a socket or a device anywhere on the way is refused (never opened for reading, so a
pipe cannot block the grader), and reads are capped. A refusal is a :class:`Refused`
whose ``why`` (a :class:`Why`) says what was found, for callers to act on without parsing
its message.

The root itself is the caller's: the folders above it are followed as usual, but the root's
own last component must be a real folder (a ``.cobotlab`` swapped for a link is refused).
"""

from __future__ import annotations

import enum
import errno
import os
import stat
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Why", "Refused", "Entry", "Folder", "Skipped", "TreeCaps", "kind_of",
           "open_folder", "read_file", "copy_file", "copy_tree", "move_aside"]

_CHUNK = 1 << 20
_OPEN = os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK


class Why(enum.Enum):
    """Why a path was refused (or a file of a tree skipped)."""

    MISSING = "missing"
    LINK = "a symlink"
    NOT_A_FOLDER = "not a folder"
    NOT_REGULAR = "not a regular file"
    TOO_BIG = "over its size cap"
    UNREADABLE = "unreadable"
    BAD_NAME = "not a plain file name"
    TOO_DEEP = "nested too deep"
    TOO_MANY = "past the file count cap"


def kind_of(mode: int) -> str:
    """What an ``lstat`` mode is, in words: ``symlink``, ``named pipe``, ``folder``, ..."""
    for test, name in ((stat.S_ISLNK, "symlink"), (stat.S_ISDIR, "folder"),
                       (stat.S_ISREG, "regular file"), (stat.S_ISFIFO, "named pipe"),
                       (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "device"),
                       (stat.S_ISBLK, "device")):
        if test(mode):
            return name
    return "special file"


class Refused(ValueError):
    """A path below a trusted root that the trusted side does not open.

    ``where`` is the offending component's path relative to ``root`` (raw, as on disk),
    ``why`` a :class:`Why`, ``kind`` what was found there (:func:`kind_of`; empty when it
    is missing or could not be looked at), ``detail`` the reason in words.
    """

    def __init__(self, root, where: str, why: Why, detail: str, kind: str = ""):
        self.root, self.where, self.why, self.detail, self.kind = \
            Path(root), where, why, detail, kind
        super().__init__(f"{where!r} under {root}: {detail}" if where else f"{root}: {detail}")


@dataclass(frozen=True)
class Entry:
    """One name in a folder, as ``lstat`` saw it (a link is ``symlink``, never its target)."""

    name: str
    kind: str
    size: int


class Folder:
    """An open folder below a trusted root; what is under it is opened from its descriptor.

    Use as a context manager (or call :meth:`close`). Names given to its methods are single
    components: ``""``, ``.``, ``..`` and anything with ``/`` are refused (``BAD_NAME``).
    """

    def __init__(self, fd: int, root: Path, where: str):
        self.fd, self.root, self.where = fd, root, where

    def __enter__(self) -> Folder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def _below(self, name: str) -> str:
        return f"{self.where}/{name}" if self.where else name

    def _refuse(self, name: str, why: Why, detail: str, kind: str = "") -> Refused:
        return Refused(self.root, self._below(name), why, detail, kind)

    def _check_name(self, name: str) -> None:
        if name in ("", ".", "..") or "/" in name or "\0" in name:
            raise self._refuse(name, Why.BAD_NAME, "not a single plain name (not opened)")

    def lstat(self, name: str) -> os.stat_result | None:
        """``lstat`` of ``name`` in this folder, or None when there is nothing by that name."""
        self._check_name(name)
        try:
            return os.stat(name, dir_fd=self.fd, follow_symlinks=False)
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise self._refuse(name, Why.UNREADABLE,
                               f"cannot be looked at ({exc.strerror})") from exc

    def _wrong_kind(self, name: str, wanted: str) -> Refused:
        """The refusal for ``name``, which turned out not to be a ``wanted``."""
        info = self.lstat(name)
        if info is None:
            return self._refuse(name, Why.MISSING, "missing")
        kind = kind_of(info.st_mode)
        plain = "a plain folder" if wanted == "folder" else "a regular file"
        if kind == "symlink":
            return self._refuse(name, Why.LINK, f"a symlink, not {plain} (not followed)", kind)
        why = Why.NOT_A_FOLDER if wanted == "folder" else Why.NOT_REGULAR
        return self._refuse(name, why, f"a {kind}, not {plain}", kind)

    def entries(self) -> list[Entry]:
        """Every name in this folder, sorted, with what ``lstat`` says it is."""
        out = []
        for name in sorted(os.listdir(self.fd)):
            info = self.lstat(name)
            if info is not None:   # gone since the listing
                out.append(Entry(name, kind_of(info.st_mode), info.st_size))
        return out

    def folder(self, name: str, create: bool = False, mode: int = 0o755) -> Folder:
        """The sub-folder ``name`` (made with ``mode`` if missing and ``create``)."""
        self._check_name(name)
        if create:
            try:
                os.mkdir(name, mode, dir_fd=self.fd)
            except FileExistsError:
                pass
        try:
            fd = os.open(name, os.O_RDONLY | os.O_DIRECTORY | _OPEN, dir_fd=self.fd)
        except OSError as exc:
            if exc.errno in (errno.ENOENT, errno.ENOTDIR, errno.ELOOP):
                raise self._wrong_kind(name, "folder") from exc
            raise self._refuse(name, Why.UNREADABLE,
                               f"cannot be opened ({exc.strerror})") from exc
        return Folder(fd, self.root, self._below(name))

    def _open_file(self, name: str, cap: int) -> tuple[int, int]:
        """(descriptor, size) of the regular file ``name``, at most ``cap`` bytes."""
        info = self.lstat(name)
        if info is None or not stat.S_ISREG(info.st_mode):
            raise self._wrong_kind(name, "regular file")   # not opened: a pipe never blocks
        try:
            fd = os.open(name, os.O_RDONLY | _OPEN, dir_fd=self.fd)
        except OSError as exc:
            if exc.errno in (errno.ENOENT, errno.ELOOP):
                raise self._wrong_kind(name, "regular file") from exc
            raise self._refuse(name, Why.UNREADABLE,
                               f"cannot be opened ({exc.strerror})") from exc
        info = os.fstat(fd)   # what was opened, if it was swapped since the lstat
        if not stat.S_ISREG(info.st_mode):
            os.close(fd)
            kind = kind_of(info.st_mode)
            raise self._refuse(name, Why.NOT_REGULAR, f"a {kind}, not a regular file", kind)
        if info.st_size > cap:
            os.close(fd)
            raise self._refuse(name, Why.TOO_BIG, f"{info.st_size / 2**20:.1f} MB, over the "
                               f"{cap / 2**20:g} MB cap", "regular file")
        return fd, info.st_size

    def _chunks(self, name: str, cap: int):
        fd, _ = self._open_file(name, cap)
        try:
            size = 0
            while chunk := os.read(fd, _CHUNK):
                size += len(chunk)
                if size > cap:   # grew while read
                    raise self._refuse(name, Why.TOO_BIG, f"grew past the {cap / 2**20:g} MB "
                                       "cap while read", "regular file")
                yield chunk
        except OSError as exc:
            raise self._refuse(name, Why.UNREADABLE,
                               f"cannot be read ({exc.strerror})") from exc
        finally:
            os.close(fd)

    def read(self, name: str, cap: int) -> bytes:
        """The bytes of the regular file ``name`` in this folder, at most ``cap`` of them."""
        return b"".join(self._chunks(name, cap))

    def copy(self, name: str, dest: Path, cap: int, mode: int = 0o600) -> int:
        """Copy the regular file ``name`` to the new file ``dest`` (streamed); its size."""
        size = 0
        out = os.open(dest, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                      mode)
        try:
            with os.fdopen(out, "wb") as f:
                for chunk in self._chunks(name, cap):
                    f.write(chunk)
                    size += len(chunk)
        except BaseException:
            os.unlink(dest)
            raise
        return size


def _parts(relative: str | Sequence[str]) -> list[str]:
    if isinstance(relative, str):
        return [p for p in relative.split("/") if p] if relative not in ("", ".") else []
    return list(relative)


def open_folder(root, relative: str | Sequence[str] = (), *, create: bool = False,
                mode: int = 0o755) -> Folder:
    """The folder ``root/relative`` (a ``/``-separated string or a list of names), opened
    component by component without following a link; with ``create``, missing folders are
    made (``mode``) on the way. Raises :class:`Refused` (a ValueError)."""
    root = Path(root)
    try:
        fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY | _OPEN)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR, errno.ENOENT):
            try:
                info = os.lstat(root)
            except OSError:
                raise Refused(root, "", Why.MISSING, "missing") from exc
            kind = kind_of(info.st_mode)
            why = Why.LINK if kind == "symlink" else Why.NOT_A_FOLDER
            raise Refused(root, "", why, f"a {kind}, not a plain folder (not followed)",
                          kind) from exc
        raise Refused(root, "", Why.UNREADABLE, f"cannot be opened ({exc.strerror})") from exc
    folder = Folder(fd, root, "")
    try:
        for part in _parts(relative):
            child = folder.folder(part, create=create, mode=mode)
            folder.close()
            folder = child
    except BaseException:
        folder.close()
        raise
    return folder


def read_file(root, relative: str | Sequence[str], cap: int) -> bytes:
    """The bytes of the regular file ``root/relative``, no link followed on the way, at most
    ``cap`` of them. Raises :class:`Refused` (``why`` is ``MISSING`` when nothing is
    there)."""
    *folders, name = _parts(relative)
    with open_folder(root, folders) as folder:
        return folder.read(name, cap)


def copy_file(root, relative: str | Sequence[str], dest: Path, cap: int) -> int:
    """Copy the regular file ``root/relative`` (no link followed) to the new file ``dest``,
    private to this user (0600); returns its size. Raises :class:`Refused`."""
    *folders, name = _parts(relative)
    with open_folder(root, folders) as folder:
        return folder.copy(name, dest, cap)


def move_aside(root, relative: str | Sequence[str], suffix: str) -> None:
    """Rename ``root/relative`` to the same name plus ``suffix``, in its own folder (reached
    without following a link)."""
    *folders, name = _parts(relative)
    with open_folder(root, folders) as folder:
        folder._check_name(name + suffix)
        os.rename(name, name + suffix, src_dir_fd=folder.fd, dst_dir_fd=folder.fd)


@dataclass(frozen=True)
class TreeCaps:
    """What :func:`copy_tree` copies at most: bytes per file and in all, files, and folder
    depth (the copied folder is depth 0; a folder at ``depth`` is skipped)."""

    file_bytes: int
    total_bytes: int
    files: int
    depth: int


@dataclass(frozen=True)
class Skipped:
    """A name :func:`copy_tree` did not copy: ``path`` relative to the copied folder,
    ``name`` its last component, ``why`` a :class:`Why`, ``detail`` in words, ``kind``
    what it was (:func:`kind_of`)."""

    path: str
    name: str
    why: Why
    detail: str
    kind: str


def copy_tree(src: Folder, dest: Path, caps: TreeCaps, *, ignore=frozenset(),
              bad_name: Callable[[str], bool] = lambda name: False) -> list[Skipped]:
    """Copy the folders and regular files under ``src`` into the existing folder ``dest``,
    as data, in name order, within ``caps``; returns what was skipped. Names in ``ignore``
    are skipped silently, names ``bad_name`` refuses are skipped (``BAD_NAME``); links,
    pipes, sockets and devices are skipped (``LINK``, ``NOT_REGULAR``), never opened."""
    copy = _Copy(caps, ignore, bad_name, caps.total_bytes, caps.files)
    _copy_into(copy, src, dest, 0, "")
    return copy.skipped


@dataclass
class _Copy:
    """One :func:`copy_tree`: its rules, what is left of its budget, what it skipped."""

    caps: TreeCaps
    ignore: frozenset
    bad_name: Callable[[str], bool]
    bytes_left: int
    files_left: int
    skipped: list[Skipped] = field(default_factory=list)

    def skip(self, prefix: str, entry: Entry, why: Why, detail: str) -> None:
        """Note ``entry`` of the folder at path ``prefix`` as not copied, and why."""
        self.skipped.append(Skipped(prefix + entry.name, entry.name, why, detail, entry.kind))


def _copy_into(copy: _Copy, src: Folder, dest: Path, depth: int, prefix: str) -> None:
    """Copy what ``src`` (at ``depth``, its path ``prefix``) holds into ``dest``."""
    try:
        entries = src.entries()
    except (OSError, Refused) as exc:
        why = exc.detail if isinstance(exc, Refused) else exc.strerror
        copy.skipped.append(Skipped(prefix.rstrip("/"), src.where.rsplit("/", 1)[-1],
                                    Why.UNREADABLE, f"cannot be listed ({why})", "folder"))
        return
    for entry in entries:
        if entry.name in copy.ignore:
            continue
        if copy.bad_name(entry.name):
            copy.skip(prefix, entry, Why.BAD_NAME, "unusable file name")
        elif entry.kind == "folder":
            _copy_folder(copy, src, dest, entry, depth + 1, prefix)
        elif entry.kind != "regular file":
            copy.skip(prefix, entry, Why.LINK if entry.kind == "symlink" else Why.NOT_REGULAR,
                      f"{entry.kind}, not a regular file")
        elif copy.files_left <= 0:
            copy.skip(prefix, entry, Why.TOO_MANY, f"more than {copy.caps.files} files")
        else:
            _copy_file(copy, src, dest, entry, prefix)


def _copy_folder(copy: _Copy, parent: Folder, dest: Path, entry: Entry, depth: int,
                 prefix: str) -> None:
    """Copy the folder ``entry`` of ``parent`` (itself at ``depth``) into ``dest``."""
    if depth >= copy.caps.depth:
        copy.skip(prefix, entry, Why.TOO_DEEP, f"folders nested over {copy.caps.depth} deep")
        return
    try:
        child = parent.folder(entry.name)
    except Refused as exc:   # swapped since the listing
        copy.skip(prefix, entry, exc.why, exc.detail)
        return
    with child:
        (dest / entry.name).mkdir(mode=0o755)
        _copy_into(copy, child, dest / entry.name, depth, f"{prefix}{entry.name}/")


def _copy_file(copy: _Copy, src: Folder, dest: Path, entry: Entry, prefix: str) -> None:
    """Copy the regular file ``entry`` of ``src`` into ``dest``, within the budget left."""
    name = entry.name
    try:
        data = src.read(name, min(copy.caps.file_bytes, copy.bytes_left))
    except Refused as exc:
        copy.skip(prefix, entry, exc.why, exc.detail)
        return
    copy.bytes_left -= len(data)
    copy.files_left -= 1
    fd = os.open(dest / name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
                 | os.O_CLOEXEC, 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
