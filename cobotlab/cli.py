"""The ``cobotlab`` command line.

Errors reach the user as one clear line (``cobotlab: error: ...``) and exit code 2; pass
``--debug`` for the full traceback.
"""

from __future__ import annotations

import argparse
import sys

# `cobotlab calibrate --method`: besides solutions.handeye.METHODS
AUTO_METHOD = "auto"
CORNERS_METHOD = "corners"


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

    cal = sub.add_parser(
        "calibrate",
        help="solve the hand-eye calibration of a saved capture folder and write the YAML",
        description=(
            "Load a capture folder written by robots.capture (poses.npz, images/, meta.yaml), "
            "solve X (flange_T_cam for eye_in_hand, base_T_cam for eye_to_hand), print it with "
            "the residual of each view and the views the robust solver flagged, and save it "
            "with robots.calibration_io."
        ),
    )
    cal.add_argument("capture_dir", metavar="CAPTURE_DIR", help="a folder written by save_capture")
    cal.add_argument("--mount", default="eye_in_hand",
                     help="eye_in_hand (camera on the flange, default) or eye_to_hand")
    cal.add_argument("--method", default=AUTO_METHOD,
                     help="auto (default): corners when every view kept its board corners "
                          "(4 or more) and there are at least 4 views, else nonlinear; "
                          "corners: fit the detected corners themselves, the model (pixel-only, "
                          "a robot-error prior, the board's scale, or a pose-based fit) chosen "
                          "by held-out views (solutions.mle.calibrate_from_corners; best on the "
                          "real captures of benchmarks/handeye_real.py); nonlinear (robust, on "
                          "the board poses); tsai, park, daniilidis, axes_ls")
    cal.add_argument("--out", default=None,
                     help="result YAML (default CAPTURE_DIR/flange_T_cam.yaml or base_T_cam.yaml)")

    data = sub.add_parser(
        "data",
        help="list the real datasets shipped with cobotlab, or copy one out",
        description="Real captures shipped inside the package, with their source and licence.",
    )
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", required=True)
    data_sub.add_parser("list", help="name, description, source and licence of each dataset")
    export = data_sub.add_parser("export", help="copy a dataset's files (and README) to a folder")
    export.add_argument("name", metavar="NAME", help="a name from `cobotlab data list`")
    export.add_argument("dest", metavar="DIR", help="folder to copy into (created if needed)")
    imp = data_sub.add_parser(
        "import",
        help="make a capture folder for `cobotlab calibrate` from a pose text file and corners "
             "or images",
        description=(
            "Convert a hand-eye capture made elsewhere into a cobotlab capture folder. POSES is "
            "a text file with one base_T_flange per line: the 16 numbers of the 4 x 4 matrix, "
            "row-major, metres (as RWHE-Calib's RobotPosesVec.txt). The board comes either as "
            "--corners, an .npz with corners_px (n, N, 2), board_points_m (N, 3) and "
            "image_size_wh, or as --images (one image per pose, in name order) with --board. "
            "The intrinsics are calibrated from the corners (cv2.calibrateCamera)."
        ),
    )
    imp.add_argument("poses", metavar="POSES", help="robot pose text file, one pose per line")
    imp.add_argument("dest", metavar="CAPTURE_DIR", help="capture folder to write")
    board_source = imp.add_mutually_exclusive_group(required=True)
    board_source.add_argument("--corners", metavar="NPZ", help="detected corners (.npz)")
    board_source.add_argument("--images", metavar="DIR", help="folder of images, one per pose")
    imp.add_argument("--board", metavar="COLSxROWS:SQUARE_MM", default=None,
                     help="with --images: inner corners and square size, e.g. 8x6:39")
    imp.add_argument("--robot", default="", help="robot name to record (optional)")
    imp.add_argument("--camera", default="", help="camera name to record (optional)")
    imp.add_argument("--force", action="store_true", help="overwrite an existing capture folder")

    labs = sub.add_parser("labs", help="the labs: new ones, their verification, the students' "
                                       "copies (no solutions)")
    labs_sub = labs.add_subparsers(dest="labs_command", metavar="ACTION", required=True)
    student = labs_sub.add_parser(
        "student",
        help="write the student version of every lab into DIR (solutions and hidden tests out)",
        description=(
            "Write DIR/<lab>/<lab>.ipynb for every lab: the release version nbgrader's "
            "generate_assignment makes (solution regions replaced by `raise "
            "NotImplementedError()`, hidden tests removed, outputs cleared), with the lab's "
            "other files and a README. Give students DIR, never the repository's labs/. "
            "Needs nbgrader (the course extra) and the labs/ sources of a full checkout."
        ),
    )
    student.add_argument("dir", metavar="DIR", help="folder to write into (created if needed)")
    student.add_argument("--lab", action="append", default=None, metavar="LAB",
                         help="only this lab (repeat for several; default: every lab)")
    student.add_argument("--force", action="store_true",
                         help="replace notebooks already in DIR (they may hold a student's "
                              "work), and write labs whose last `labs verify` failed")
    _course_option(student, "the course whose own labs are written too")
    remove = labs_sub.add_parser(
        "remove",
        help="remove a lab from the course: its folders, gradebook entry and grades",
        description=(
            "Remove lab NAME from the course: nbgrader's source/, release/, submitted/, "
            "autograded/ and feedback/ folders of it (and its exchange outbound/inbound "
            "entries), its assignment in gradebook.db with every score, its rows of grades.csv, "
            "cobotlab's feedback, kept executions and verify record; for a course's own lab its "
            "folder and private spec too. A built-in lab stays in the package: it is added to "
            "removed_labs in the course's cobotlab.toml. Shows the plan and asks first."
        ),
    )
    remove.add_argument("name", metavar="NAME", help="the lab (its nbgrader assignment name)")
    _course_option(remove, "the course to remove it from")
    remove.add_argument("--yes", action="store_true",
                        help="remove without asking (for scripts; without it, a run with no "
                             "terminal is refused)")
    new = labs_sub.add_parser(
        "new",
        help="start a lab of your own in a course repository: from a skeleton, or a copy of a lab",
        description=(
            "Write a new lab NAME into the course folder: its nbgrader source notebook "
            "(LABS/NAME/NAME.ipynb), its public scoring (LABS/NAME/scoring.py, released with "
            "the notebook) and its private spec (.cobotlab/specs/NAME.py: the hidden problems, "
            "their truths, the classic mistakes; never released). LABS is the first of the "
            "lab_folders of the course's cobotlab.toml, which is created (lab_folders = "
            "[\"labs\"]) if the course has none. Without --from the lab is a skeleton with one "
            "graded function, ready to adapt; with --from it is a copy of that lab (built in or "
            "the course's) under the new name. Nothing is written if anything is refused."
        ),
    )
    new.add_argument("name", metavar="NAME",
                     help="the lab's name: a folder, an nbgrader assignment and part of a Python "
                          "module name (a letter, then letters, digits or _), e.g. lab6_gripper")
    new.add_argument("--dir", default=None, metavar="DIR",
                     help="the course folder (default: the current course, that of "
                          "$COBOTLAB_COURSE or the nearest cobotlab.toml above the current "
                          "folder, else the current folder)")
    new.add_argument("--from", dest="from_lab", default=None, metavar="LAB",
                     help="copy this lab (e.g. lab1_flange, or one of the course's) instead of "
                          "starting from the skeleton")
    verify = labs_sub.add_parser(
        "verify",
        help="check a lab's grading: correct code keeps full credit, each mistake loses it",
        description=(
            "Draw many sets of the hidden problems of the lab in PATH (its folder) and grade the "
            "notebook's solution and each of the spec's code mistakes on them; record the "
            "evidence beside the private specs, where `cobotlab grade` looks for it. Exits "
            "non-zero when the lab fails."
        ),
    )
    verify.add_argument("path", metavar="PATH", help="the lab: its folder (e.g. labs/lab6_gripper) or its name")
    verify.add_argument("--draws", type=int, default=None, metavar="N",
                        help="hidden draws per graded function (default 3688: with no loss, the "
                             "95 %% bound on the reference's loss rate is below 1e-3; use "
                             "10000 before a release)")
    verify.add_argument("--worst", action="store_true",
                        help="after the table, print each function's worst problem (where the "
                             "reference came closest to its tolerance) as a notebook cell: "
                             "the inputs as numpy literals, the call, the errors")
    verify.add_argument("--json", default=None, metavar="FILE",
                        help="write the JSON report to FILE instead of the course's "
                             ".cobotlab/verified/<lab>.json (where `cobotlab grade` looks)")

    course = sub.add_parser("course", help="lay out an nbgrader course for the labs")
    course_sub = course.add_subparsers(dest="course_command", metavar="ACTION", required=True)
    init = course_sub.add_parser(
        "init",
        help="write nbgrader_config.py, source/<lab>/ for every lab, and the grading secret",
        description=(
            "Lay out an nbgrader course in DIR: nbgrader_config.py, source/<assignment>/ for "
            "every lab, and the grading secret in DIR/.cobotlab/secret (mode 0600; keep it "
            "private). Safe to run again after adding a lab: sources and the secret are kept. "
            "Then `nbgrader generate_assignment <assignment>` in DIR makes the student version."
        ),
    )
    init.add_argument("dir", metavar="DIR", help="course directory (created if needed)")
    init.add_argument("--force", action="store_true",
                      help="lay out labs whose last `cobotlab labs verify` failed too (a lab "
                           "that does not load is always left out)")
    init.add_argument("--exchange", default=None, metavar="PATH",
                      help="nbgrader's exchange folder (default DIR/exchange; created). On a "
                           "JupyterHub, a folder every student's server mounts at this path")
    private = course_sub.add_parser(
        "exchange",
        help="as root: a private nbgrader exchange where no student reaches another's work",
        description=(
            "Set up (or bring up to date) nbgrader's exchange at ROOT for a machine many "
            "students share (JupyterHub spawning each student's server as their own Unix "
            "user): each student on the roster gets an inbound and a feedback folder of their "
            "own, which the instructors' group GROUP reads; nobody else can list, read, "
            "replace or delete them. Run as root; again after adding students. Every user's "
            "nbgrader then needs the lines this prints (or writes with --config) in its "
            "nbgrader_config.py. See docs/exchange.md."
        ),
    )
    private.add_argument("root", metavar="ROOT", help="the exchange folder (made if missing; "
                         "root-owned folders above it), e.g. /srv/nbgrader/exchange")
    private.add_argument("--students", required=True, metavar="ROSTER",
                         help="CSV with an id column (as for `nbgrader db student import`): "
                              "each student's Unix user name")
    private.add_argument("--instructors", required=True, metavar="GROUP",
                         help="the Unix group of the instructors (and the grading account)")
    private.add_argument("--course", default="cobotlab", metavar="ID",
                         help="nbgrader course id (default cobotlab, as `course init` writes)")
    private.add_argument("--config", default=None, metavar="FILE",
                         help="also write the nbgrader_config.py lines into FILE, e.g. "
                              "/etc/jupyter/nbgrader_config.py (other lines kept)")

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

    # Issue 40, parts 4 and 5: grades to the LMS and the class at a glance.
    export = sub.add_parser(
        "export", help="write a lab's grades as the LMS imports them (Canvas, Moodle, CSV)",
        description=(
            "Write the grades of ASSIGNMENT (the gradebook's after `cobotlab grade`: manual "
            "scores over automatic ones, less the late penalty) as Canvas' gradebook import, "
            "Moodle's CSV grade import, or a plain CSV, for the students of ROSTER (a CSV with "
            "a student_id column and the LMS's identity columns: docs/instructors.md, Grades "
            "to the LMS). A submission whose student is not in the roster is refused by name; "
            "a roster row with no submission, or an ungraded one, gets an empty cell and is "
            "named on stderr."))
    export.add_argument("course_dir", metavar="COURSE", help="course directory")
    export.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    export.add_argument("--format", required=True, choices=("canvas", "moodle", "csv"))
    export.add_argument("--roster", required=True, metavar="CSV",
                        help="student_id -> the LMS's identities, one row per student")
    export.add_argument("--out", default=None, metavar="FILE",
                        help="default COURSE/exports/ASSIGNMENT_FORMAT.csv")
    export.add_argument("--title", default=None,
                        help="the grade column's name (default: the assignment's)")
    export.add_argument("--canvas-id", default=None, metavar="N",
                        help="canvas: the Canvas assignment's id, so the column is 'TITLE (N)' "
                             "and updates that assignment (without it Canvas makes a new one)")
    export.add_argument("--moodle-id", default="email", choices=("email", "idnumber", "username"),
                        help="moodle: the roster column Moodle maps users by (default email)")
    export.add_argument("--missing", default="blank", choices=("blank", "zero"),
                        help="a roster row with no submission: empty cell (default) or 0")
    export.add_argument("--skip-unrostered", action="store_true",
                        help="leave out (and name) students who submitted but are not in the "
                             "roster, instead of refusing")
    class_report = sub.add_parser(
        "report", help="the class at a glance: an HTML page with figures and CSV files",
        description=(
            "Write COURSE/reports/ASSIGNMENT/index.html (and its figures and CSV files): the "
            "score distribution, each function's and check's share of students who lost "
            "credit, the named mistakes and who made them, each check's errors against its "
            "tolerance, late and ungraded submissions, and pairs of students whose graded "
            "functions are the same code up to names and formatting. Scores again, in this "
            "process, from the executions the last grade run kept: no student code runs."))
    class_report.add_argument("course_dir", metavar="COURSE", help="course directory")
    class_report.add_argument("assignment", metavar="ASSIGNMENT", help="e.g. lab0_frames")
    class_report.add_argument("--out", default=None, metavar="DIR",
                              help="default COURSE/reports/ASSIGNMENT")

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


