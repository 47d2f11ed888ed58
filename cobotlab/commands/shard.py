"""``cobotlab shard``: write a shard job's hidden problems into its copy of the course
(``autograder.shards.write_job``), before the job runs ``cobotlab grade --students``."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub) -> None:
    shard = sub.add_parser(
        "shard",
        help="write a shard job's problems into its copy of the course (before the job runs)",
        description=(
            "Draw here, from HOME's grading secret (which the job never gets), the hidden "
            "problems of the job's students and write only their inputs into JOB's "
            ".cobotlab/job/ASSIGNMENT/: no truth, no tolerance. A copy that holds the secret "
            "is refused. Then the job runs `cobotlab grade JOB ASSIGNMENT --students @FILE`, "
            "and `cobotlab merge` scores what it returns."),
    )
    shard.add_argument("home", metavar="HOME", help="the home course (holds the secret)")
    shard.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    shard.add_argument("job", metavar="JOB", help="the job's copy of the course")
    shard.add_argument("students", metavar="STUDENT", nargs="*",
                       help="the job's students (default: everyone who submitted)")


def run(args) -> None:
    from autograder.secret import PRIVATE_DIR
    from autograder.shards import write_job

    written = write_job(args.home, args.assignment, args.job, args.students or None)
    print(f"{args.assignment}: the problems of {len(written)} student(s) written into "
          f"{Path(args.job).resolve() / PRIVATE_DIR / 'job'}")
