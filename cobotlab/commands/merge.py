"""``cobotlab merge``: score at home what shard jobs executed, and record it
(``autograder.shards.merge_shard``)."""

from __future__ import annotations


def add_parser(sub) -> None:
    merge = sub.add_parser(
        "merge",
        help="score here what shard jobs executed (cobotlab grade --students) and record it",
        description=(
            "Score the executions of ASSIGNMENT that each SHARD (a job's copy of the course, "
            "its problems written by `cobotlab shard`, executed there with "
            "`cobotlab grade SHARD ASSIGNMENT --students @FILE`, without the secret) "
            "returned, against the truth drawn here, and record them in COURSE as "
            "`cobotlab grade --rescore` does. The shard's files are read as data; none sets "
            "a score, and nothing of it runs."),
    )
    merge.add_argument("course_dir", metavar="COURSE", help="the home course directory")
    merge.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    merge.add_argument("shards", metavar="SHARD", nargs="+", help="a graded copy of the course")


def run(args) -> None:
    from autograder.scratch import put_interpreter_on_path
    from autograder.shards import merge_shard

    put_interpreter_on_path()   # as for grade: nbgrader's gradebook needs `alembic`
    for shard in args.shards:
        merge_shard(args.course_dir, args.assignment, shard)