def _calibrate(capture_dir, mount: str, method: str, out) -> None:
    """``cobotlab calibrate``: solve a saved capture, print X and its residuals, save the YAML."""
    from pathlib import Path

    import numpy as np

    from cobotlab.demo import per_pose_residuals, require_solutions
    from robots.calibration_io import save_calibration
    from robots.capture import load_capture
    from robots.geometry import rpy_from_pose

    require_solutions("calibrate")
    from solutions import handeye

    if mount not in handeye.MOUNTS:
        raise ValueError(f"--mount must be eye_in_hand or eye_to_hand, got {mount!r}")
    choices = (AUTO_METHOD, CORNERS_METHOD) + handeye.METHODS
    if method not in choices:
        raise ValueError(f"unknown --method {method!r}; choose one of {', '.join(choices)}")
    capture = load_capture(capture_dir)
    has_pose = np.all(np.isfinite(capture.cam_T_target), axis=(1, 2))
    F, C = capture.pose_pairs()
    views = capture.pose_indices[has_pose]
    if len(F) < 3:
        raise ValueError(f"{capture_dir} has {len(F)} views with a target pose; a hand-eye "
                         "calibration needs at least 3 (better 10-15) with varied orientations")
    mount_note = _mount_check(F, C, mount)
    solve = (handeye.calibrate_eye_in_hand_report if mount == "eye_in_hand"
             else handeye.calibrate_eye_to_hand_report)
    kept = np.flatnonzero(has_pose)
    auto_note = ""
    if method == AUTO_METHOD:
        method, auto_note = _auto_method(capture, kept)
    if method == CORNERS_METHOD:
        result, held_out_solve = _corner_calibration(capture, kept, F, C, mount)
    else:
        result = solve(F, C, method=method)

        def held_out_solve(f, c, rest):
            return solve(f, c, method=method).X, None, 1.0
    X = result.X
    parent = "flange" if mount == "eye_in_hand" else "base"
    rot, trans = per_pose_residuals(F, C, X, mount)
    flagged = [int(views[i]) for i in result.outlier_pose_indices]

    print(f"capture: {capture_dir} ({capture.robot_name or 'robot ?'}, "
          f"{capture.camera_name or 'camera ?'}, {len(F)} views, "
          f"{len(capture.failed_indices)} failed at capture)")
    print(f"{parent}_T_cam by {method} ({mount}){auto_note}:")
    for row in X:
        print("  [" + "  ".join(f"{v:11.6f}" for v in row) + "]")
    print("translation (mm): " + "  ".join(f"{v:.2f}" for v in X[:3, 3] * 1000))
    print("rpy (deg, R = Rz(yaw) Ry(pitch) Rx(roll)): "
          + "  ".join(f"{v:.3f}" for v in rpy_from_pose(X, degrees=True)))
    print(f"motion residuals: rotation {result.rotation_residual:.3g} (Frobenius^2), "
          f"translation {np.sqrt(result.translation_residual) * 1000:.3f} mm (rms)")
    print("residual per view (the board pose each view implies vs their mean):")
    worst = max(float(np.median(trans)) * 5, 1e-3)  # far above the typical view
    for k, (r, t) in enumerate(zip(rot, trans)):
        mark = "  <- flagged by the robust solver" if int(views[k]) in flagged else (
            "  <- large" if t > worst else "")
        print(f"  view {int(views[k]):3d}: {t * 1000:8.3f} mm {r:8.4f} deg{mark}")
    print(f"flagged views: {flagged or 'none'}")
    if method == CORNERS_METHOD:
        print(f"corner fit: {result.choice.label} chosen by held-out views "
              f"({result.choice.held_out_px:.3f} px; next best: "
              + ", ".join(f"{c.label} {c.held_out_px:.3f} px" for c in result.choices[1:3])
              + f"); corner RMS {result.reprojection_rms_px:.3f} px, board scale "
              f"{result.board_scale:.4f}")
    if len(F) >= 4 and all(len(capture.corners_px[i]) >= 4 for i in kept):
        held_out = _held_out_px(F, C, [capture.corners_px[i] for i in kept],
                                [capture.object_points[i] for i in kept], capture.intrinsics.K,
                                capture.intrinsics.dist, mount, held_out_solve)
        fixed = ", the chosen model kept" if method == CORNERS_METHOD else ""
        print(f"held-out error (each view's corners predicted by a calibration without it{fixed}, "
              f"through the robot pose): median {np.median(held_out):.2f} px, "
              f"p95 {np.percentile(held_out, 95):.2f} px, worst view "
              f"{int(views[int(np.argmax(held_out))])} at {held_out.max():.2f} px")
    if mount_note:
        print(mount_note)
    out = Path(out) if out else Path(capture_dir) / f"{parent}_T_cam.yaml"
    save_calibration(out, X, parent, "cam", method, len(F),
                     {"rotation_residual": result.rotation_residual,
                      "translation_residual_m2": result.translation_residual,
                      "per_pose_rotation_deg": rot, "per_pose_translation_m": trans},
                     robot_id=capture.robot_name, camera_id=capture.camera_name)
    print(f"saved {out}")


