"""The 3-D workcell view (robots/viewer.py, sim_backends/viewer_scene.py) on real PyBullet cells.

Everything is read back from the k3d scene the viewer built (``plot.objects``: the widgets whose
state is what the browser draws), never from a mock, and compared with the simulator's truth.
The last test renders the view in Debian's Chromium (software WebGL) and checks the picture.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest

from robots import connect
from robots.geometry import compose, make_pose, pose_from_rotvec, transform_points
from robots.jog import jog_step

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("k3d") is None or importlib.util.find_spec("ipywidgets") is None,
    reason="the 3-D view needs k3d and ipywidgets (the course/dev extra)")

POSE_TOL = 1e-5  # the widget holds float32 matrices: ~1e-7 relative on metre-sized values
UR5E_LINKS = ["arm/base"] + [f"arm/link_{k}" for k in range(1, 7)]


@pytest.fixture
def cell():
    with connect("sim", arm="ur5e", mount="eye_in_hand", seed=0, width=160, height=120) as c:
        yield c


def scene_tree(view) -> dict:
    """name -> k3d object, straight from the plot the browser is sent."""
    tree = {}
    for obj in view.plot.objects:
        assert obj.name not in tree, f"two objects named {obj.name!r}"
        tree[obj.name] = obj
    return tree


def drawn_at(obj) -> np.ndarray:
    return np.asarray(obj.model_matrix, dtype=float)


def drawn_vertices_in_base(obj) -> np.ndarray:
    return transform_points(drawn_at(obj), np.asarray(obj.vertices, dtype=float))


def make_view(cell, **options):
    from robots.viewer import WorkcellViewer

    return WorkcellViewer(cell, refresh_s=None, **options)


def test_the_scene_holds_the_arm_camera_board_and_frames_at_their_true_poses(cell):
    view = make_view(cell)
    tree = scene_tree(view)
    truth = cell.truth
    for name in [*UR5E_LINKS, "table", "calibration board", "flange target", "frustum",
                 "frame base", "frame flange", "frame cam", "frame target", "legend"]:
        assert name in tree, f"{name} missing from the scene: {sorted(tree)}"
    np.testing.assert_allclose(drawn_at(tree["frame base"]), np.eye(4), atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frame flange"]), truth.base_T_flange(),
                               atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frame cam"]), truth.base_T_cam_now(), atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frustum"]), truth.base_T_cam_now(), atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frame target"]), truth.base_T_board, atol=POSE_TOL)
    # The board body's frame is the target frame (sim_backends.textures), printed pattern on it.
    np.testing.assert_allclose(drawn_at(tree["calibration board"]), truth.base_T_board,
                               atol=POSE_TOL)
    assert tree["calibration board"].texture is not None
    assert len(tree["calibration board"].uvs) == len(tree["calibration board"].vertices)


def test_drawn_links_end_at_the_flange_the_kinematics_report(cell):
    """The last link's cylinder, as drawn, must end where the ISO 9409 flange face begins
    (FLANGE_PROUD_M behind tool0, 0.0996 m beyond link_6's frame in the URDF), and the face,
    drawn on tool0, must end on tool0, both along the flange's z axis: this checks the
    visual-frame convention."""
    from sim_backends.flanges import FLANGE_PROUD_M, FLANGES

    view = make_view(cell)
    for q_change in (None, [0.3, -0.2, 0.25, 0.4, -0.5, 0.6]):
        if q_change is not None:
            cell.robot.move_joints(cell.robot.joint_positions() + q_change, 0.5)
            view.update()
        flange = cell.truth.base_T_flange()
        points = drawn_vertices_in_base(scene_tree(view)["arm/link_6"])
        in_flange = transform_points(np.linalg.inv(flange), points)
        # the cylinder's end face is where the flange face's rim begins
        assert np.abs(in_flange[:, 2] + FLANGE_PROUD_M).min() < POSE_TOL
        assert in_flange[:, 2].min() > -0.0996 - POSE_TOL
        assert in_flange[:, 2].max() < -FLANGE_PROUD_M + POSE_TOL
        radial = np.linalg.norm(in_flange[:, :2], axis=1)
        assert radial.max() == pytest.approx(0.036, abs=1e-5)  # link_6's radius, about z
        face = transform_points(np.linalg.inv(flange),
                                drawn_vertices_in_base(scene_tree(view)["arm/tool0"]))
        assert np.abs(face[:, 2]).min() < POSE_TOL and face[:, 2].max() < POSE_TOL
        assert face[:, 2].min() == pytest.approx(-FLANGE_PROUD_M, abs=POSE_TOL)
        assert np.linalg.norm(face[:, :2], axis=1).max() == pytest.approx(
            FLANGES["ur5e"].radius, abs=1e-5)


def test_drawn_panda_meshes_lie_on_the_simulators_collision_surfaces():
    """The Panda is drawn from its .obj meshes (its links' inertial frames sit centimetres
    off their link frames): every drawn vertex must touch the link PyBullet collides with.
    A vertex never lies outside the convex hull PyBullet uses for a mesh, so a signed distance
    above the probe's radius plus the collision margin means the drawing is misplaced."""
    import pybullet as p

    from sim_backends.flanges import FLANGE_PROUD_M

    with connect("sim", engine="pybullet", arm="panda", seed=0, width=96, height=72) as cell:
        cell.robot.move_joints(cell.robot.joint_positions() + 0.3, 0.5)
        view = make_view(cell)
        client, body = cell.client, cell.arm.body_id
        probe_radius = 0.0005
        shape = p.createCollisionShape(p.GEOM_SPHERE, radius=probe_radius, physicsClientId=client)
        probe = p.createMultiBody(0, shape, -1, [5, 5, 5], physicsClientId=client)
        rng = np.random.default_rng(0)
        for link in range(-1, 7):
            info = (p.getBodyInfo(body, physicsClientId=client)[0] if link == -1
                    else p.getJointInfo(body, link, physicsClientId=client)[12])
            points = drawn_vertices_in_base(scene_tree(view)[f"arm/{info.decode()}"])
            if info.decode() == "panda_link7":
                # drawn FLANGE_PROUD_M back along its axis, so the flange face on link 8
                # stands proud of it in depth (sim_backends.arms._render_urdf): undone here
                axis = p.getLinkState(body, link, physicsClientId=client)[5]
                z = np.array(p.getMatrixFromQuaternion(axis)).reshape(3, 3)[:, 2]
                points = points + FLANGE_PROUD_M * z
            distances = []
            for point in points[rng.choice(len(points), 30, replace=False)]:
                p.resetBasePositionAndOrientation(probe, point.tolist(), [0, 0, 0, 1],
                                                  physicsClientId=client)
                contacts = p.getClosestPoints(probe, body, 0.1, linkIndexB=link,
                                              physicsClientId=client)
                distances.append(min(c[8] for c in contacts) if contacts else 0.1)
            assert max(distances) < probe_radius + 0.0015, (link, max(distances))


def test_update_follows_a_move_and_resends_only_what_moved(cell):
    view = make_view(cell)
    tree = scene_tree(view)
    truth = cell.truth
    board_before = drawn_at(tree["calibration board"])
    link1_before = drawn_at(tree["arm/link_1"])
    assert view.update() == 0  # nothing moved yet

    q = cell.robot.joint_positions()
    q[0] += 0.2  # the shoulder turns: every link but the base moves
    cell.robot.move_joints(q, 0.5)
    moved = view.update()
    assert moved >= 8  # six links, flange marker, flange and cam frames, frustum
    np.testing.assert_allclose(drawn_at(tree["frame flange"]), truth.base_T_flange(),
                               atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frame cam"]), truth.base_T_cam_now(), atol=POSE_TOL)
    np.testing.assert_allclose(drawn_at(tree["frustum"]), truth.base_T_cam_now(), atol=POSE_TOL)
    turn = pose_from_rotvec([0.0, 0.0, 0.2])  # link_1 turns about the base z axis by 0.2 rad
    np.testing.assert_allclose(drawn_at(tree["arm/link_1"]), turn @ link1_before, atol=POSE_TOL)
    np.testing.assert_array_equal(drawn_at(tree["calibration board"]), board_before)
    np.testing.assert_allclose(drawn_at(tree["arm/base"]), np.eye(4), atol=POSE_TOL)
    assert view.update() == 0


def test_eye_to_hand_the_camera_stays_and_the_target_rides_on_the_flange():
    with connect("sim", arm="ur5e", mount="eye_to_hand", seed=0, width=160, height=120) as cell:
        view = make_view(cell)
        tree = scene_tree(view)
        truth = cell.truth
        cam_before = drawn_at(tree["frame cam"])
        np.testing.assert_allclose(cam_before, truth.base_T_cam, atol=POSE_TOL)
        cell.robot.move_to(jog_step(cell.robot, "rz", 0.1), 0.1)
        view.update()
        np.testing.assert_array_equal(drawn_at(tree["frame cam"]), cam_before)
        on_flange = truth.base_T_flange() @ truth.flange_T_marker
        np.testing.assert_allclose(drawn_at(tree["frame target"]), on_flange, atol=POSE_TOL)
        np.testing.assert_allclose(drawn_at(tree["flange target"]), on_flange, atol=POSE_TOL)
        view.show_estimate("cam", truth.nominal_base_T_cam, label="cam (design)")
        np.testing.assert_allclose(drawn_at(scene_tree(view)["estimate cam (design)"]),
                                   truth.nominal_base_T_cam, atol=POSE_TOL)


def test_an_estimate_is_dashed_beside_the_truth_and_follows_the_flange(cell):
    view = make_view(cell)
    design = cell.truth.nominal_flange_T_cam
    view.show_estimate("cam", design, parent="flange", label="cam (design drawing)")
    tree = scene_tree(view)
    estimate = tree["estimate cam (design drawing)"]
    solid = tree["frame cam"]
    assert len(estimate.indices) == 18 and len(solid.indices) == 3  # 6 dashes per axis
    assert "label estimate cam (design drawing)" in tree and "label frame cam" in tree
    assert "dashed: cam (design drawing)" in tree["legend"].text
    np.testing.assert_allclose(drawn_at(estimate), cell.robot.flange_pose() @ design,
                               atol=POSE_TOL)

    cell.robot.move_to(jog_step(cell.robot, "z", 0.02), 0.1)
    view.update()
    np.testing.assert_allclose(drawn_at(estimate), cell.robot.flange_pose() @ design,
                               atol=POSE_TOL)
    # Showing the same label again moves that estimate rather than adding another.
    shifted = compose(design, make_pose(t=[0.01, 0, 0]))
    view.show_estimate("cam", shifted, parent="flange", label="cam (design drawing)")
    assert len(scene_tree(view)) == len(tree)
    np.testing.assert_allclose(drawn_at(estimate), cell.robot.flange_pose() @ shifted,
                               atol=POSE_TOL)
    with pytest.raises(ValueError, match="parent"):
        view.show_estimate("cam", design, parent="camera")
    bad = np.eye(4)
    bad[0, 0] = -1
    with pytest.raises(ValueError):
        view.show_estimate("cam", bad)


def test_the_chess_scene_shows_every_piece_and_follows_a_moved_one():
    from sim_backends.scene import set_pose_of_body

    with connect("sim", engine="pybullet", arm="ur5e", scene="chess", seed=0, width=160,
                 height=120) as cell:   # moves a piece through PyBullet
        view = make_view(cell)
        tree = scene_tree(view)
        pieces = cell.truth.pieces
        drawn = {n: o for n, o in tree.items() if n.startswith("piece ")}
        assert len(drawn) == len(pieces) == 32
        assert {"chess board", "tool/suction_cup", "frame world", "frame tcp"} <= set(tree)
        for piece in pieces.values():
            name = f"piece {piece.body_id}: {piece.colour} {piece.kind}"
            np.testing.assert_allclose(drawn_at(drawn[name]), piece.base_T_piece, atol=POSE_TOL)

        e2 = pieces["e2"]
        world_T_e4 = cell.truth._chess.world_T_square("e4")
        set_pose_of_body(cell.client, e2.body_id, world_T_e4)
        view.update()
        moved = cell.truth.pieces["e4"]
        assert moved.body_id == e2.body_id
        np.testing.assert_allclose(drawn_at(drawn[f"piece {e2.body_id}: white pawn"]),
                                   moved.base_T_piece, atol=POSE_TOL)


def test_beside_the_jog_panel_every_jog_redraws_the_view(cell):
    view = make_view(cell)
    box = view.with_jog_panel(refresh_s=None)
    panel = view.jog_panel
    assert list(box.children) == [view.plot, panel.widget]
    before = drawn_at(scene_tree(view)["frame flange"])
    panel.axis_buttons[("y", 1)].click()
    after = drawn_at(scene_tree(view)["frame flange"])
    np.testing.assert_allclose(after, cell.truth.base_T_flange(), atol=POSE_TOL)
    assert np.linalg.norm(after[:3, 3] - before[:3, 3]) == pytest.approx(0.005, abs=5e-4)


def test_a_loop_of_moves_animates_the_view_without_calling_update(cell):
    view = make_view(cell)
    flange = scene_tree(view)["frame flange"]
    view.min_redraw_s = 0.0
    for step in range(3):  # as a servo loop in one cell: no update() call, no event loop
        cell.robot.move_to(jog_step(cell.robot, "x", 0.005), 0.1)
        np.testing.assert_allclose(drawn_at(flange), cell.truth.base_T_flange(), atol=POSE_TOL)

    view.min_redraw_s = 3600.0  # throttled: a move right after a redraw waits for the next
    view.update()
    drawn = drawn_at(flange)
    cell.robot.move_to(jog_step(cell.robot, "x", 0.005), 0.1)
    np.testing.assert_array_equal(drawn_at(flange), drawn)
    view.update()
    np.testing.assert_allclose(drawn_at(flange), cell.truth.base_T_flange(), atol=POSE_TOL)

    view.close()  # a closed view stops following the robot
    assert view._robot_moved not in cell.robot.move_listeners


def test_a_failing_move_listener_warns_and_never_fails_the_move(cell):
    def broken():
        raise RuntimeError("display gone")

    cell.robot.move_listeners.append(broken)
    target = jog_step(cell.robot, "y", 0.005)
    with pytest.warns(RuntimeWarning, match="display gone"):
        cell.robot.move_to(target, 0.1)
    np.testing.assert_allclose(cell.robot.flange_pose()[:3, 3], target[:3, 3], atol=5e-4)


@pytest.mark.parametrize("wrap", ["robot", "workcell"])
def test_a_robot_without_a_scene_model_gets_its_frames_only(cell, wrap):
    from robots.interfaces import Workcell

    # A plain Workcell is what a real driver returns: visual_scene() is the default None.
    target = cell.robot if wrap == "robot" else Workcell(cell.robot, cell.camera, kind="ur")
    view = make_view(target)
    tree = scene_tree(view)
    assert {"frame base", "frame flange", "legend"} <= set(tree)
    assert not any(n.startswith("arm/") for n in tree) and "frustum" not in tree
    assert "what the robot reports" in tree["legend"].text
    np.testing.assert_allclose(drawn_at(tree["frame flange"]), cell.robot.flange_pose(),
                               atol=POSE_TOL)
    cell.close()
    assert view.update() == 0  # a closed robot leaves the view as it was


def test_the_timer_redraws_between_cells_on_the_event_loop(cell):
    import asyncio

    from robots.viewer import WorkcellViewer

    assert not WorkcellViewer(cell, refresh_s=0.5).auto_refresh_running  # no loop, no timer

    async def scenario():
        view = WorkcellViewer(cell, refresh_s=0.02)
        assert view.auto_refresh_running
        cell.robot.move_to(jog_step(cell.robot, "x", -0.01), 0.05)
        flange = scene_tree(view)["frame flange"]
        for _ in range(50):
            await asyncio.sleep(0.02)
            if np.allclose(drawn_at(flange), cell.truth.base_T_flange(), atol=POSE_TOL):
                break
        np.testing.assert_allclose(drawn_at(flange), cell.truth.base_T_flange(), atol=POSE_TOL)
        view.close()
        assert not view.auto_refresh_running

    asyncio.run(scenario())


CHROMIUM = Path(os.environ.get("COBOTLAB_CHROMIUM", "/usr/bin/chromium"))


@pytest.mark.slow
def test_chromium_draws_the_arm_the_board_and_the_frames(cell, tmp_path):
    """The standalone page of the view in Debian's Chromium, software WebGL as on a laptop
    without a GPU driver. The screenshot is left in tmp_path for a person to look at."""
    pytest.importorskip("playwright.sync_api")
    if not CHROMIUM.exists():
        pytest.skip(f"needs Debian's Chromium at {CHROMIUM} (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    view = make_view(cell, height=600)
    view.show_estimate("cam", cell.truth.nominal_flange_T_cam @ make_pose(t=[0.03, 0, 0]),
                       parent="flange", label="cam (estimate)")
    page_path = view.save_html(tmp_path / "view.html")
    shot = tmp_path / "view.png"
    errors = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=str(CHROMIUM), headless=True,
            args=["--no-sandbox", "--disable-gpu", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update"])
        try:
            page = browser.new_page(viewport={"width": 900, "height": 640})
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.goto(Path(page_path).as_uri())
            page.wait_for_function("document.querySelector('canvas') !== null", timeout=30000)
            page.wait_for_timeout(3000)  # the objects load asynchronously
            page.screenshot(path=str(shot))
        finally:
            browser.close()
    print(f"screenshot: {shot}")
    assert not errors, errors
    import cv2

    rgb = cv2.cvtColor(cv2.imread(str(shot)), cv2.COLOR_BGR2RGB).astype(int)

    def share(colour, tol=40):
        return float(np.mean(np.abs(rgb - np.array(colour)).max(axis=2) < tol))

    table = [int(round(255 * c)) for c in (0.78, 0.70, 0.58)]
    assert share(table, 45) > 0.15, "the table is not drawn"
    assert share((0, 0, 0), 35) > 0.003, "the board's black squares are not drawn"
    assert share((0xE4, 0x1A, 0x1C), 60) > 1e-4, "no red x axis in the picture"
    assert share((0x6A, 0x3D, 0x9A), 50) > 2e-5, "no camera frustum in the picture"
