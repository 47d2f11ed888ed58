"""The command line: help, one-line errors, --debug tracebacks, demo, calibrate, data."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cobotlab import cli
from robots.calibration_io import load_calibration
from robots.geometry import compose, invert, make_pose, rotation_error_deg, translation_error


def _one_line_error(capsys, argv, *fragments):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cobotlab: error:"), err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for fragment in fragments:
        assert fragment in err, err
    return err


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["--help"])
    assert excinfo.value.code == 0
    out = capsys.readouterr().out
    for command in ("demo", "calibrate", "data", "robot"):
        assert command in out


def test_every_command_is_its_own_module_and_cli_only_dispatches(capsys):
    source = Path(cli.__file__).read_text()
    assert source.count("add_argument(") == 1, "cli.py declares only --debug"
    assert "add_parser(" not in source.replace("command.add_parser(sub)", "")
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    listed = capsys.readouterr().out
    for name, module in cli._COMMANDS.items():
        assert module.__name__ == f"cobotlab.commands.{name}"
        assert re.search(rf"^ +{name}\b", listed, re.M), name


def test_shard_of_a_missing_course_is_one_line(capsys, tmp_path):
    _one_line_error(capsys, ["shard", str(tmp_path / "nowhere"), "lab0_frames",
                             str(tmp_path / "job")])


def test_errors_are_one_line_without_debug(capsys):
    _one_line_error(capsys, ["demo", "--synthetic", "--poses", "2"], "n_poses")


def test_debug_shows_the_exception():
    with pytest.raises(ValueError, match="n_poses"):
        cli.main(["--debug", "demo", "--synthetic", "--poses", "2"])


@pytest.mark.parametrize("argv, fragments", [
    (["demo", "--robot", "kuka"], ["unknown robot 'kuka'", "panda"]),
    (["demo", "--noise", "loud"], ["unknown noise level 'loud'", "none, low, high"]),
    (["demo", "--seed", "-1"], ["seed must be a non-negative integer"]),
    (["demo", "--poses", "3"], ["n_poses must be at least 6"]),
    (["demo", "--pixel-noise", "1"], ["--pixel-noise applies to --synthetic only"]),
    (["calibrate", "/nonexistent/capture"], ["has no poses.npz"]),
    (["calibrate", ".", "--method", "magic"], ["unknown --method 'magic'", "tsai"]),
    (["calibrate", ".", "--mount", "eye_on_ceiling"], ["--mount must be eye_in_hand or eye_to_hand"]),
    (["data", "export", "nope", "somewhere"], ["no dataset named 'nope'", "bionicdl_aubo_i5_flange"]),
])
def test_bad_arguments_give_one_line_errors(capsys, argv, fragments):
    _one_line_error(capsys, argv, *fragments)


def test_usage_mistakes_are_one_line_too(capsys):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["demo", "--bogus"])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "unrecognized arguments: --bogus" in err


def test_synthetic_demo_table_runs_in_a_subprocess():
    out = subprocess.run([sys.executable, "-m", "cobotlab.cli", "demo", "--synthetic", "--poses",
                          "6"], check=False, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    for expected in ("eye_in_hand", "eye_to_hand", "nonlinear", "opencv PARK"):
        assert expected in out.stdout
    assert "failed" not in out.stdout


def _table_errors(text: str, label: str) -> tuple[float, float]:
    """(deg, mm) from a printed row '  <label>   <deg> deg   <mm> mm'."""
    match = re.search(re.escape(label) + r"\s+([\d.]+) deg\s+([\d.]+) mm", text)
    assert match, f"no row {label!r} in:\n{text}"
    return float(match.group(1)), float(match.group(2))


def check_quick_demo(run: subprocess.CompletedProcess, out_dir: Path) -> None:
    """What `cobotlab demo --quick` (the Panda) must print and write to ``out_dir``.

    tests/test_course_install.py's regular install runs that demo (from the wheel: its data
    files included) and checks it with this; the suite ran the same 9 s of CPU twice when
    this file ran it again from the checkout."""
    assert run.returncode == 0, run.stderr[-2000:]
    text = run.stdout
    for name in ("report.html", "frames_3d.png", "residuals.png", "methods.png",
                 "servo_errors.png", "board_before.png", "board_after.png", "flange_T_cam.yaml"):
        assert (out_dir / name).is_file() and (out_dir / name).stat().st_size > 0, name
    page = (out_dir / "report.html").read_text()
    for image in ("frames_3d.png", "methods.png", "servo_errors.png", "board_after.png"):
        assert f'src="{image}"' in page
    # Errors against the truth: the camera is mounted 3 mm / 1.5 deg off its design pose, and
    # the calibrations must find it to well under that.
    deg, mm = _table_errors(text, "flange calibration   base_T_cam")
    assert deg < 0.3 and mm < 2.0
    deg, mm = _table_errors(text, "eye-in-hand (nonlinear) flange_T_cam")
    assert deg < 0.2 and mm < 1.0
    assert "3/3 pieces placed" in text
    assert "capture:" in run.stderr and "pick:" in run.stderr  # the progress bars
    assert re.search(r"elapsed: [\d.]+ s", text)
    saved = load_calibration(out_dir / "flange_T_cam.yaml")
    assert saved.parent == "flange" and saved.child == "cam" and saved.method == "nonlinear"


@pytest.mark.slow
@pytest.mark.parametrize("arm", ["ur10e", "aubo_i5", "cobotta"])
def test_quick_demo_runs_on_every_arm(capsys, tmp_path, arm):
    assert cli.main(["demo", "--quick", "--robot", arm, "--out", str(tmp_path / arm)]) == 0
    text = capsys.readouterr().out
    deg, mm = _table_errors(text, "eye-in-hand (nonlinear) flange_T_cam")
    assert deg < 0.2 and mm < 1.0
    assert "3/3 pieces placed" in text
    assert (tmp_path / arm / "report.html").is_file()


# --------------------------------------------------------------------------- calibrate


@pytest.fixture(scope="module")
def sim_capture(tmp_path_factory):
    """A real eye-in-hand capture folder from the simulator (10 views, 320x240) and the truth."""
    from robots.capture import capture_pose_pairs, chessboard_detector
    from robots.geometry import pose_from_rpy
    from sim_backends.world import create_workcell

    folder = tmp_path_factory.mktemp("capture") / "run1"
    with create_workcell(arm="panda", mount="eye_in_hand", seed=4, width=320, height=240,
                         mount_error=(3.0, 1.0)) as cell:
        truth = cell.truth
        board = truth.board
        cols, rows = board.pattern_size
        square = float(np.linalg.norm(board.object_points[1] - board.object_points[0]))
        centre = compose(truth.base_T_board, make_pose(t=board.object_points.mean(axis=0)))
        rng = np.random.default_rng(4)
        poses = []
        for azimuth in np.linspace(0, 2 * np.pi, 10, endpoint=False):
            tilt = np.deg2rad(rng.uniform(12, 25))
            # Camera 0.45 m from the board centre, looking at it, image x along board x.
            cam = compose(centre, pose_from_rpy(0, 0, azimuth), pose_from_rpy(tilt, 0, 0),
                          pose_from_rpy(0, 0, -azimuth), make_pose(t=[0, 0, -0.45]))
            poses.append(compose(cam, invert(truth.nominal_flange_T_cam)))
        capture = capture_pose_pairs(cell.robot, cell.camera, poses,
                                     chessboard_detector(cols, rows, square), folder=folder,
                                     progress=False, settle_s=0.0, speed=0.25)
        assert len(capture) >= 8, capture.failed_reasons
        return folder, truth.flange_T_cam.copy(), capture


def test_calibrate_solves_a_saved_capture_and_writes_the_yaml(capsys, sim_capture, tmp_path):
    folder, true_X, capture = sim_capture
    out = tmp_path / "result.yaml"
    assert cli.main(["calibrate", str(folder), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    # every view kept its corners: the default is the corner fit
    assert "flange_T_cam by corners (eye_in_hand) (auto: every view has its board corners)" in text
    assert "corner fit:" in text and "held-out error" in text
    assert text.count("view ") >= len(capture) and "flagged views:" in text
    result = load_calibration(out)
    assert result.n_samples == len(capture) and result.method == "corners"
    assert translation_error(result.pose, true_X) < 1e-3
    assert rotation_error_deg(result.pose, true_X) < 0.1
    doc = yaml.safe_load(out.read_text())
    assert len(doc["residuals"]["per_pose_translation_m"]) == len(capture)


def _turned_copy(capture, view: int, folder):
    """The capture as a detector that read ``view``'s chessboard half a turn round gives it:
    corners listed from the other end, the board pose turned with them."""
    import dataclasses

    from robots.capture import save_capture
    from robots.half_turn import half_turn

    corners = [c.copy() for c in capture.corners_px]
    corners[view] = corners[view][::-1].copy()
    poses = capture.cam_T_target.copy()
    poses[view] = poses[view] @ half_turn(capture.object_points[view])
    return save_capture(dataclasses.replace(capture, corners_px=corners, cam_T_target=poses),
                        folder)


def test_calibrate_resolves_a_chessboard_read_half_a_turn_round(capsys, sim_capture, tmp_path):
    from robots.capture import TargetRecord, load_capture

    folder, true_X, capture = sim_capture
    target = load_capture(folder).target   # capture_pose_pairs recorded chessboard_detector's
    assert target == TargetRecord("chessboard", {"inner_cols": 8, "inner_rows": 6,
                                                 "square_m": target.geometry["square_m"]}, True)
    view = int(capture.pose_indices[3])
    turned = _turned_copy(load_capture(folder), 3, tmp_path / "turned")
    out = tmp_path / "X.yaml"
    assert cli.main(["calibrate", str(turned), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"half-turn of the corner order: corner order: views [{view}] turned half a turn" \
        in text, text
    X = load_calibration(out).pose
    assert translation_error(X, true_X) < 1e-3 and rotation_error_deg(X, true_X) < 0.1

    # A folder saved before targets were recorded: solved as it is, and the user is told.
    meta = yaml.safe_load((turned / "meta.yaml").read_text())
    del meta["target"]
    (turned / "meta.yaml").write_text(yaml.safe_dump(meta))
    assert cli.main(["calibrate", str(turned), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "half-turn of the corner order: not checked: the capture does not record its " \
           "target" in text, text


def test_calibrate_default_output_and_other_method(capsys, sim_capture):
    folder, true_X, _ = sim_capture
    assert cli.main(["calibrate", str(folder), "--method", "tsai"]) == 0
    assert "flange_T_cam by tsai" in capsys.readouterr().out
    result = load_calibration(folder / "flange_T_cam.yaml")
    assert result.method == "tsai" and translation_error(result.pose, true_X) < 2e-3


def test_the_pipeline_a_notebook_calls_is_what_calibrate_prints(capsys, sim_capture, tmp_path):
    """solutions.pipeline: typed values, the same X and held-out error the command prints."""
    from robots.capture import load_capture
    from solutions import pipeline

    folder, true_X, _ = sim_capture
    capture = load_capture(folder)
    result = pipeline.calibrate_capture(capture, "eye_in_hand", "tsai")
    assert result.method == "tsai" and result.parent == "flange"
    assert result.corner_fit is None and result.held_out is not None
    assert result.held_out.per_view_px.shape == (len(result.views),)
    assert not result.held_out.model_kept
    assert translation_error(result.X, true_X) < 2e-3
    out = tmp_path / "X.yaml"
    assert cli.main(["calibrate", str(folder), "--method", "tsai", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"median {result.held_out.median_px:.2f} px" in printed
    np.testing.assert_allclose(load_calibration(out).pose, result.X, atol=1e-12)
    with pytest.raises(ValueError, match="unknown --method 'magic'"):
        pipeline.calibrate_capture(capture, "eye_in_hand", "magic")


def test_calibrate_warns_when_the_views_cannot_tell_the_mounts_apart(capsys, sim_capture):
    # The fixture's views only tilt the camera about axes in the board plane, aimed at one
    # point: both mounts fit them exactly, so the student must be told the result rests on
    # --mount alone.
    folder, _, _ = sim_capture
    assert cli.main(["calibrate", str(folder), "--mount", "eye_to_hand",
                     "--out", str(folder / "wrong.yaml")]) == 0
    assert "cannot tell the two mounts apart" in capsys.readouterr().out


def _synthetic_capture(folder, mount):
    """A capture folder holding a synthetic problem's poses (views that also roll the camera);
    no corners and blank images, so ``calibrate`` reads only the poses (auto: nonlinear)."""
    from autograder.synthetic import NoiseModel, make_hand_eye
    from robots.capture import Capture, save_capture
    from robots.interfaces import Intrinsics

    p = make_hand_eye(2, mount, n_poses=10, noise=NoiseModel(cam_rot_deg=0.05, cam_trans_mm=0.2))
    n = len(p.base_T_flange)
    save_capture(Capture(
        base_T_flange=p.base_T_flange, cam_T_target=p.cam_T_target,
        corners_px=[np.zeros((0, 2))] * n, object_points=[np.zeros((0, 3))] * n,
        intrinsics=Intrinsics(600.0, 600.0, 319.5, 239.5, 640, 480),
        commanded_base_T_flange=p.base_T_flange, pose_indices=np.arange(n),
        timestamps=np.arange(n, dtype=float), images=[np.zeros((4, 4, 3), np.uint8)] * n),
        folder)
    return p


@pytest.mark.parametrize("true_mount, wrong_mount",
                         [("eye_in_hand", "eye_to_hand"), ("eye_to_hand", "eye_in_hand")])
def test_calibrate_names_the_right_mount_when_the_wrong_one_is_given(capsys, tmp_path,
                                                                     true_mount, wrong_mount):
    _synthetic_capture(tmp_path / "cap", true_mount)
    assert cli.main(["calibrate", str(tmp_path / "cap"), "--mount", true_mount]) == 0
    text = capsys.readouterr().out
    assert "WARNING" not in text
    # no corners in these views: the default falls back to the pose-based fit and says why
    assert "by nonlinear" in text and "no view has board corners" in text
    # The wrong mount gives every solver a wrong X: refused, naming the mount that fits, and
    # nothing saved that a lab could mistake for a calibration.
    (tmp_path / "cap" / "flange_T_cam.yaml").unlink(missing_ok=True)
    (tmp_path / "cap" / "base_T_cam.yaml").unlink(missing_ok=True)
    assert cli.main(["calibrate", str(tmp_path / "cap"), "--mount", wrong_mount]) == 2
    assert f"these views fit --mount {true_mount} far better" in capsys.readouterr().err
    assert not list((tmp_path / "cap").glob("*_T_cam.yaml"))


# --------------------------------------------------------------------------- data


def test_data_list_shows_provenance_and_licence(capsys):
    assert cli.main(["data", "list"]) == 0
    out = capsys.readouterr().out
    assert "bionicdl_aubo_i5_flange" in out
    assert "ancorasir/BionicDL-CobotLearning-Project2" in out
    assert re.search(r"licence: .*MIT License", out)


def test_data_export_copies_the_files_and_refuses_to_overwrite(capsys, tmp_path):
    from autograder.datasets import load_aubo_flange_capture

    dest = tmp_path / "aubo"
    assert cli.main(["data", "export", "bionicdl_aubo_i5_flange", str(dest)]) == 0
    assert (dest / "README.md").is_file()
    with np.load(dest / "calibration_data.npz") as data:
        cam, base = load_aubo_flange_capture()
        np.testing.assert_array_equal(data["arr_0"], cam)
        np.testing.assert_array_equal(data["arr_1"], base)
    capsys.readouterr()
    _one_line_error(capsys, ["data", "export", "bionicdl_aubo_i5_flange", str(dest)],
                    "already has", "calibration_data.npz")


# --------------------------------------------------------------------------- robot check


def test_robot_check_reads_the_cell_and_moves_nothing(capsys):
    assert cli.main(["robot", "check", "--arm", "ur5e"]) == 0
    out = capsys.readouterr().out
    assert "connected: sim / ur5e" in out
    assert "flange (mm)" in out and "safety: workspace" in out
    assert out.rstrip().endswith("nothing moved.")


def test_robot_check_unknown_kind_is_one_line(capsys):
    assert cli.main(["robot", "check", "--kind", "kuka"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown robot kind 'kuka'" in err and len(err.splitlines()) == 1


def test_robot_check_jog_moves_only_after_a_yes(monkeypatch, capsys):
    answers = iter(["x+", "y", "z-", "n", "q"])
    monkeypatch.setattr("builtins.input", lambda prompt="": next(answers))
    assert cli.main(["robot", "check", "--arm", "ur5e", "--jog"]) == 0
    out = capsys.readouterr().out
    assert "moved." in out and "you answered no" in out
    assert out.rstrip().endswith("1 jog move(s) made.")


def test_grade_names_a_missing_batch_in_one_line(tmp_path, capsys):
    # A copy of the run's one `course init` (course_kit): what `cobotlab course init` lays
    # out (config, sources, a secret only its owner reads, the .gitignore) is checked where
    # the command runs as docs/instructors.md writes it, in tests/test_instructor_docs.py;
    # running it here again cost 4-11 s of CPU (every built-in lab's practice problems).
    import course_kit as kit

    course = kit.initialized_course(tmp_path)
    assert cli.main(["grade", str(course), "lab0_frames", "--no-nbgrader"]) == 2
    err = capsys.readouterr().err.strip()
    assert "no submissions for 'lab0_frames'" in err and len(err.splitlines()) == 1
