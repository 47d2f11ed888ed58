"""The ``cobotlab`` command line.

Errors reach the user as one clear line (``cobotlab: error: ...``) and exit code 2; pass
``--debug`` for the full traceback.
"""

from __future__ import annotations

import argparse
import sys

from cobotlab.commands import calibrate as calibrate_command
from cobotlab.commands import course as course_command
from cobotlab.commands import data as data_command
from cobotlab.commands import export as export_command
from cobotlab.commands import labs as labs_command
from cobotlab.commands import report as report_command


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="cobotlab",
        description="Course labs for robot hand-eye calibration and visual servoing.",
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser(
        "demo",
        help="the whole chain in simulation: calibrate the cameras, then pick and place chess pieces",
        description=(
            "Run the course chain in the PyBullet simulator: (1) flange calibration of a fixed "
            "camera, (2) eye-in-hand calibration with every method (ours and OpenCV's), the "
            "default result saved to OUT/flange_T_cam.yaml, (3) three chess pieces picked and "
            "placed by visual servoing with that calibration. Prints each part's errors against "
            "the simulator's truth and writes OUT/report.html with figures. With --synthetic: "
            "only the table of hand-eye methods on synthetic data (no simulator)."
        ),
    )
    demo.add_argument("--robot", default="panda",
                      help="arm to simulate: panda (default), ur10e, aubo_i5 or cobotta")
    demo.add_argument("--seed", type=int, default=0, help="scene and noise seed (default 0)")
    demo.add_argument("--noise", default="low", help="none, low (default) or high: image noise "
                      "and robot encoder offsets")
    demo.add_argument("--out", default="out", help="folder for report.html, figures and the "
                      "calibration YAML (default out/)")
    demo.add_argument("--quick", action="store_true",
                      help="fewer poses and 320x240 calibration images (for tests)")
    demo.add_argument("--poses", type=int, default=None,
                      help="eye-in-hand views (default 15, 10 with --quick; --synthetic: 15)")
    demo.add_argument("--synthetic", action="store_true",
                      help="only the synthetic table of every hand-eye method (no simulator)")
    synthetic = demo.add_argument_group("--synthetic only")
    synthetic.add_argument("--pixel-noise", type=float, default=None,
                           help="corner pixel noise, px (default 0.3)")
    synthetic.add_argument("--robot-noise-deg", type=float, default=None,
                           help="robot rotation noise per axis, degrees (default 0.05)")
    synthetic.add_argument("--robot-noise-mm", type=float, default=None,
                           help="robot translation noise per axis, mm (default 0.2)")

    calibrate_command.add_parser(sub)
    data_command.add_parser(sub)
    labs_command.add_parser(sub)
    course_command.add_parser(sub)

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

    merge = sub.add_parser(
        "merge",
        help="score here what shard jobs executed (cobotlab grade --students) and record it",
        description=(
            "Score the executions of ASSIGNMENT that each SHARD (a job's copy of the course, "
            "its problems written by `python -m autograder.shards job`, executed there with "
            "`cobotlab grade SHARD ASSIGNMENT --students @FILE`, without the secret) "
            "returned, against the truth drawn here, and record them in COURSE as "
            "`cobotlab grade --rescore` does. The shard's files are read as data; none sets "
            "a score, and nothing of it runs."),
    )
    merge.add_argument("course_dir", metavar="COURSE", help="the home course directory")
    merge.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    merge.add_argument("shards", metavar="SHARD", nargs="+", help="a graded copy of the course")

    export_command.add_parser(sub)
    report_command.add_parser(sub)

    robot = sub.add_parser("robot", help="talk to a robot cell (sim or real) without a notebook")
    robot_sub = robot.add_subparsers(dest="robot_command", metavar="ACTION", required=True)
    check = robot_sub.add_parser(
        "check",
        help="connect, print joints, flange pose and safety limits (moves nothing unless --jog)",
        description=(
            "Connect to a robot cell, read and print its joint positions, flange pose and the "
            "safety limits every move is checked against, then disconnect. Nothing moves "
            "unless --jog is given. Use it first whenever a real arm is (re)wired."
        ),
    )
    check.add_argument("--jog", action="store_true",
                       help="then jog the arm in small steps (<= 20 mm / 10 deg); every move asks y/N")
    check.add_argument("--kind", default=None,
                       help="sim (default), ur, franka, aubo or cobotta; or COBOTLAB_KIND / lab.toml")
    check.add_argument("--host", default=None, help="controller address for a real arm")
    check.add_argument("--arm", default=None, help="sim only: panda, ur5e, ur10e, aubo_i5, cobotta")
    check.add_argument("--realtime", default=None, choices=("enforce", "ignore"),
                       help="franka only: 'ignore' connects without a PREEMPT_RT kernel "
                            "(libfranka's kIgnore; motions may abort under load)")
    return parser


