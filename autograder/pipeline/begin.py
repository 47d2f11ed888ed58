"""Stage 1 of the grader's line, begin: the run's shared values (:class:`GradeRun`).

Checks the request (workers, fresh/replay/rescore, a shard job's copy), recovers from an
interrupted run, refuses a concurrent one and backs up the gradebook before anything else.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import stat
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from autograder import (
    gradebook,
    record,
    registry,
    sandbox,
    shard_job,
)
from autograder.feedback_release import (
    config_problem,
)
from autograder.freeze import printable
from autograder.grade_options import GradeOptions
from autograder.pipeline.problems import specs_of
from autograder.pipeline.worker import Limits
from autograder.record import read_private
from autograder.secret import PRIVATE_DIR, load_secret


def run_options(workers: int, options: GradeOptions | None, settings: dict) -> GradeOptions:
    """The run's one :class:`GradeOptions`: ``options``, or one made of ``workers`` and the
    keyword ``settings`` (TypeError names a keyword grade_course does not take)."""
    if options is None:
        return GradeOptions(workers=workers, **settings)
    if settings or workers != 1:
        raise TypeError("grade_course takes options= or keyword settings (workers included), "
                        f"not both: got options and {sorted(settings) or ['workers']}")
    return options


@dataclass
class GradeRun:
    """What every stage of one grade run shares: the course, the assignment, the secret
    and the run's nonce (None: the course's fixed problems), the limits, and the notes for
    the run's log."""

    root: Path
    private: Path
    assignment: str
    secret: str
    nonce: str | None
    problems: str              # "fixed", "fresh", "replay", "rescore" or "job" (runs.jsonl)
    limits: Limits
    notes: list[str]
    started: float
    options: GradeOptions = GradeOptions()


def _course(course_dir, assignment: str) -> Path:
    """The course's root, its labs registered, ``assignment`` one of them; ValueError
    names the known ones."""
    root = Path(course_dir).resolve()
    registry.use_course(root)
    specs_of(assignment)
    return root


def course_and_secret(course_dir, assignment: str) -> tuple[Path, str]:
    """(the course's root, its grading secret): see :func:`_course`."""
    root = _course(course_dir, assignment)
    return root, load_secret(root)


def _secret_or_job(root: Path, assignment: str, fresh, nonce, rescore, cluster) -> str:
    """The course's grading secret; "" for a shard job's copy, which must hold none and
    runs only the problems home wrote for it (:mod:`autograder.shard_job`)."""
    if not shard_job.is_job(root, assignment):
        return load_secret(root)
    shard_job.refuse_secret(root)
    if fresh or nonce or rescore or cluster is not None:
        raise ValueError("this course is a shard job's copy: it executes the problems home "
                         "wrote for it, and takes no fresh, replay, rescore or cluster")
    return ""


def begin(course_dir, assignment: str, options: GradeOptions, cluster) -> GradeRun:
    """Check the request, recover from an interrupted run, refuse a concurrent one, back up
    the gradebook; the run's shared values."""
    workers, limits, quiet = options.workers, options.limits, options.quiet
    fresh, nonce, rescore = options.fresh, options.nonce, options.rescore
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    root = _course(course_dir, assignment)
    secret = _secret_or_job(root, assignment, fresh, nonce, rescore, cluster)
    if fresh and nonce:
        raise ValueError("fresh=True draws new problems; nonce= replays a fresh run's: pass "
                         "one of them")
    if rescore and (fresh or nonce or cluster is not None):
        raise ValueError("rescore scores the executions the last grade run kept, on that "
                         "run's problems: it takes no fresh, replay or cluster")
    if nonce is not None and not re.fullmatch(r"[0-9a-f]{16,64}", nonce):
        raise ValueError(f"nonce {printable(nonce, 80)!r} is not one `cobotlab grade --fresh` "
                         "draws (16-64 hex digits): copy it from .cobotlab/runs.jsonl")
    problems = "job" if not secret else "rescore" if rescore else "fresh" if fresh else (
        "replay" if nonce else "fixed")
    nonce = secrets.token_hex(16) if fresh else nonce
    private = private_dir(root)
    started = time.monotonic()
    # a cluster whose workers would grade differently (lab version) is refused here
    cluster_note = cluster.check(assignment) if cluster is not None else None
    run = GradeRun(root, private, assignment, secret, nonce, problems, limits,
                   _begin_run(root, private), started, options)
    unverified = registry.verification_note(assignment)
    if unverified:
        run.notes.append(f"warning: {unverified}")
        if not quiet:
            print(f"warning: {unverified}", file=sys.stderr)
    if cluster_note:
        run.notes.append(cluster_note)
    old_config = config_problem(root)   # students' feedback would lack cobotlab's, or worse
    if old_config:
        run.notes.append(f"warning: {old_config}")
        if not quiet:
            print(f"warning: {old_config}", file=sys.stderr)
    return run


def private_dir(root: Path) -> Path:
    """The course's private folder (``.cobotlab/``, mode 0700), made if missing; ValueError
    when it is a link or not a folder."""
    private = root / PRIVATE_DIR
    private.mkdir(mode=0o700, exist_ok=True)
    if not stat.S_ISDIR(os.lstat(private).st_mode):
        raise ValueError(f"{private} is not a folder (a symlink?): refusing to grade")
    return private


def _begin_run(root: Path, private: Path) -> list[str]:
    """Recover from an interrupted run, refuse a concurrent one, back up the gradebook."""
    notes = []
    marker = private / record.RUN_MARKER
    stamp = read_private(private, record.RUN_MARKER)
    if stamp is not None:
        try:
            pid = int(json.loads(stamp).get("pid", 0))
        except (ValueError, AttributeError, TypeError):
            pid = 0
        if pid and pid != os.getpid() and sandbox.process_alive(pid):
            raise ValueError(f"another `cobotlab grade` (pid {pid}) is grading this course; "
                             f"wait for it, or remove {marker} if it is gone")
        problem = gradebook.problem(root / "gradebook.db")
        backup = private / "gradebook.backup.db"
        if problem and backup.is_file():
            gradebook.restore(root, backup)
            notes.append(f"the previous run was interrupted and gradebook.db was damaged "
                         f"({problem}): restored from its backup")
        else:
            notes.append("the previous run was interrupted; gradebook.db checked: "
                         + (problem or "ok"))
    removed = sandbox.remove_stale_scratch() + sandbox.remove_stale_folders()
    if removed:
        notes.append(f"removed {removed} scratch folder(s) left by an interrupted run")
    problem = gradebook.problem(root / "gradebook.db")
    if problem:
        raise ValueError(f"gradebook.db is damaged before grading ({problem}); restore it from "
                         f"{private / 'gradebook.backup.db'} or nbgrader's own backup first")
    gradebook.backup(root, private)
    record.write_file(private, record.RUN_MARKER, json.dumps(
        {"pid": os.getpid(), "started": datetime.now(timezone.utc).isoformat()}).encode())
    return notes