def _auto_method(capture, kept) -> tuple[str, str]:
    """``--method auto``: (the method, a note saying why) for this capture.

    The corner fit wins on the real captures of benchmarks/handeye_real.py (the pose-based
    ``nonlinear`` is the best of the rest there), but it needs every view's corners.
    """
    short = [int(capture.pose_indices[i]) for i in kept if len(capture.corners_px[i]) < 4]
    if len(kept) >= 4 and not short:
        return CORNERS_METHOD, " (auto: every view has its board corners)"
    if len(short) == len(kept):
        why = "no view has board corners (4 or more): the capture holds poses only"
    elif short:
        why = f"views {short} have fewer than 4 corners"
    else:
        why = f"only {len(kept)} views, the corner fit's cross-validation needs 4"
    return "nonlinear", f" (auto: {why})"


def _corner_calibration(capture, kept, F, C, mount: str):
    """``--method corners``: ``solutions.mle.calibrate_from_corners`` on the capture's corners.

    Returns (a result with X, outlier_pose_indices, rotation/translation_residual on the
    motions, and the chosen model and its rivals; a ``solve(F_rest, C_rest, rest)`` -> (X, Y,
    board scale) that refits the chosen model on a subset of the views, for the held-out error).
    """
    from types import SimpleNamespace

    import numpy as np

    from solutions import handeye, mle

    corners = [np.asarray(capture.corners_px[i], dtype=float) for i in kept]
    objects = [np.asarray(capture.object_points[i], dtype=float) for i in kept]
    if any(len(c) < 4 for c in corners):
        raise ValueError("--method corners needs at least 4 detected corners in every view with "
                         "a board pose; use another --method or drop those views")
    # One board for all views (each view may see a different subset of a ChArUco board's
    # corners): the distinct object points, and each view's pixels at their index (NaN unseen).
    board, index = np.unique(np.round(np.concatenate(objects), 9), axis=0, return_inverse=True)
    pixels = np.full((len(kept), len(board), 2), np.nan)
    start = 0
    for k, c in enumerate(corners):
        pixels[k, index.ravel()[start:start + len(c)]] = c
        start += len(c)
    K, dist = capture.intrinsics.K, capture.intrinsics.dist
    fit, choices = mle.calibrate_from_corners(board, pixels, K, dist, F, mount, C)
    A, B, _ = handeye.hand_eye_motions(F, C, mount)
    result = SimpleNamespace(X=fit.X, outlier_pose_indices=fit.outlier_indices,
                             rotation_residual=handeye.rotation_residual(A, B, fit.X),
                             translation_residual=handeye.translation_residual(A, B, fit.X),
                             choice=choices[0], choices=choices, board_scale=fit.board_scale,
                             reprojection_rms_px=fit.reprojection_rms_px)
    best = choices[0]

    def refit(f, c, rest):
        if best.method == "reprojection":
            r = mle.refine_reprojection(board, pixels[rest], K, dist, f, mount, X0=fit.X,
                                        Y0=fit.Y, robot_sigma=best.robot_sigma,
                                        fit_board_scale=best.fit_board_scale)
        else:  # a pose-based fit: only that candidate, its cross-validation is cheap
            r, _ = mle.calibrate_from_corners(board, pixels[rest], K, dist, f, mount, c,
                                              robot_weights=(), pose_candidates=(best.method,),
                                              folds=2)
        return r.X, r.Y, r.board_scale

    return result, refit


