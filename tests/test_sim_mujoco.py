"""The MuJoCo engine: chosen as documented, built from the same description as PyBullet's,
rendering the same geometry (corners, depth, lens), moving the arm with the same checks.

Cheap on purpose (small images, one cell per module where the checks share it); the frame
rate and the comparison with PyBullet are in benchmarks/sim_speed.py.
"""

import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

import robots.backends as backends
from robots import connect
from robots.backends import BackendNotAvailableError, resolve_connect_options
from robots.safety import SafetyError

pytest.importorskip("mujoco", reason="the MuJoCo engine needs `pip install mujoco`")

from sim_backends.mujoco_gl import OpenGLUnavailableError, _choose_linux_platform  # noqa: E402

CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)


def _true_corners(cell, dist=None) -> np.ndarray:
    """Where the board's corners truly land in the main camera's image (N, 2) px."""
    truth, intr = cell.truth, cell.camera.intrinsics
    cam_T_board = np.linalg.inv(truth.base_T_cam_now()) @ truth.base_T_board
    rvec, _ = cv2.Rodrigues(cam_T_board[:3, :3])
    dist = np.zeros(5) if dist is None else np.asarray(dist, float)
    uv, _ = cv2.projectPoints(truth.board.object_points, rvec, cam_T_board[:3, 3], intr.K, dist)
    return uv.reshape(-1, 2)


def _detected_corners(rgb, pattern) -> np.ndarray:
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(gray, pattern)
    assert found, "the chessboard is not detected in the MuJoCo frame"
    return cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), CRITERIA).reshape(-1, 2)


def _corner_error(detected, true) -> float:
    # The detector may list the corners from either end of the (symmetric) board.
    return min(np.abs(detected - true).max(), np.abs(detected[::-1] - true).max())


# --------------------------------------------------------------------------- engine choice


def test_the_engine_comes_from_the_argument_then_the_environment_then_lab_toml(tmp_path):
    (tmp_path / "lab.toml").write_text('[connect.sim]\nengine = "pybullet"\narm = "ur5e"\n')
    env = {"COBOTLAB_SIM_ENGINE": "mujoco"}
    assert resolve_connect_options(None, {}, tmp_path, {})[1]["engine"] == "pybullet"
    assert resolve_connect_options(None, {}, tmp_path, env)[1]["engine"] == "mujoco"
    assert resolve_connect_options("sim", {"engine": "pybullet"}, tmp_path, env)[1]["engine"] \
        == "pybullet"
    # A real robot never gets the simulator's engine.
    assert "engine" not in resolve_connect_options("ur", {}, tmp_path, env)[1]


def test_the_default_engine_is_mujoco_where_installed_else_pybullet():
    assert backends.default_sim_engine(lambda package: True) == "mujoco"
    assert backends.default_sim_engine(lambda package: package == "mujoco") == "mujoco"
    assert backends.default_sim_engine(lambda package: package == "pybullet") == "pybullet"
    with pytest.raises(BackendNotAvailableError, match=r"pip install 'mujoco.*pip install pybullet"):
        backends.default_sim_engine(lambda package: False)


def test_an_unknown_or_missing_engine_says_what_to_do(monkeypatch):
    with pytest.raises(ValueError, match="engine must be one of 'mujoco', 'pybullet'.*'bullet3'"):
        connect("sim", engine="bullet3")
    monkeypatch.setattr(backends, "_installed", lambda package: package != "mujoco")
    with pytest.raises(BackendNotAvailableError, match=r"'mujoco'.*not installed.*pip install"):
        connect("sim", engine="mujoco")


def test_without_egl_or_osmesa_the_error_names_the_debian_packages():
    with pytest.raises(OpenGLUnavailableError, match="apt-get install libegl1 libgl1-mesa-dri"):
        _choose_linux_platform(find_library=lambda name: None)
    assert _choose_linux_platform(lambda name: "libOSMesa.so" if name == "OSMesa" else None) \
        == "osmesa"


