"""``cobotlab demo``: the whole chain in simulation, or only the synthetic table of
hand-eye methods (``cobotlab.demo``)."""

from __future__ import annotations


def add_parser(sub) -> None:
    demo = sub.add_parser(
        "demo",
        help="the whole chain in simulation: calibrate the cameras, then pick and place chess pieces",
        description=(
            "Run the course chain in the simulator (MuJoCo, or PyBullet where only it is installed; "
            "COBOTLAB_SIM_ENGINE chooses): (1) flange calibration of a fixed "
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


def run(args) -> None:
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
