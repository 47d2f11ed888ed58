"""Importing what calibration users have: pose files of every layout and convention, given
intrinsics; what the importer decides is checked against the data and printed with evidence,
and where the data cannot tell it asks for the flag.

The poses are a shipped real capture's (kuka_3: eye-in-hand, 29 views, metres, base_T_flange)
rewritten in other layouts, so the right answer is known: the importer must read them back to
the same base_T_flange whatever the layout, unit or direction."""

from __future__ import annotations

import json
from importlib import resources

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from autograder.datasets import load_rwhe_kuka
from cobotlab import cli
from robots import geometry as geo
from robots.pose_files import read_intrinsics, read_poses
from solutions.capture_import import import_capture


def _kuka(name):
    return resources.files("autograder").joinpath("data", "rwhe_kuka", "kuka_3", name)


@pytest.fixture(scope="module")
def kuka():
    """(base_T_flange (n, 4, 4) m, the corners file's path)."""
    with resources.as_file(_kuka("corners.npz")) as corners:
        yield load_rwhe_kuka("kuka_3").base_T_flange, corners


def _write_rows(path, rows, header=None):
    lines = [header] if header else []
    lines += [",".join(f"{v:.12g}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _quat(F, order):
    q = Rotation.from_matrix(F[:, :3, :3]).as_quat()  # xyzw
    return q if order == "xyzw" else np.roll(q, 1, axis=1)


def _same_poses(imported, F):
    got = imported.capture.base_T_flange
    want = F[imported.capture.pose_indices]
    assert np.max(geo.translation_error(got, want)) < 1e-6
    assert np.max(geo.rotation_error_deg(got, want)) < 1e-6


def test_a_named_quaternion_csv_in_millimetres_reads_back_the_poses(tmp_path, kuka):
    F, corners = kuka
    rows = np.hstack([F[:, :3, 3] * 1000, _quat(F, "xyzw")])
    path = _write_rows(tmp_path / "poses.csv", rows, "x,y,z,qx,qy,qz,qw")
    imported = import_capture(path, corners=corners)
    _same_poses(imported, F)
    decided = {d.what: d for d in imported.decisions}
    assert decided["quat order"].how == "named in the file"
    assert decided["length unit"].value == "mm" and decided["length unit"].how == "from the data"
    # the evidence: the robot's screw pitch is ~1000 times the camera's (metres)
    ratio = float(decided["length unit"].evidence.split("screw pitch is ")[1].split(" times")[0])
    assert 900 < ratio < 1100


def test_rotation_vectors_in_degrees_are_told_from_radians_by_the_motion_angles(tmp_path, kuka):
    F, corners = kuka
    rotvec = Rotation.from_matrix(F[:, :3, :3]).as_rotvec(degrees=True)
    path = _write_rows(tmp_path / "poses.txt", np.hstack([F[:, :3, 3], rotvec]))
    imported = import_capture(path, corners=corners)
    _same_poses(imported, F)
    angle = next(d for d in imported.decisions if d.what == "angle unit")
    assert angle.value == "deg" and "rad " in angle.evidence and "deg " in angle.evidence


def test_a_folder_of_visp_pose_files_theta_u_in_metres(tmp_path, kuka):
    F, corners = kuka
    folder = tmp_path / "poses"
    folder.mkdir()
    for k, T in enumerate(F):
        tu = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        values = "\n".join(f"  - [{v:.15g}]" for v in np.concatenate([T[:3, 3], tu]))
        (folder / f"pose_fPe_{k:02d}.yaml").write_text(f"rows: 6\ncols: 1\ndata:\n{values}\n")
    imported = import_capture(folder, corners=corners)
    _same_poses(imported, F)
    assert {d.what: d.value for d in imported.decisions}["angle unit"] == "rad"


def test_an_unlabelled_quaternion_order_is_decided_by_the_data(tmp_path, kuka):
    F, corners = kuka
    path = _write_rows(tmp_path / "poses.csv", np.hstack([F[:, :3, 3], _quat(F, "wxyz")]))
    imported = import_capture(path, corners=corners)
    _same_poses(imported, F)
    order = next(d for d in imported.decisions if d.what == "quat order")
    assert order.value == "wxyz" and order.how == "from the data"


def test_inverted_poses_are_found_only_when_the_mount_is_stated(tmp_path, kuka):
    F, corners = kuka
    inverse = geo.invert(F)
    path = _write_rows(tmp_path / "poses.txt", inverse.reshape(len(F), 16))
    # inverting the poses and switching the mount give the same equations: say which
    with pytest.raises(ValueError, match="pass --mount eye_in_hand or eye_to_hand"):
        import_capture(path, corners=corners, mount_given=False)
    imported = import_capture(path, corners=corners, mount="eye_in_hand")
    _same_poses(imported, F)
    direction = next(d for d in imported.decisions if d.what == "pose direction")
    assert direction.value == "flange_T_base"


def test_given_flags_are_used_as_given_and_said_so(tmp_path, kuka):
    F, corners = kuka
    path = _write_rows(tmp_path / "poses.txt", F.reshape(len(F), 16))
    imported = import_capture(path, corners=corners, length_unit="m", direction="base_T_flange")
    assert [(d.what, d.how) for d in imported.decisions] == [("length unit", "given"),
                                                             ("pose direction", "given")]
    _same_poses(imported, F)


def test_a_unit_the_data_cannot_tell_is_asked_for(tmp_path, kuka):
    F, corners = kuka
    # centimetres: neither the reach nor the screw pitch fits metres or millimetres
    rows = np.hstack([F[:, :3, 3] * 100, _quat(F, "xyzw")])
    path = _write_rows(tmp_path / "poses.csv", rows, "x,y,z,qx,qy,qz,qw")
    with pytest.raises(ValueError, match="cannot tell the length unit.*pass --length-unit m or mm"):
        import_capture(path, corners=corners)


def test_opencv_intrinsics_are_used_as_given_not_recalibrated(tmp_path, kuka):
    F, corners = kuka
    K = np.array([[2060.0, 0, 960.0], [0, 2061.0, 610.0], [0, 0, 1]])
    dist = np.array([-0.1, 0.12, 0.0, 0.0, 0.05])
    fs = cv2.FileStorage(str(tmp_path / "camera.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1928)
    fs.write("image_height", 1208)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", dist.reshape(1, 5))
    fs.release()
    with np.load(corners) as data:
        size = tuple(int(v) for v in data["image_size_wh"])
    intrinsics = read_intrinsics(tmp_path / "camera.yaml", size)
    assert np.array_equal(intrinsics.K, K) and np.array_equal(intrinsics.dist, dist)
    path = _write_rows(tmp_path / "poses.txt", F.reshape(len(F), 16))
    imported = import_capture(path, corners=corners, intrinsics=intrinsics)
    assert np.array_equal(imported.capture.intrinsics.K, K)
    assert imported.intrinsics_source == "given"
    # and a calibration of another resolution is refused
    with pytest.raises(ValueError, match="another resolution"):
        read_intrinsics(tmp_path / "camera.yaml", (640, 480))


@pytest.mark.parametrize("text, message", [
    ("x,y,z,a,b,c\n1,2,3,4,5,6\n", "a header naming no layout"),
    ("1 2 3 4 5\n", "5 numbers per view"),
    ("1 2 3 0 0 0\n1 2 3 0 0 0 1\n", "every view needs the same layout"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0.5 0.2 0.1 1\n", "column-major"),
    ("1 2 nan 0 0 0\n", "NaN or inf"),
])
def test_a_bad_pose_file_says_what_was_expected(tmp_path, text, message):
    path = tmp_path / "poses.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_poses(path)


def test_cli_import_prints_each_decision_and_the_given_intrinsics(tmp_path, kuka, capsys):
    F, corners = kuka
    rows = np.hstack([F[:, :3, 3] * 1000, _quat(F, "xyzw")])
    path = _write_rows(tmp_path / "poses.csv", rows, "x,y,z,qx,qy,qz,qw")
    assert cli.main(["data", "import", str(path), str(tmp_path / "cap"), "--corners",
                     str(corners), "--fx", "2060", "--fy", "2061", "--cx", "960", "--cy", "610",
                     "--dist=-0.1,0.12,0,0", "--mount", "eye_in_hand"]) == 0
    out = capsys.readouterr().out
    assert "fx 2060.0 fy 2061.0 cx 960.0 cy 610.0 px, dist -0.1000 0.1200" in out
    assert "(given)" in out
    assert "length unit: mm (from the data): the flange is up to" in out
    assert "pose direction: base_T_flange (from the data)" in out
    assert cli.main(["data", "import", str(path), str(tmp_path / "cap2"), "--corners",
                     str(corners), "--fx", "2060"]) == 2
    assert "need --fy, --cx, --cy too" in capsys.readouterr().err


def test_eye_to_hand_marker_free_synthetic_capture_reads_with_its_mount(tmp_path):
    from autograder.synthetic import NoiseModel, make_hand_eye

    p = make_hand_eye(3, "eye_to_hand", n_poses=12, noise=NoiseModel(pixel_px=0.2))
    corners = tmp_path / "corners.npz"
    np.savez(corners, corners_px=p.pixels, board_points_m=p.board.object_points(),
             image_size_wh=np.array([p.camera.width, p.camera.height]))
    rotvec = Rotation.from_matrix(p.base_T_flange[:, :3, :3]).as_rotvec()
    path = _write_rows(tmp_path / "poses.txt", np.hstack([p.base_T_flange[:, :3, 3] * 1000,
                                                          rotvec]))
    with pytest.raises(ValueError, match="or the camera is eye_to_hand"):
        import_capture(path, corners=corners, mount_given=False)
    imported = import_capture(path, corners=corners, mount="eye_to_hand")
    _same_poses(imported, p.base_T_flange)
    assert {d.what: d.value for d in imported.decisions} == {
        "angle unit": "rad", "pose direction": "base_T_flange", "length unit": "mm"}


def test_a_json_list_in_one_file(tmp_path, kuka):
    F, corners = kuka
    poses = [{"position": {"x": T[0, 3], "y": T[1, 3], "z": T[2, 3]},
              "orientation": dict(zip("xyzw", Rotation.from_matrix(T[:3, :3]).as_quat()))}
             for T in F]
    path = tmp_path / "poses.json"
    path.write_text(json.dumps({"poses": poses}))
    imported = import_capture(path, corners=corners)
    _same_poses(imported, F)


def test_bad_files_and_numbers_name_the_file_the_view_and_the_fix(tmp_path):
    from robots.pose_files import PoseConvention, intrinsics_from, to_base_T_flange

    with pytest.raises(FileNotFoundError, match="no pose file or folder"):
        read_poses(tmp_path / "missing.csv")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no .yaml, .yml or .json pose files"):
        read_poses(tmp_path / "empty")
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "a.yaml").write_text("stamp: 3\n")
    with pytest.raises(ValueError, match="a.yaml: no pose found; give 'matrix'"):
        read_poses(tmp_path / "one")
    quats = tmp_path / "q.csv"
    quats.write_text("0 0 0 0 0 0 1\n0 0 0 0.5 0 0 1\n0 0 0 0 1 0 0\n")
    with pytest.raises(ValueError, match=r"quaternion of q.csv:2 has norm 1.118"):
        to_base_T_flange(read_poses(quats), PoseConvention())
    scaled = tmp_path / "m.txt"
    scaled.write_text("2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1\n")
    with pytest.raises(ValueError, match="m.txt poses"):
        to_base_T_flange(read_poses(scaled), PoseConvention())
    with pytest.raises(ValueError, match="--fy must be a positive number of pixels"):
        intrinsics_from(500, -1, 320, 240, 640, 480)
    with pytest.raises(ValueError, match="keeps OpenCV's first five"):
        intrinsics_from(500, 500, 320, 240, 640, 480, [0.1, 0, 0, 0, 0, 0.2, 0, 0])
    skewed = tmp_path / "camera_info.yaml"
    skewed.write_text("image_width: 640\nimage_height: 480\n"
                      "camera_matrix: {data: [500, 3, 320, 0, 500, 240, 0, 0, 1]}\n")
    with pytest.raises(ValueError, match=r"is not \[\[fx 0 cx\]"):
        read_intrinsics(skewed)
    (tmp_path / "nothing.yaml").write_text("image_width: 640\n")
    with pytest.raises(ValueError, match="no 3 x 3 camera_matrix found"):
        read_intrinsics(tmp_path / "nothing.yaml")


def test_cli_flag_mistakes_are_one_line(tmp_path, kuka, capsys):
    F, corners = kuka
    path = _write_rows(tmp_path / "poses.txt", F.reshape(len(F), 16))
    for argv, message in (
            (["--corners", str(corners), "--board", "8x6:39"], "--board goes with --images"),
            (["--corners", str(corners), "--dist=0.1,0"], "--dist needs --fx --fy --cx --cy"),
            (["--corners", str(corners), "--intrinsics", "x.yaml", "--fx", "1"],
             "either as --intrinsics FILE or as --fx")):
        assert cli.main(["data", "import", str(path), str(tmp_path / "cap"), *argv]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(SystemExit) as exit_:
        cli.main(["data", "import", str(path), str(tmp_path / "cap"), "--corners", str(corners),
                  "--length-unit", "cm"])
    assert exit_.value.code == 2
    assert "invalid choice: 'cm' (choose from 'm', 'mm')" in capsys.readouterr().err


def test_poses_not_in_the_order_of_the_views_are_refused_with_the_pairing(tmp_path, kuka):
    F, corners = kuka
    # image names sorted so the last view comes first (im_9 before im_10 without natural
    # order, say): every pose goes with its neighbour's image
    shifted = np.roll(F, 1, axis=0)
    path = _write_rows(tmp_path / "poses.txt", shifted.reshape(len(F), 16))
    with pytest.raises(ValueError, match="not paired one to one.*another pairing of the same poses"):
        import_capture(path, corners=corners)
    # (one swapped pair of 29 leaves the median motion angle as it is: the calibration's
    # per-view residuals name those two views instead)


def test_numbered_files_sort_as_numbers(tmp_path):
    from robots.pose_files import in_natural_order

    names = ["image-10.png", "image-2.png", "image-1.png"]
    assert [p.name for p in in_natural_order(names)] == ["image-1.png", "image-2.png",
                                                         "image-10.png"]


def test_corners_given_as_a_file_get_their_half_turn_checked_by_calibrate(tmp_path, capsys):
    """A chessboard's corners from another tool (--corners, --target default chessboard), one
    view listed from the other end: calibrate puts it back from the robot's motion."""
    from autograder.synthetic import NoiseModel, make_hand_eye
    from robots.calibration_io import load_calibration
    from robots.capture import load_capture

    p = make_hand_eye(5, "eye_in_hand", n_poses=10, noise=NoiseModel(pixel_px=0.2))
    pixels = p.pixels.copy()
    pixels[4] = pixels[4][::-1]
    corners = tmp_path / "corners.npz"
    np.savez(corners, corners_px=pixels, board_points_m=p.board.object_points(),
             image_size_wh=np.array([p.camera.width, p.camera.height]))
    path = _write_rows(tmp_path / "poses.txt", p.base_T_flange.reshape(-1, 16))
    K = p.camera.K
    assert cli.main(["data", "import", str(path), str(tmp_path / "cap"), "--corners",
                     str(corners), "--mount", "eye_in_hand", "--length-unit", "m",
                     "--pose-direction", "base_T_flange", "--fx", str(K[0, 0]),
                     "--fy", str(K[1, 1]), "--cx", str(K[0, 2]), "--cy", str(K[1, 2]),
                     "--dist=" + ",".join(str(v) for v in p.camera.dist)]) == 0
    capsys.readouterr()
    assert load_capture(tmp_path / "cap").target.kind == "chessboard"
    out = tmp_path / "X.yaml"
    assert cli.main(["calibrate", str(tmp_path / "cap"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "half-turn of the corner order: corner order: views [4] turned half a turn" in text, \
        text
    X = load_calibration(out).pose
    assert geo.translation_error(X, p.X_true) < 2e-3 and geo.rotation_error_deg(X, p.X_true) < 0.2
