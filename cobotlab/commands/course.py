"""``cobotlab course``: lay out an nbgrader course (``init``), or, as root, a private
exchange for a shared machine (``exchange``)."""

from __future__ import annotations


def add_parser(sub) -> None:
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


def run(args) -> None:
    if args.course_command == "init":
        from autograder.course import init_course
        from cobotlab.authoring import write_gitignore

        course = init_course(args.dir, exchange=args.exchange, force=args.force)
        print(f"course laid out in {course}")
        # the secret it just drew, and the grades to come, must never reach a repository
        if write_gitignore(course):
            print(f"{course / '.gitignore'} keeps the grading secret and the students' "
                  "data out of git")
    elif args.course_command == "exchange":
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