def _mount_check(F, C, mount: str) -> str:
    """Refuse views that fit the other mount far better; return a warning when they fit both
    about equally (``solutions.diagnostics``, the check every hand-eye solver makes), else ""."""
    from solutions import diagnostics

    d = diagnostics.diagnose_hand_eye(F, C, mount, full=True)
    other = "eye_to_hand" if mount == "eye_in_hand" else "eye_in_hand"
    if d.verdict == "flipped":
        raise ValueError(
            f"these views fit --mount {other} far better (median rotation residual "
            f"{d.flipped_residual_deg:.3g} deg per view against {d.residual_deg:.3g} deg, "
            f"{d.ratio:.0f} times what their noise explains): check where the camera is mounted, "
            "and that base_T_flange is not inverted (flange_T_base) nor cam_T_target "
            "(target_T_cam)")
    if d.verdict == "ok" and diagnostics.mounts_indistinguishable(d):
        return (f"WARNING: these views fit --mount {other} as well (median rotation residual "
                f"{d.flipped_residual_deg:.3g} deg against {d.residual_deg:.3g} deg), so they "
                "cannot tell the two mounts apart and the result rests on --mount being right. "
                "Add views that roll the camera about its viewing axis (15-45 deg) to make it "
                "unambiguous")
    return ""


