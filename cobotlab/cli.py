"""The ``cobotlab`` command line.

Errors reach the user as one clear line (``cobotlab: error: ...``) and exit code 2; pass
``--debug`` for the full traceback.
"""

from __future__ import annotations

import argparse
import sys


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cobotlab",
        description="Course labs for robot hand-eye calibration and visual servoing.",
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser(
        "demo",
        help="solve seeded hand-eye problems with every method and print errors against the truth",
        description=(
            "Draw a seeded eye-in-hand and an eye-to-hand problem (board corners with pixel "
            "noise, robot poses with encoder-level noise), solve each with every reference "
            "method and with OpenCV, and print the error of each against the known truth."
        ),
    )
    demo.add_argument("--seed", type=int, default=0, help="problem seed (default 0)")
    demo.add_argument("--poses", type=int, default=15, help="number of robot poses (default 15)")
    demo.add_argument("--pixel-noise", type=float, default=0.3,
                      help="corner pixel noise, px (default 0.3)")
    demo.add_argument("--robot-noise-deg", type=float, default=0.05,
                      help="robot rotation noise per axis, degrees (default 0.05)")
    demo.add_argument("--robot-noise-mm", type=float, default=0.2,
                      help="robot translation noise per axis, mm (default 0.2)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        if args.command == "demo":
            from cobotlab.demo import run_demo

            run_demo(seed=args.seed, n_poses=args.poses, pixel_px=args.pixel_noise,
                     robot_rot_deg=args.robot_noise_deg, robot_trans_mm=args.robot_noise_mm)
    except KeyboardInterrupt:
        print("cobotlab: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one line for users; --debug shows where it came from
        if args.debug:
            raise
        print(f"cobotlab: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