def test_a_mujoco_only_install_runs_the_simulator_without_pybullet():
    # A student's laptop with no PyBullet wheel: pybullet cannot be imported at all.
    code = textwrap.dedent("""
        import sys
        sys.modules["pybullet"] = None
        sys.modules["pybullet_data"] = None
        from robots import connect
        from robots.backends import BackendNotAvailableError
        import robots.backends as b
        b._installed = lambda package: package != "pybullet"
        with connect("sim", arm="panda", seed=0, width=160, height=120) as cell:
            frame = cell.camera.capture()
            print(type(cell).__name__, frame.rgb.shape, "pybullet" in sys.modules and
                  sys.modules["pybullet"] is not None)
        try:
            connect("sim", engine="pybullet", arm="panda")
        except BackendNotAvailableError as error:
            print("pybullet:", error)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "MujocoWorkcell (120, 160, 3) False"
    assert "pip install pybullet" in lines[1]


# --------------------------------------------------------------------------- one description


def test_each_engine_builds_the_one_checked_description():
    # A new option is added (checked, documented) in layout.describe_workcell alone: neither
    # engine's factory has parameters of its own, and each builder takes the description.
    import inspect

    from sim_backends import layout, mujoco_world, world

    for engine in (world, mujoco_world):
        factory = inspect.signature(engine.create_workcell).parameters.values()
        assert [p.kind for p in factory] == [inspect.Parameter.VAR_KEYWORD], engine.__name__
        (param,) = inspect.signature(engine.build_workcell).parameters.values()
        assert "WorkcellDescription" in str(param.annotation), engine.__name__
    with pytest.raises(TypeError, match="no_such_option"):
        world.create_workcell(no_such_option=1)
    assert "depth_model :" in layout.describe_workcell.__doc__


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_both_engines_lay_the_cell_out_the_same_for_a_seed(mount):
    options = dict(arm="ur5e", mount=mount, seed=5, width=160, height=120,
                   encoder_noise_deg=0.05, mount_error=(2.0, 0.5))
    with connect("sim", engine="pybullet", **options) as a, \
            connect("sim", engine="mujoco", **options) as b:
        ta, tb = a.truth, b.truth
        for name in ("base_T_board", "flange_T_cam", "base_T_cam", "encoder_offsets",
                     "base_T_world"):
            va, vb = getattr(ta, name), getattr(tb, name)
            assert (va is None) == (vb is None), name
            if va is not None:
                np.testing.assert_allclose(vb, va, atol=1e-12, err_msg=name)
        # The flange target stands 1 mm in front of whatever the engine's rays hit beyond
        # tool0: Bullet's collision margin adds 1 mm that MuJoCo's exact geometry does not.
        if ta.flange_T_marker is not None:
            diff = np.linalg.inv(ta.flange_T_marker) @ tb.flange_T_marker
            np.testing.assert_allclose(diff[:3, :3], np.eye(3), atol=1e-12)
            assert np.linalg.norm(diff[:3, 3]) <= 1.1e-3
        # The same start pose (each engine's IK reaches it within its 0.1 mm tolerance): for a
        # fixed camera, the flange target where the camera sees it.
        if mount == "eye_to_hand":
            np.testing.assert_allclose(tb.base_T_flange() @ tb.flange_T_marker,
                                       ta.base_T_flange() @ ta.flange_T_marker, atol=2e-4)
        else:
            np.testing.assert_allclose(tb.base_T_flange(), ta.base_T_flange(), atol=2e-4)
        assert b.arm.ik_seed == a.arm.ik_seed


# --------------------------------------------------------------------------- rendering


@pytest.fixture(scope="module")
def eye_in_hand():
    with connect("sim", engine="mujoco", arm="ur5e", seed=0, width=640, height=480) as cell:
        yield cell


def test_board_corners_land_where_the_intrinsics_put_them(eye_in_hand):
    cell = eye_in_hand
    frame = cell.camera.capture()
    detected = _detected_corners(frame.rgb, cell.truth.board.pattern_size)
    assert _corner_error(detected, _true_corners(cell)) < 0.15


def test_depth_is_the_z_distance_of_the_board_and_segmentation_names_it(eye_in_hand):
    cell = eye_in_hand
    depth = cell.camera.capture().depth
    truth, K = cell.truth, cell.camera.intrinsics.K
    # The printed face's plane in the camera frame: its normal and a point on it.
    cam_T_board = np.linalg.inv(truth.base_T_cam_now()) @ truth.base_T_board
    n, p0 = cam_T_board[:3, 2], cam_T_board[:3, 3]
    uv = _true_corners(cell)
    u, v = np.rint(uv).astype(int).T
    rays = np.linalg.solve(K, np.stack([u, v, np.ones_like(u)]).astype(float))
    z_true = (n @ p0) / (n @ rays)  # ray (x, y, 1) * z meets the plane
    z = depth[v, u]
    assert np.all(np.isfinite(z))
    assert np.abs(z - z_true).max() < 5e-4
    # The segmentation mask names the board's body there, and nothing where no depth is.
    _, depth_r, seg = cell.camera.render(segmentation=True)
    assert np.all(seg[v, u] == cell.world.model.body("board").id)
    assert np.array_equal(seg == -1, np.isnan(depth_r))


def test_a_silhouette_in_depth_lands_where_its_truth_projects():
    # The bare flange face seen by the fixed camera: its pixels in the depth image (those on
    # the face's true plane) against the disc's true projection, 4 x 4 supersampled. A
    # multisampled buffer put depth silhouettes 0.37 px up and 0.1 px right of the truth.
    with connect("sim", engine="mujoco", arm="ur5e", mount="eye_to_hand", seed=0, width=320,
                 height=240, flange_target=False, tool=None) as cell:
        z = cell.camera.render()[1].astype(float)
        K, radius = cell.camera.intrinsics.K, cell.truth.flange.radius
        cam_T_flange = np.linalg.inv(cell.truth.base_T_cam) @ cell.truth.base_T_flange()
    n, c = cam_T_flange[:3, 2], cam_T_flange[:3, 3]

    def rays(u, v):
        return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)

    u, v = np.meshgrid(np.arange(320.0), np.arange(240.0))
    on_face = np.abs((rays(u, v) * np.nan_to_num(z, nan=1e3)[..., None] - c) @ n) < 0.002
    S = 4
    us, vs = np.meshgrid((np.arange(320 * S) + 0.5) / S - 0.5, (np.arange(240 * S) + 0.5) / S - 0.5)
    r = rays(us, vs)
    p = r * ((c @ n) / (r @ n))[..., None] - c
    inside = np.linalg.norm(p - (p @ n)[..., None] * n, axis=-1) < radius
    cover = inside.reshape(240, S, 320, S).mean(axis=(1, 3))
    assert abs(on_face.sum() / cover.sum() - 1) < 0.02
    drawn = np.array([u[on_face].mean(), v[on_face].mean()])
    true = np.array([(cover * u).sum(), (cover * v).sum()]) / cover.sum()
    assert np.abs(drawn - true).max() < 0.1, (drawn, true)


def test_moves_reach_the_pose_and_safety_refuses_first(eye_in_hand):
    robot, truth = eye_in_hand.robot, eye_in_hand.truth
    start = robot.flange_pose()
    target = start.copy()
    target[:3, 3] += [0.03, -0.02, 0.02]
    robot.move_to(target, speed=0.2)
    np.testing.assert_allclose(truth.base_T_flange(), target, atol=1e-4)
    before = truth.base_T_flange()
    outside = target.copy()
    outside[2, 3] = -0.2  # under the table
    with pytest.raises(SafetyError):
        robot.move_to(outside)
    np.testing.assert_array_equal(truth.base_T_flange(), before)  # nothing moved
    robot.move_to(start, speed=0.2)


def test_a_distorted_lens_bends_the_corners_as_opencv_does():
    dist = (-0.12, 0.05, 0.001, -0.0015, 0.0)
    with connect("sim", engine="mujoco", arm="ur5e", seed=0, width=640, height=480,
                 distortion=dist) as cell:
        detected = _detected_corners(cell.camera.capture().rgb, cell.truth.board.pattern_size)
        assert _corner_error(detected, _true_corners(cell, dist)) < 0.25


def test_the_realsense_depth_model_applies_on_mujoco_frames():
    with connect("sim", engine="mujoco", arm="aubo_i5", mount="eye_to_hand", seed=2,
                 width=320, height=240, depth_model="d435") as cell:
        depth = cell.camera.capture().depth
        valid = depth[np.isfinite(depth)]
        assert 0.0 < np.isnan(depth).mean() < 0.5  # edges and far background drop out
        steps = valid / cell.camera.depth_scale
        np.testing.assert_allclose(steps, np.rint(steps), atol=1e-3)  # 1 mm steps


@pytest.mark.parametrize("arm", ["panda", "ur10e", "aubo_i5", "cobotta"])
def test_every_mujoco_arm_sees_its_board_and_the_fixed_camera_its_flange_board(arm):
    with connect("sim", engine="mujoco", arm=arm, mount="eye_to_hand", seed=1,
                 width=640, height=480) as cell:
        rgb = cell.camera.capture().rgb
        target = cell.truth.flange_target
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        found, corners = cv2.findChessboardCorners(gray, target.pattern_size)
        assert found, f"{arm}: the flange chessboard is not seen by the fixed camera"
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), CRITERIA).reshape(-1, 2)
        truth = cell.truth
        cam_T_marker = (np.linalg.inv(truth.base_T_cam) @ truth.base_T_flange()
                        @ truth.flange_T_marker)
        rvec, _ = cv2.Rodrigues(cam_T_marker[:3, :3])
        uv, _ = cv2.projectPoints(target.object_points, rvec, cam_T_marker[:3, 3],
                                  cell.camera.intrinsics.K, np.zeros(5))
        assert _corner_error(corners, uv.reshape(-1, 2)) < 0.3


@pytest.mark.parametrize("arm", ["panda", "ur5e", "ur10e", "aubo_i5", "cobotta"])
def test_mujocos_arm_models_have_pybullets_kinematics(arm):
    # The Panda's generated URDF against pybullet_data's: the same joints, to float32 rounding.
    from sim_backends import mujoco_model
    from sim_backends.arm_specs import ARM_SPECS
    from sim_backends.ik import KinematicModel
    from sim_backends.mujoco_arm import MujocoKinematics

    s = ARM_SPECS[arm]
    pb = KinematicModel(s.urdf, s.joint_names, s.flange_link, s.joint_limits, s.home, s.reach,
                        other_joints=s.other_joints)
    mj = MujocoKinematics(mujoco_model.arm_spec(s, drawn=False).compile(), s.joint_names,
                          s.flange_link, s.joint_limits, s.home, s.reach)
    rng = np.random.default_rng(0)
    for q in rng.uniform(s.joint_limits[:, 0], s.joint_limits[:, 1], size=(20, s.n_joints)):
        np.testing.assert_allclose(mj.fk(q), pb.fk(q), atol=1e-6)
        np.testing.assert_allclose(mj.jacobian(q), pb.jacobian(q), atol=1e-6)
    pb.close()


def test_the_maintainers_page_names_what_exists():
    import importlib
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    doc = (root / "docs" / "simulation.md").read_text()
    paths = set(re.findall(r"`(?:python )?((?:sim_backends|robots|benchmarks)/[\w/]+\.py)", doc))
    assert len(paths) >= 6, paths
    for path in paths:
        assert (root / path).is_file(), path
    for name in re.findall(r"`(mujoco_\w+\.py)`", doc):  # the engine's modules, by file name
        assert (root / "sim_backends" / name).is_file(), name
    named = re.findall(r"`sim_backends\.(\w+)\.(\w+)", doc)
    assert len(named) >= 4, named
    for module, name in named:
        assert hasattr(importlib.import_module(f"sim_backends.{module}"), name), (module, name)
    layout = importlib.import_module("sim_backends.layout")
    for name in ("describe_workcell", "table_target_pose", "rectangle_mark_pose", "start_pose",
                 "flange_target", "flange_T_marker", "encoder_offsets", "Streams"):
        assert f"`{name}" in doc and hasattr(layout, name), name
    for name in ("SIM_ENGINES", "DEFAULT_ENGINE_ORDER", "default_sim_engine"):
        assert name in doc and hasattr(backends, name), name


def test_the_viewer_scene_matches_pybullets():
    from robots.viewer import tessellate

    def summary(cell):
        scene = cell.visual_scene()
        groups = sorted(s.group for s in scene.shapes)
        corners = {}
        for shape in scene.shapes:
            if shape.group in ("board", "target"):
                part = shape.parts[0]
                v, _ = tessellate(part)
                world = (shape.base_T_body @ part.body_T_part @ np.c_[v, np.ones(len(v))].T).T
                corners[shape.group] = (world[:, :3].min(0), world[:, :3].max(0),
                                        part.texture_png is not None)
        return groups, corners, scene.frames

    options = dict(arm="ur5e", mount="eye_to_hand", seed=3, width=64, height=48)
    with connect("sim", engine="pybullet", **options) as a, \
            connect("sim", engine="mujoco", **options) as b:
        (ga, ca, fa), (gb, cb, fb) = summary(a), summary(b)
        assert ga == gb and set(fa) == set(fb)
        lo_a, hi_a, tex_a = ca["board"]
        lo_b, hi_b, tex_b = cb["board"]
        np.testing.assert_allclose(lo_b, lo_a, atol=1e-9)
        np.testing.assert_allclose(hi_b, hi_a, atol=1e-9)
        assert tex_a and tex_b
        np.testing.assert_allclose(fb["cam"], fa["cam"], atol=1e-12)