def _datasets() -> dict:
    """Shipped datasets: folder name -> (folder Traversable, title, source line, licence line),
    read from each data folder's README (its title, first paragraph and Licence section)."""
    from importlib import resources

    found = {}
    root = resources.files("autograder").joinpath("data")
    for folder in sorted(root.iterdir(), key=lambda f: f.name):
        readme = folder.joinpath("README.md")
        if not readme.is_file():
            continue
        lines = readme.read_text().splitlines()
        title = next((text[2:].strip() for text in lines if text.startswith("# ")), folder.name)
        body = lines[lines.index(next(text for text in lines if text.startswith("# "))) + 1:]
        paragraph = []
        for line in body:
            if line.strip():
                paragraph.append(line.strip())
            elif paragraph:
                break
        source = " ".join(paragraph)
        licence = ""
        if "## Licence" in lines:
            after = lines[lines.index("## Licence") + 1:]
            licence = next((text.strip() for text in after if text.strip()), "")
        found[folder.name] = (folder, title, source, licence)
    return found


def _data_list() -> None:
    for name, (folder, title, source, licence) in _datasets().items():
        files = [f.name for f in folder.iterdir() if f.is_file()]
        print(f"{name}: {title}")
        print(f"  source:  {source}")
        print(f"  licence: {licence or 'see README.md'}")
        print(f"  files:   {', '.join(sorted(files))}")


