"""Lab 5 (depth camera calibrated by the bare flange; a rectangle's pose from its shape).

The source notebook runs headless top to bottom with its solutions and hidden tests; the
students' copy (`cobotlab labs student`) holds no solution or hidden test; the lab's helpers
(`robots.labkit.lab5`) find the flange face, its rim and the rectangle mark's corners on
simulated arms. About 30 s in all.
"""

from __future__ import annotations

import json
import re

import course_kit as kit
import cv2
import numpy as np
import pytest

from robots import connect
from robots.labkit import lab5

ASSIGNMENT = "lab5_depth"
FUNCTIONS = ("backproject", "fit_plane_ransac", "fit_flange_circle", "base_T_cam_from_flanges",
             "rectangle_pose")


def _namespace() -> dict:
    ns = {"np": np}
    for source in kit.solution_sources(ASSIGNMENT, FUNCTIONS).values():
        exec(source, ns)  # noqa: S102 - our own reference cells
    return ns


def _number_after(text: str, label: str) -> float:
    return float(re.search(re.escape(label) + r"\s*([-+0-9.]+)", text).group(1))


# --------------------------------------------------------------------------- notebooks


def test_source_notebook_runs_with_solutions_and_hidden_tests():
    nb = kit.execute_source(ASSIGNMENT, timeout_s=180)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)
    graded = {c.metadata["nbgrader"]["grade_id"]: c for c in nb.cells
              if c.metadata.get("nbgrader", {}).get("grade")}
    assert set(graded) == {f"test_{f}" for f in FUNCTIONS}
    assert sum(c.metadata["nbgrader"]["points"] for c in graded.values()) == 10
    for name, c in graded.items():
        assert f"check({name[5:]})" in c.source.split("\n", 2)[1], name   # check() first
    text = kit.output_text(nb, "\n")
    assert "pybullet build time" not in text
    for name in FUNCTIONS:
        assert f"{name}: 2 / 2 points" in text, name
    assert "12 flange views" in text
    # The markerless calibration against the simulator's truth: well under a few mm.
    assert _number_after(text, "base_T_cam vs the truth:") < 2.0
    assert _number_after(text, "error against the truth:") < 1.0
    assert "cv2.solvePnP     : vs truth" in text


def test_release_has_no_solution_or_hidden_tests(tmp_path):
    from cobotlab.labs import RELEASE_LEAKS, write_student_labs

    (notebook,) = write_student_labs(tmp_path / "labs", labs=[ASSIGNMENT])
    text = notebook.read_text()
    for needle in (*RELEASE_LEAKS, "solutions", "np.linalg.svd(pts[best] - centre",
                   "dist - radius_m", "cb - R @ ca", "np.cross(np.cross(h[0], h[1])",
                   "(u - K[0, 2]) * z / K[0, 0]"):
        assert needle not in text, needle
    assert text.count("raise NotImplementedError()") == len(FUNCTIONS)
    released = json.loads(text)
    assert not any(c.get("outputs") for c in released["cells"] if c["cell_type"] == "code")


def _wrong() -> dict[str, str]:
    """Two classic mistakes as exact edits of the reference: depth left in sensor units
    (millimetres on a D435) and the algebraic circle fit without its geometric refinement."""
    s = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    wrong = {
        "backproject": s["backproject"].replace(" * float(depth_scale)", ""),
        "fit_flange_circle": s["fit_flange_circle"].replace("for _ in range(50):",
                                                            "for _ in range(0):"),
    }
    assert all(wrong[k] != s[k] for k in wrong), "the wrong edits must change the solutions"
    return {**s, **wrong}


@pytest.mark.slow
def test_full_cycle_reference_blank_and_classic_mistakes(tmp_path):
    from autograder.pipeline.pipeline import grade_course
    from autograder.secret import load_secret

    course = kit.released_course(tmp_path, ASSIGNMENT)
    kit.submit(course, ASSIGNMENT, "ref", replace=kit.solution_sources(ASSIGNMENT, FUNCTIONS))
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace=_wrong())
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    grades = {r["student_id"]: r for r in rows}
    assert grades["ref"]["score"] == 10.0 and grades["ref"]["max_score"] == 10.0, grades["ref"]
    assert grades["ref"]["flags"] == "", grades["ref"]
    assert grades["blank"]["score"] == 0.0
    # backproject in millimetres keeps only the holes' share (0.2 of 2 points); the unrefined
    # circle fit loses credit on the short arcs; the other three functions are the reference's.
    assert 6.0 + 0.4 <= grades["wrong"]["score"] < 6.0 + 0.4 + 2.0, grades["wrong"]
    feedback = (course / "feedback_cobotlab" / "wrong" / ASSIGNMENT / "feedback.html").read_text()
    assert "depth is in sensor units" in feedback
    assert "Kasa" in feedback and "left unrefined" in feedback
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        assert secret not in path.read_text(), path


# --------------------------------------------------------------------------- the lab's helpers


