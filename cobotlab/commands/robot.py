"""``cobotlab robot check``: talk to a robot cell (sim or real) without a notebook."""

from __future__ import annotations


def add_parser(sub) -> None:
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


def check(kind, host, arm, jog: bool = False, realtime=None) -> None:
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


def run(args) -> None:
    if args.robot_command == "check":
        check(args.kind, args.host, args.arm, jog=args.jog, realtime=args.realtime)