def _data_export(name: str, dest) -> None:
    import shutil
    from importlib import resources
    from pathlib import Path

    datasets = _datasets()
    if name not in datasets:
        raise ValueError(f"no dataset named {name!r}; `cobotlab data list` shows: "
                         f"{', '.join(datasets) or 'none'}")
    folder = datasets[name][0]
    dest = Path(dest)
    files = [f for f in folder.iterdir() if f.is_file()]
    clashes = [f.name for f in files if (dest / f.name).exists()]
    if clashes:
        raise FileExistsError(f"{dest} already has {', '.join(clashes)}; export into an empty "
                              "folder or remove those files first")
    dest.mkdir(parents=True, exist_ok=True)
    for f in files:
        with resources.as_file(f) as source:
            shutil.copyfile(source, dest / f.name)
        print(f"copied {dest / f.name}")


def _data_import(args) -> None:
    """``cobotlab data import``: pose text file + corners or images -> a capture folder."""
    import re

    from robots.capture import import_pose_text_capture, save_capture

    board = None
    if args.images is not None:
        match = re.fullmatch(r"(\d+)x(\d+):([0-9.]+)", args.board or "")
        if not match:
            raise ValueError("--images needs --board COLSxROWS:SQUARE_MM (inner corners and the "
                             "square size in millimetres), e.g. --board 8x6:39")
        board = (int(match[1]), int(match[2]), float(match[3]) / 1000.0)
    capture = import_pose_text_capture(args.poses, corners_file=args.corners,
                                       images_dir=args.images, board=board,
                                       robot_name=args.robot, camera_name=args.camera)
    folder = save_capture(capture, args.dest, overwrite=args.force)
    i = capture.intrinsics
    print(f"imported {len(capture)} views ({len(capture.failed_indices)} without the board) "
          f"into {folder}; intrinsics fx {i.fx:.1f} fy {i.fy:.1f} cx {i.cx:.1f} cy {i.cy:.1f} "
          f"px, dist {' '.join(f'{v:.4f}' for v in i.dist)}")
    print(f"next: cobotlab calibrate {folder} --mount eye_in_hand (or eye_to_hand)")


