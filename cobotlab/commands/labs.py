"""``cobotlab labs``: the labs of a course: the students' copies (``student``), a new lab
(``new``), its grading checked (``verify``), a lab removed (``remove``)."""

from __future__ import annotations

import sys


def add_parser(sub) -> None:
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


def run(args) -> int:
    """Run the ``labs`` action; its exit status (0 unless ``verify`` or ``remove`` say
    otherwise)."""
    if args.labs_command == "student":
        _labs_student(args)
    elif args.labs_command == "remove":
        from cobotlab.removal import run_remove

        return run_remove(args.name, args.course, yes=args.yes)
    elif args.labs_command == "new":
        _labs_new(args.name, args.dir, args.from_lab)
    elif args.labs_command == "verify":
        from cobotlab.verify import run_verify

        return run_verify(args.path, draws=args.draws, json_out=args.json, worst=args.worst)
    return 0


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
