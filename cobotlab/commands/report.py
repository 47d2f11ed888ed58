"""``cobotlab report``: the class at a glance (``cobotlab.class_report``)."""

from __future__ import annotations


def add_parser(sub) -> None:
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


def run(args) -> None:
    from cobotlab.class_report import run_report

    run_report(args)
