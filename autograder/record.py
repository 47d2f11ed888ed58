"""The trusted side of grading: write into the instructor's course without losing anything.

* :func:`write_file` writes atomically (temp file + rename in the same folder) and never
  follows a symlink on the way (its folders are opened by :mod:`autograder.safe_files`,
  which every read of the trusted side goes through too); :func:`remove_file` removes one
  the same way.
* :func:`write_csv` escapes cells a spreadsheet would run (:func:`csv_cell`),
  :func:`update_csv` replaces only the rows of this run and keeps the others (read through
  :mod:`autograder.safe_files` too); :func:`drop_csv_rows` removes a lab's rows.
* :data:`RUN_MARKER` names the file a grading run leaves while it writes: a run interrupted
  half-way leaves it, and the next run sees it and acts on it.

nbgrader's gradebook (its backup, check and restore, and every score written into it) is
:mod:`autograder.gradebook`'s.
"""

from __future__ import annotations

import csv
import io
import os
import stat
import time
from pathlib import Path

from autograder import safe_files
from autograder.freeze import printable
from autograder.safe_files import Refused, Why, move_aside, read_file

__all__ = ["write_file", "remove_file", "write_csv", "update_csv", "drop_csv_rows", "csv_cell",
           "RUN_MARKER"]

RUN_MARKER = "grading-in-progress"
_CSV_CAP = 256 * 2**20   # grades.csv: about a million rows


# --------------------------------------------------------------------------- safe writing


def write_file(root: Path, relative: str, data: bytes) -> Path:
    """Write ``root/relative`` atomically, without following any symlink below ``root``.

    A symlink at the target itself is replaced (rename does not follow it); a directory
    there is moved aside to ``<name>.moved-<time>`` so the run still ends with the file.
    """
    parts = relative.split("/")
    name = parts[-1]
    if name in ("", ".", "..") or "\0" in name:
        raise ValueError(f"refusing to write {printable(relative)!r}: not a file name")
    folder = safe_files.open_folder(Path(root), parts[:-1], create=True)
    fd = folder.fd
    try:
        try:
            info = os.stat(name, dir_fd=fd, follow_symlinks=False)
            if stat.S_ISDIR(info.st_mode):
                os.rename(name, f"{name}.moved-{int(time.time())}", src_dir_fd=fd, dst_dir_fd=fd)
        except FileNotFoundError:
            pass
        temp = f".{name}.tmp-{os.getpid()}"
        out = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o644,
                      dir_fd=fd)
        with os.fdopen(out, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.rename(temp, name, src_dir_fd=fd, dst_dir_fd=fd)
    finally:
        folder.close()
    return Path(root) / relative


def remove_file(root: Path, relative: str) -> bool:
    """Remove ``root/relative`` if it is there (a link is removed, never followed), without
    following any symlink below ``root`` on the way. Returns whether something was removed;
    a folder there is left alone."""
    parts = relative.split("/")
    try:
        folder = safe_files.open_folder(Path(root), parts[:-1])
    except (OSError, ValueError):   # safe_files.Refused is a ValueError
        return False
    try:
        os.unlink(parts[-1], dir_fd=folder.fd)
        return True
    except (FileNotFoundError, IsADirectoryError, PermissionError):
        return False
    finally:
        folder.close()


def csv_cell(value):
    """A CSV cell a spreadsheet shows as text: ``= + - @`` (and tab, CR) at the start get a
    leading apostrophe; control characters are escaped. Numbers pass unchanged."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return value
    text = printable(value, 2000)
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def write_csv(root: Path, relative: str, columns: list[str], rows: list[dict]) -> Path:
    """Write ``rows`` (dicts; missing keys empty) as ``root/relative``, atomically, every cell
    through :func:`csv_cell`."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: csv_cell(row.get(k, "")) for k in columns})
    return write_file(root, relative, buffer.getvalue().encode("utf-8"))


def _ident(row: dict, key: tuple[str, ...]) -> tuple:
    """A row's key, compared as written: old rows were escaped already."""
    return tuple(str(csv_cell(row.get(k, ""))) for k in key)


def _kept_rows(root: Path, relative: str, columns: list[str],
               key: tuple[str, ...]) -> dict[tuple, dict]:
    """{key: row} of the CSV at ``root/relative`` as :func:`update_csv` keeps it: {} when
    there is none or it is not a regular file; one that is not readable CSV is moved aside."""
    kept: dict[tuple, dict] = {}
    data = None
    try:
        data = safe_files.read_file(root, relative, _CSV_CAP)
    except safe_files.Refused as exc:
        # Missing, or not a regular file (replaced below, never followed): nothing to keep.
        # Too big or unreadable: kept aside, as a file that is not CSV is.
        if exc.why in (safe_files.Why.TOO_BIG, safe_files.Why.UNREADABLE):
            safe_files.move_aside(root, relative, f".unreadable-{int(time.time())}")
    if data is not None:
        try:
            reader = csv.DictReader(io.StringIO(data.decode("utf-8"), newline=""))
            if reader.fieldnames is not None and not set(key) <= set(reader.fieldnames):
                raise ValueError(f"no {'/'.join(key)} columns")  # None: an empty file
            for row in reader:
                kept[_ident(row, key)] = {k: row.get(k) or "" for k in columns}
        except (ValueError, UnicodeDecodeError, csv.Error):
            safe_files.move_aside(root, relative, f".unreadable-{int(time.time())}")
            kept = {}
    return kept


def update_csv(root: Path, relative: str, columns: list[str], rows: list[dict],
               key: tuple[str, ...]) -> list[dict]:
    """Merge ``rows`` into the CSV at ``root/relative`` and write it back atomically.

    A row already there with the same ``key`` columns is replaced; every other row is kept
    as it was (columns it lacks stay empty, columns not in ``columns`` are dropped). Rows are
    sorted by ``key``. Anything but a regular file there (a symlink, say) is not read, and
    replaced as :func:`write_file` does; a regular file that is not readable CSV is moved
    aside to ``<name>.unreadable-<time>`` rather than lost. Returns every row written.
    """
    kept = _kept_rows(root, relative, columns, key)
    for row in rows:
        kept[_ident(row, key)] = row
    merged = [kept[k] for k in sorted(kept)]
    write_csv(root, relative, columns, merged)
    return merged


def drop_csv_rows(root: Path, relative: str, columns: list[str], key: tuple[str, ...],
                  column: str, value: str) -> int:
    """Remove the rows whose ``column`` is ``value`` from the CSV at ``root/relative`` (read
    and written back as :func:`update_csv` does; nothing is written when no row matches).
    Returns how many were removed."""
    kept = _kept_rows(root, relative, columns, key)
    gone = [k for k, row in kept.items() if row.get(column, "") == str(csv_cell(value))]
    if gone:
        for k in gone:
            del kept[k]
        write_csv(root, relative, columns, [kept[k] for k in sorted(kept)])
    return len(gone)


PRIVATE_CAP = 1 << 30   # a private file read back whole (runs.jsonl grows by a line a run)


def read_private(private: Path, name: str) -> bytes | None:
    """The bytes of ``private/name`` (``private`` itself no link either), or None: missing,
    or not a regular file (a link is not followed; the next write replaces it). One too
    big or unreadable is moved aside to ``<name>.unreadable-<time>``, not lost."""
    try:
        return read_file(private, name, PRIVATE_CAP)
    except Refused as exc:
        if exc.why in (Why.TOO_BIG, Why.UNREADABLE) and exc.where == name:
            move_aside(private, name, f".unreadable-{int(time.time())}")
        return None
