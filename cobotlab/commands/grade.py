"""``cobotlab grade``: autograde every submission of an assignment
(``autograder.pipeline.pipeline.grade_course``) and write grades.csv."""

from __future__ import annotations

import sys

NOT_GRADED_EXIT = 3
"""`cobotlab grade`'s exit status when the grader itself failed on some submission (no
score recorded for it; the next run grades it again): a script or a cron job must notice."""


def add_parser(sub) -> None:
    grade = sub.add_parser(
        "grade",
        help="autograde every submission of an assignment on hidden problems; write grades.csv",
        description=(
            "Grade every submission in COURSE/submitted/*/ASSIGNMENT in three stages: freeze "
            "the submissions (regular files only, copied before any student code runs); run "
            "each student's nbgrader autograde in a throwaway sandboxed course and the "
            "isolated grader on hidden problems drawn from the course secret, the assignment, "
            "the student and the function, the same on every regrade (bubblewrap, "
            "one cgroup per submission, no network, the course and the answer key out of "
            "sight); record validated numbers into gradebook.db (backed up and checked). "
            "Writes COURSE/grades.csv (nbgrader's export columns plus flags) and per-student "
            "feedback HTML in COURSE/feedback_cobotlab/, and prints a summary."
        ),
    )
    grade.add_argument("course_dir", metavar="COURSE", help="course directory (from `course init`)")
    grade.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    grade.add_argument("--workers", type=int, default=None,
                       help="parallel graders (default 1; with --cluster, the cluster's)")
    grade.add_argument("--no-nbgrader", action="store_true",
                       help="skip nbgrader's autograde; use the results gradebook.db already has")
    grade.add_argument("--nbgrader-kernel", action="store_true",
                       help="run nbgrader's autograde in its own kernel (a second, sandboxed "
                            "run of each notebook: slower, but the autograded notebooks keep "
                            "plots and check() tables); default: its cells run once, by the "
                            "grader's worker")
    grade.add_argument("--no-template", action="store_true",
                       help="start a new interpreter for every submission instead of forking "
                            "each from a template that loaded the lab's imports and first "
                            "read-only cells once (same results, slower; for comparison)")
    grade.add_argument("--nbgrader-timeout", type=float, default=300, metavar="S",
                       help="wall clock of one student's nbgrader kernel run (default 300 s)")
    grade.add_argument("--students", default=None, metavar="IDS",
                       help="grade only these students: a,b,c or @FILE (one id a line); a "
                            "shard of the class, e.g. one job of many")
    grade.add_argument("--no-progress", action="store_true",
                       help="no progress bar on stderr")
    grade.add_argument("--cluster", default=None, metavar="ADDRESS",
                       help="grade on a Dask cluster (the `cluster` extra): tls://HOST:PORT "
                            "(a scheduler with TLS client certificates), `gateway` (a new "
                            "dask-gateway cluster of --workers workers, shut down after) or "
                            "gateway:NAME / gateway://HOST:PORT/NAME (an existing one); each "
                            "worker runs submissions in its own sandbox on the inputs of "
                            "their problems (it needs no grading secret); tcp:// is refused. "
                            "--workers: submissions in flight (default: the cluster's threads)")
    grade.add_argument("--tls-ca-file", default=None, metavar="PEM",
                       help="with --cluster tls://: the cluster's CA (default: Dask's config "
                            "distributed.comm.tls.ca-file)")
    grade.add_argument("--tls-cert", default=None, metavar="PEM",
                       help="with --cluster tls://: this client's certificate, signed by the CA")
    grade.add_argument("--tls-key", default=None, metavar="PEM",
                       help="with --cluster tls://: its key (if not in --tls-cert's file)")
    redraw = grade.add_mutually_exclusive_group()
    redraw.add_argument("--fresh", action="store_true",
                        help="draw new hidden problems for this run (its nonce goes to "
                             "COURSE/.cobotlab/runs.jsonl); default: the course's fixed ones")
    redraw.add_argument("--replay", default=None, metavar="NONCE",
                        help="the problems of an earlier --fresh run (its nonce in runs.jsonl)")
    redraw.add_argument("--rescore", action="store_true",
                        help="run no student code: score every submission again from what "
                             "its code did in the last grade run (kept in COURSE/.cobotlab/"
                             "executions/), after a change to the lab's tolerances, points, "
                             "bands or mistakes; refused, naming them, for a submission "
                             "handed in again since, or when the change altered the "
                             "problems' inputs")


def student_ids(spec: str | None) -> list[str] | None:
    """``a,b,c`` or ``@FILE`` (one id a line, ``#`` comments) -> ids; None: everyone."""
    if spec is None:
        return None
    if spec.startswith("@"):
        from pathlib import Path

        lines = Path(spec[1:]).expanduser().read_text().splitlines()
        ids = [line.split("#", 1)[0].strip() for line in lines]
    else:
        ids = [part.strip() for part in spec.split(",")]
    ids = [i for i in ids if i]
    if not ids:
        raise ValueError(f"--students {spec!r} names no student")
    return ids


def run(args) -> int:
    from autograder.pipeline.pipeline import grade_course
    from autograder.scratch import put_interpreter_on_path

    put_interpreter_on_path()   # nbgrader finds `alembic` without an activated venv
    bar = None

    def progress(done: int, total: int, student: str) -> None:
        nonlocal bar
        if bar is None:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="submission", desc=f"grading {args.assignment}",
                       file=sys.stderr, dynamic_ncols=True)
        if done:
            bar.set_postfix_str(student[:40], refresh=False)
            bar.update(done - bar.n)
        if done == total:   # before the summary is printed below it
            bar.close()

    cluster = None
    if args.cluster is None:
        if args.tls_ca_file or args.tls_cert or args.tls_key:
            raise ValueError("--tls-ca-file, --tls-cert and --tls-key go with --cluster tls://")
    else:
        from autograder import cluster as dask_cluster

        security = None
        if args.cluster.strip().startswith("tls://"):
            security = dask_cluster.security_from(args.tls_ca_file, args.tls_cert,
                                                  args.tls_key)
        cluster = dask_cluster.connect(args.cluster, security=security, workers=args.workers)
    try:
        workers = args.workers if args.workers is not None else (
            cluster.slots() if cluster is not None else 1)
        rows = grade_course(
            args.course_dir, args.assignment, workers=workers,
            run_nbgrader=not args.no_nbgrader, nbgrader_kernel=args.nbgrader_kernel,
            nbgrader_timeout_s=args.nbgrader_timeout, students=student_ids(args.students),
            progress=None if args.no_progress else progress, fresh=args.fresh,
            nonce=args.replay, cluster=cluster, template=not args.no_template,
            rescore=args.rescore)
    finally:
        if bar is not None:
            bar.close()
        if cluster is not None:
            cluster.close()
    # a row the grader could not grade has no raw score (course.grade_row)
    return NOT_GRADED_EXIT if any(row["raw_score"] == "" for row in rows) else 0