def _held_out_px(F, C, corners, objects, K, dist, mount: str, solve):
    """RMS pixel error of each view's corners predicted by a calibration without that view.

    For view k: ``solve(F_rest, C_rest, rest)`` -> (X, Y or None, board scale) on the other
    views (``rest`` their mask), Y when None as the chordal mean of what those views imply,
    then the corners (object points times the scale) projected through ``inv(X) @ H_k @ Y``
    with H_k = inv(base_T_flange_k) (eye-in-hand) or base_T_flange_k (eye-to-hand)."""
    import warnings

    import cv2
    import numpy as np

    from robots import geometry as geo

    errors = []
    for k in range(len(F)):
        rest = np.arange(len(F)) != k
        with warnings.catch_warnings():  # the full fit has already warned about these views
            warnings.simplefilter("ignore", UserWarning)
            X, Y, board_scale = solve(F[rest], C[rest], rest)
        H = geo.invert(F) if mount == "eye_in_hand" else F
        if Y is None:
            implied = geo.invert(H[rest]) @ X @ C[rest]
            Y = geo.make_pose(geo.chordal_mean_rotation(implied), implied[:, :3, 3].mean(axis=0))
        pose = geo.invert(X) @ H[k] @ Y
        proj, _ = cv2.projectPoints(board_scale * objects[k], cv2.Rodrigues(pose[:3, :3])[0],
                                    pose[:3, 3], K, dist)
        errors.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - corners[k]) ** 2, axis=1)))))
    return np.array(errors)


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


