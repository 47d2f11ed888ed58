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
from cobotlab.commands import demo as demo_command
from cobotlab.commands import export as export_command
from cobotlab.commands import grade as grade_command
from cobotlab.commands import labs as labs_command
from cobotlab.commands import merge as merge_command
from cobotlab.commands import report as report_command
from cobotlab.commands import robot as robot_command
from cobotlab.commands import shard as shard_command

# Kept importable from here: scripts and tests name them as cobotlab.cli's.
NOT_GRADED_EXIT = grade_command.NOT_GRADED_EXIT
_student_ids = grade_command.student_ids

# In --help's order. Each module declares its arguments and runs its command; run()
# returns None (exit 0) or the exit status.
_COMMANDS = {
    "demo": demo_command,
    "calibrate": calibrate_command,
    "data": data_command,
    "labs": labs_command,
    "course": course_command,
    "grade": grade_command,
    "shard": shard_command,
    "merge": merge_command,
    "export": export_command,
    "report": report_command,
    "robot": robot_command,
}


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="cobotlab",
        description="Course labs for robot hand-eye calibration and visual servoing.",
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in _COMMANDS.values():
        command.add_parser(sub)
    return parser


class _Parser(argparse.ArgumentParser):
    """argparse with usage mistakes reported as one line, like every other error."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def main(argv: list[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return _COMMANDS[args.command].run(args) or 0
    except KeyboardInterrupt:
        print("cobotlab: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one line for users; --debug shows where it came from
        if args.debug:
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"cobotlab: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