@pytest.mark.parametrize("arm", ["panda", "cobotta"])
def test_flange_pipeline_finds_the_face_centre(arm):
    ns = _namespace()
    with connect("sim", arm=arm, mount="eye_to_hand", flange_target=False, tool=None,
                 depth_model="d435", seed=2) as cell:
        K, scale = cell.camera.intrinsics.K, cell.camera.depth_scale
        radius = cell.truth.flange.radius

        def measure(frame):
            return lab5.measure_flange(lab5.to_z16(frame.depth, scale), K, scale, radius,
                                       ns["backproject"], ns["fit_plane_ransac"],
                                       ns["fit_flange_circle"])

        capture = lab5.capture_flange_centres(
            cell, lab5.flange_goals(cell, np.random.default_rng(2), 30), measure, n_poses=5)
    assert len(capture.cam_centres) == 5
    # Sub-pixel: a pixel is 0.7 mm wide at 0.45 m; the D435's depth noise is ~0.7 mm there.
    err = np.linalg.norm(capture.cam_centres - capture.true_cam_centres, axis=1)
    assert np.max(err) < 0.0015, err


def test_to_z16_and_rim_points_on_a_drawn_disc():
    depth = np.full((60, 80), 1.0, np.float32)
    vv, uu = np.mgrid[0:60, 0:80]
    disc = (uu - 40.3) ** 2 + (vv - 29.6) ** 2 < 15.0 ** 2
    depth[disc] = 0.5
    depth[0, 0] = np.nan
    raw = lab5.to_z16(depth, 0.001)
    assert raw.dtype == np.uint16 and raw[0, 0] == 0 and raw[30, 40] == 500
    K = np.array([[300.0, 0, 39.5], [0, 300.0, 29.5], [0, 0, 1]])
    points = _namespace()["backproject"](raw, K, 0.001)
    rim, rim_px = lab5.rim_points(disc, points, K, np.array([0, 0, 0.5]), np.array([0, 0, -1.0]))
    # The rim runs midway between the disc's border pixels and their neighbours: on the circle.
    r = np.hypot(rim_px[:, 0] - 40.3, rim_px[:, 1] - 29.6)
    assert len(rim) > 80 and abs(np.mean(r) - 15.0) < 0.2
    assert np.allclose(rim[:, 2], 0.5)


def _flange_in_front_of_a_housing(ring_px: float):
    """Exact depth (m) of a fronto-parallel face (radius 18 px, 0.5 m) in front of a housing
    ``ring_px`` wider in radius, 6.5 mm behind it, before a wall at 1 m; its K."""
    vv, uu = np.mgrid[0:120, 0:160]
    r = np.hypot(uu - 80.3, vv - 59.6)
    depth = np.where(r < 18.0, 0.5, np.where(r < 18.0 + ring_px, 0.5065, 1.0))
    return depth, np.array([[300.0, 0, 79.5], [0, 300.0, 59.5], [0, 0, 1]])


@pytest.mark.parametrize("ring_px", [2.0, 2.6, 6.0])
def test_rim_points_find_the_face_whether_or_not_the_housing_ring_survives(ring_px):
    # Through the real D4xx model: a 6.5 mm step at 0.5 m is no edge to it, the housing's
    # outer edge is, with 2 pixels lost either side. A 2-pixel ring is lost whole, a
    # 2.6-pixel one (the MuJoCo UR at 320 x 240) in most places: the band then runs from the
    # face to the wall, and its middle (what rim_points took before) lay 2 pixels out. A
    # 6-pixel ring survives.
    from sim_backends.depth_noise import RealSenseDepthModel

    exact, K = _flange_in_front_of_a_housing(ring_px)
    depth = RealSenseDepthModel(subpixel=0.0).apply(exact, K, np.random.default_rng(0))
    points = _namespace()["backproject"](lab5.to_z16(depth, 0.001), K, 0.001)
    face = np.isfinite(depth) & (depth < 0.503)
    rim, rim_px = lab5.rim_points(face, points, K, np.array([0, 0, 0.5]), np.array([0, 0, -1.0]))
    r = np.hypot(rim_px[:, 0] - 80.3, rim_px[:, 1] - 59.6)
    assert len(rim) > 80
    assert abs(np.median(r) - 18.0) < 0.5, np.median(r)
    with pytest.raises(ValueError, match="near_m"):
        lab5.rim_points(face, points, K, np.array([0, 0, 0.5]), np.array([0, 0, -1.0]),
                        near_m=float("nan"))


def test_face_plane_leaves_the_housing_strip_a_tilted_plane_took_in():
    """A face (radius 31.5 mm, 0.45 m, D435-like noise) with the wrist housing 6.5 mm behind
    it on one side, and a plane tilted 6.4 deg that passes within 3 mm of both that strip and
    most of the face (what RANSAC found on a Panda view): the refit on the face's inner disc
    is the face's plane."""
    rng = np.random.default_rng(0)
    radius, g = 0.0315, np.arange(-0.06, 0.06, 0.0008)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    r = np.hypot(x, y)
    face, housing = r < radius, (r >= radius) & (r < 0.05) & (x > 0)
    z = np.where(face, 0.45, 0.4565) + rng.normal(0.0, 0.0007, x.size)
    pts = np.column_stack([x, y, z])[face | housing]
    tilt = np.arctan(0.0045 / 0.04)
    normal = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    took_in = (np.abs((pts - [0, 0, 0.45]) @ normal) < 0.003) & (pts[:, 2] > 0.454)
    assert took_in.sum() > 300                      # the start is the trap, not the answer
    centre, n = lab5.face_plane(pts, np.array([0, 0, 0.45]), normal,
                                _namespace()["fit_plane_ransac"], 0.003, radius)
    assert np.degrees(np.arccos(abs(n[2]))) < 0.5
    assert abs(centre[2] - 0.45) < 0.0005 and np.hypot(*centre[:2]) < 0.7 * radius