def _labs_new(name: str, course_dir, from_lab) -> None:
    """``cobotlab labs new``: write the lab, then say what was written and what comes next."""
    import os

    from autograder import registry
    from cobotlab.authoring import new_lab, next_steps

    if course_dir is None:   # inside a course, its lab goes there, wherever the shell is
        course_dir = registry.course_root() or "."
    written = new_lab(name, course_dir, from_lab=from_lab)
    for path in written:
        print(f"wrote {os.path.relpath(path)}")
    print("next:")
    for number, step in enumerate(next_steps(written, course_dir), 1):
        print(f"  {number}. {step}")


def _course_option(parser, what: str) -> None:
    """``--course COURSE`` of the lab commands that work on one course, found as git finds
    its repository when not given."""
    parser.add_argument("--course", default=None, metavar="COURSE",
                        help=f"{what} (default: that of $COBOTLAB_COURSE, else the nearest "
                             "cobotlab.toml at or above the current folder)")


def _labs_student(args) -> None:
    """``cobotlab labs student``: the course named, or found from here (said when none is)."""
    from autograder import registry
    from cobotlab.labs import write_student_labs

    if args.course is not None:
        from pathlib import Path

        course = Path(args.course).expanduser().resolve()
        if not any((course / f).is_file() for f in (registry.CONFIG_NAME, "nbgrader_config.py")):
            raise ValueError(f"--course {args.course}: not a course (no {registry.CONFIG_NAME} "
                             "or nbgrader_config.py there); give the course folder, the one "
                             "`cobotlab course init` or `cobotlab labs new` wrote into")
        registry.use_course(course)
    elif registry.course_root() is None and registry.builtin_folder().is_dir():
        # said, so a course's own labs are never left out unseen (a student's install has
        # no lab sources at all, and the error below says so)
        print(f"cobotlab: no course found (no {registry.CONFIG_NAME} here or above, "
              f"${registry.COURSE_ENV} unset): writing the built-in labs only; pass --course "
              "DIR for a course's own labs", file=sys.stderr)
    for path in write_student_labs(args.dir, labs=args.lab, force=args.force):
        print(f"wrote {path}")


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
            _calibrate(args.capture_dir, args.mount, args.method, args.out)
        elif args.command == "data" and args.data_command == "list":
            _data_list()
        elif args.command == "data" and args.data_command == "export":
            _data_export(args.name, args.dest)
        elif args.command == "data" and args.data_command == "import":
            _data_import(args)
        elif args.command == "labs" and args.labs_command == "student":
            _labs_student(args)
        elif args.command == "labs" and args.labs_command == "remove":
            from cobotlab.removal import run_remove

            return run_remove(args.name, args.course, yes=args.yes)
        elif args.command == "labs" and args.labs_command == "new":
            _labs_new(args.name, args.dir, args.from_lab)
        elif args.command == "labs" and args.labs_command == "verify":
            from cobotlab.verify import run_verify

            return run_verify(args.path, draws=args.draws, json_out=args.json,
                              worst=args.worst)
        elif args.command == "course" and args.course_command == "init":
            from autograder.course import init_course
            from cobotlab.authoring import write_gitignore

            course = init_course(args.dir, exchange=args.exchange, force=args.force)
            print(f"course laid out in {course}")
            # the secret it just drew, and the grades to come, must never reach a repository
            if write_gitignore(course):
                print(f"{course / '.gitignore'} keeps the grading secret and the students' "
                      "data out of git")
        elif args.command == "course" and args.course_command == "exchange":
            from autograder import exchange

            done = exchange.set_up(args.root, exchange.read_roster(args.students),
                                   args.instructors, course_id=args.course)
            for line in done.changed + [f"warning: {w}" for w in done.warnings]:
                print(line)
            if args.config:
                print(f"wrote {exchange.write_config(args.config, args.root, args.course)}")
            else:
                print("Put these lines in every user's nbgrader_config.py "
                      "(/etc/jupyter/nbgrader_config.py):\n"
                      + exchange.config_block(args.root, args.course))
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
            from cobotlab.lms_export import run_export

            run_export(args)
        elif args.command == "report":
            from cobotlab.class_report import run_report

            run_report(args)
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
