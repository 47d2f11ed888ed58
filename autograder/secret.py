"""The course's grading secret: where it is kept and how it is read.

Every student's hidden problems are drawn from it
(:func:`autograder.pipeline.problems.problem_rng`), so it never leaves the instructor's machine: not into a sandbox, a cluster's worker or a shard
job. ``$COBOTLAB_GRADING_SECRET`` wins; otherwise ``<course>/.cobotlab/secret`` is read through
:mod:`autograder.safe_files` (a regular file, no link followed).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from autograder import (
    safe_files,
)

SECRET_ENV = "COBOTLAB_GRADING_SECRET"


PRIVATE_DIR = ".cobotlab"          # inside the course directory; never under source/ or release/


SECRET_FILE = "secret"


def create_secret(course_dir) -> Path:
    """Write a new random grading secret to ``<course>/.cobotlab/secret`` (mode 0600)."""
    private = Path(course_dir) / PRIVATE_DIR
    private.mkdir(mode=0o700, parents=True, exist_ok=True)
    path = private / SECRET_FILE
    if not path.exists():
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32) + "\n")
    return path


_SECRET_CAP = 4096   # bytes: a secret is 64 hex digits; anything past this is no secret


def load_secret(course_dir=None) -> str:
    """The grading secret: ``$COBOTLAB_GRADING_SECRET``, else ``<course>/.cobotlab/secret``,
    read through :mod:`autograder.safe_files` (a regular file, no link followed below the
    course: a link there could hand the grader a secret someone else chose, or leak which
    file it points at). ValueError names the problem and the fix."""
    value = os.environ.get(SECRET_ENV, "").strip()
    if not value and course_dir is not None:
        try:
            data = safe_files.read_file(Path(course_dir), [PRIVATE_DIR, SECRET_FILE],
                                        _SECRET_CAP)
        except safe_files.Refused as exc:
            if exc.why is not safe_files.Why.MISSING:
                raise ValueError(f"the grading secret {Path(course_dir) / PRIVATE_DIR / SECRET_FILE}"
                                 f" is refused: {exc.detail} ({exc.where}). Make it a regular "
                                 "file of the course (copy the content in, mode 0600), or set "
                                 f"${SECRET_ENV}") from None
            data = b""
        value = data.decode("utf-8", "replace").strip()
    if len(value) < 16:
        raise ValueError(
            f"no grading secret (at least 16 characters) found: set ${SECRET_ENV} or run "
            "init_course(DIR) / `cobotlab course init DIR`, which writes "
            f"DIR/{PRIVATE_DIR}/{SECRET_FILE}"
        )
    return value