def _robot_check(kind, host, arm, jog: bool = False, realtime=None) -> None:
    import numpy as np

    from robots import connect
    from robots.geometry import rpy_from_pose

    options = {k: v for k, v in (("host", host), ("arm", arm), ("realtime", realtime))
               if v is not None}
    with connect(kind, **options) as cell:
        robot = cell.robot
        q = robot.joint_positions()
        T = robot.flange_pose()
        limits = robot.joint_limits()
        print(f"connected: {cell.kind} / {robot.name}")
        print("joints (deg):  " + "  ".join(f"{v:8.2f}" for v in np.degrees(q)))
        print("joint limits:  " + "  ".join(f"[{lo:.0f}, {hi:.0f}]" for lo, hi in np.degrees(limits)))
        print("flange (mm):   " + "  ".join(f"{v:8.1f}" for v in T[:3, 3] * 1000))
        print("flange rpy (deg, R = Rz(yaw) Ry(pitch) Rx(roll)): "
              + "  ".join(f"{v:7.2f}" for v in rpy_from_pose(T, degrees=True)))
        safety = robot.safety
        print(f"safety: workspace {np.round(safety.workspace_min * 1000)} .. "
              f"{np.round(safety.workspace_max * 1000)} mm, speed <= {safety.max_speed} m/s, "
              f"joint speed <= {safety.max_joint_speed} rad/s, step <= {safety.max_step * 1000:.0f} mm "
              f"/ {np.degrees(safety.max_rotation_step):.0f} deg, mode {safety.mode!r}")
        tool = robot.tool
        print(f"tool: {tool!r}" if tool is not None else "tool: none")
        moves = 0
        if jog:
            from robots.jog import run_jog_console

            moves = run_jog_console(cell)
    print("disconnected; " + ("nothing moved." if moves == 0 else f"{moves} jog move(s) made."))


def _demo(args) -> None:
    if args.synthetic:
        from cobotlab.demo import run_synthetic

        defaults = {"n_poses": 15, "pixel_px": 0.3, "robot_rot_deg": 0.05, "robot_trans_mm": 0.2}
        given = {"n_poses": args.poses, "pixel_px": args.pixel_noise,
                 "robot_rot_deg": args.robot_noise_deg, "robot_trans_mm": args.robot_noise_mm}
        run_synthetic(seed=args.seed, **{k: defaults[k] if v is None else v
                                         for k, v in given.items()})
        return
    for flag, value in (("--pixel-noise", args.pixel_noise),
                        ("--robot-noise-deg", args.robot_noise_deg),
                        ("--robot-noise-mm", args.robot_noise_mm)):
        if value is not None:
            raise ValueError(f"{flag} applies to --synthetic only; the simulation's noise is set "
                             "with --noise none|low|high")
    from cobotlab.demo import run_demo

    run_demo(robot=args.robot, seed=args.seed, noise=args.noise, out=args.out, quick=args.quick,
             n_poses=args.poses)


class _Parser(argparse.ArgumentParser):
    """argparse with usage mistakes reported as one line, like every other error."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _student_ids(spec: str | None) -> list[str] | None:
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


NOT_GRADED_EXIT = 3
"""`cobotlab grade`'s exit status when the grader itself failed on some submission (no
score recorded for it; the next run grades it again): a script or a cron job must notice."""


def _grade(args) -> int:
    from autograder.course import grade_course
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
            nbgrader_timeout_s=args.nbgrader_timeout, students=_student_ids(args.students),
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


def main(argv: list[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        if args.command == "demo":
            _demo(args)
        elif args.command == "calibrate":
            return calibrate_command.run(args)
        elif args.command == "data":
            data_command.run(args)
        elif args.command == "labs":
            return labs_command.run(args)
        elif args.command == "course":
            course_command.run(args)
        elif args.command == "grade":
            status = _grade(args)
            if status:
                return status
        elif args.command == "merge":
            from autograder.scratch import put_interpreter_on_path
            from autograder.shards import merge_shard

            put_interpreter_on_path()   # as for grade: nbgrader's gradebook needs `alembic`
            for shard in args.shards:
                merge_shard(args.course_dir, args.assignment, shard)
        elif args.command == "export":
            export_command.run(args)
        elif args.command == "report":
            report_command.run(args)
        elif args.command == "robot" and args.robot_command == "check":
            _robot_check(args.kind, args.host, args.arm, jog=args.jog, realtime=args.realtime)
    except KeyboardInterrupt:
        print("cobotlab: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one line for users; --debug shows where it came from
        if args.debug:
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"cobotlab: error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
