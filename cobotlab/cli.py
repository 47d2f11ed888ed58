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
    return parser


def _robot_check(kind, host, arm, jog: bool = False) -> None:
    import numpy as np

    from robots import connect
    from robots.geometry import rpy_from_pose

    options = {k: v for k, v in (("host", host), ("arm", arm)) if v is not None}
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
        elif args.command == "robot" and args.robot_command == "check":
            _robot_check(args.kind, args.host, args.arm, jog=args.jog)
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
