"""``cobotlab export``: a lab's grades as the LMS imports them (``cobotlab.lms_export``)."""

from __future__ import annotations


def add_parser(sub) -> None:
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


def run(args) -> None:
    from cobotlab.lms_export import run_export

    run_export(args)