def test_find_rectangle_corners_on_a_drawn_quadrilateral():
    rgb = np.full((240, 320, 3), 190, np.uint8)
    quad = np.array([[100.0, 70.0], [210.0, 90.0], [190.0, 180.0], [90.0, 160.0]])
    scale = 16
    cv2.fillPoly(rgb, [np.round(quad * scale).astype(np.int32)], (20, 20, 20), shift=4)
    corners = lab5.find_rectangle_corners(rgb)
    assert corners.shape == (4, 2)
    # TL, TR, BR, BL; fillPoly also fills the pixels the outline touches (up to half a pixel
    # more than the polygon), so within a pixel.
    np.testing.assert_allclose(corners, quad, atol=1.0)
    assert lab5.find_rectangle_corners(np.full_like(rgb, 190)) is None


def test_the_real_hardware_connect_lines_fit_each_drivers_options():
    # The "On real hardware" cell is commented out (no arm here), so nothing runs it: each
    # line's keywords are checked against its driver's create_workcell instead, and the
    # camera keywords against the RealSense option every driver resolves.
    import ast
    import importlib
    import inspect

    nb = json.loads(kit.source_notebook(ASSIGNMENT).read_text())
    (cell,) = [c for c in nb["cells"]
               if c["metadata"].get("nbgrader", {}).get("grade_id") == "real_robot"]
    lines = [line.lstrip("# ").split("  #")[0] for line in "".join(cell["source"]).splitlines()]
    calls = [ast.parse(line).body[0].value for line in lines if line.startswith("cell = connect(")]
    kinds = {call.args[0].value for call in calls}
    assert kinds == {"ur", "franka", "aubo", "cobotta"}, kinds
    cam_line = next(line for line in lines if line.startswith("cam = "))
    cam_keys = {k.value for k in ast.parse(cam_line).body[0].value.keys}
    assert cam_keys == {"camera", "camera_options"}
    for call in calls:
        kind = call.args[0].value
        driver = importlib.import_module(f"robots.drivers.{kind}")
        accepted = set(inspect.signature(driver.create_workcell).parameters)
        given = {k.arg for k in call.keywords if k.arg is not None} | cam_keys
        assert given <= accepted, (kind, sorted(given - accepted))
        for k in call.keywords:
            if k.arg == "tool":
                assert k.value.value == "none", (kind, "the flange must be bare")


def test_a_recorded_session_reruns_through_the_notebooks_load_cell(tmp_path, capsys):
    # Record three views on the simulated UR5e as a real session would (as_capture, then
    # save_capture), then run the notebook's own "load a capture" cell on that folder.
    from robots.capture import save_capture
    from robots.geometry import transform_points

    ns = _namespace()
    with connect("sim", arm="ur5e", mount="eye_to_hand", flange_target=False, tool=None,
                 depth_model="d435", seed=3) as cell:
        K, scale = cell.camera.intrinsics.K, cell.camera.depth_scale
        radius = cell.truth.flange.radius

        def measure(frame):
            return lab5.measure_flange(lab5.to_z16(frame.depth, scale), K, scale, radius,
                                       ns["backproject"], ns["fit_plane_ransac"],
                                       ns["fit_flange_circle"])

        capture = lab5.capture_flange_centres(
            cell, lab5.flange_goals(cell, np.random.default_rng(3), 20), measure, n_poses=3)
        folder = save_capture(lab5.as_capture(capture, cell.camera, "ur5e"), tmp_path / "cap")
        base_T_cam = cell.truth.base_T_cam
    nb = json.loads(kit.source_notebook(ASSIGNMENT).read_text())
    (load,) = [c for c in nb["cells"]
               if c["metadata"].get("nbgrader", {}).get("grade_id") == "load_capture"]
    source = "".join(load["source"])
    assert 'CAPTURE_FOLDER = None' in source and "RADIUS_M = 0.0315" in source
    ns.update(np=np, lab5=lab5, geo=__import__("robots.geometry", fromlist=["geometry"]),
              INLIER_M=0.003)
    exec(source.replace("CAPTURE_FOLDER = None", f"CAPTURE_FOLDER = {str(folder)!r}"), ns)
    out = capsys.readouterr().out
    assert "3 views" in out, out
    # The same centres as measured live, and a map that puts them on the flange positions.
    centres = np.array(ns["centres"])
    np.testing.assert_allclose(centres, capture.cam_centres, atol=1e-9)
    assert np.abs(transform_points(base_T_cam, centres)
                  - capture.base_T_flanges[:, :3, 3]).max() < 2e-3
