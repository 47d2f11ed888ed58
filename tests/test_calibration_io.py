"""Calibration results on disk: one YAML file that round-trips bit for bit."""

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from robots import CalibrationResult, load_calibration, save_calibration
from robots.geometry import pose_from_rotvec, quat_xyzw_from_pose


def _save(path, pose, **kw):
    args = dict(
        parent="flange",
        child="cam",
        method="park",
        n_samples=15,
        residuals={"rotation_deg": 0.05, "translation_m": 4.2e-4},
    )
    args.update(kw)
    return save_calibration(path, pose, **args)


@settings(max_examples=40, deadline=None)
@given(
    rotvec=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
    t=st.lists(
        st.floats(-10, 10).filter(lambda v: v == 0 or abs(v) > 1e-300), min_size=3, max_size=3
    ),
)
def test_round_trip_is_bit_exact(tmp_path_factory, rotvec, t):
    path = tmp_path_factory.mktemp("cal") / "flange_T_cam.yaml"
    pose = pose_from_rotvec(rotvec, t)
    written = _save(path, pose)
    loaded = load_calibration(path)
    assert np.array_equal(loaded.pose, pose)
    assert loaded == written


def test_file_is_readable_and_complete(tmp_path):
    pose = pose_from_rotvec([0.1, -0.2, 0.3], [0.1, 0.2, 1 / 3])
    path = tmp_path / "base_T_cam.yaml"
    _save(
        path,
        pose,
        parent="base",
        robot_id="UR5e #42: lab 3",
        camera_id="D435 123",
        residuals={"rotation_deg": np.float64(0.07), "per_pair_mm": np.array([0.1, 0.25])},
    )
    text = path.read_text()
    assert text.startswith("# cobotlab calibration result: base_T_cam maps cam coordinates")
    doc = yaml.safe_load(text)
    assert doc["translation_m"] == [0.1, 0.2, 1 / 3]
    assert np.array_equal(doc["matrix"], pose[:3, :3])
    assert np.allclose(doc["quat_xyzw"], quat_xyzw_from_pose(pose)[0], atol=0, rtol=0)
    assert isinstance(doc["date"], str) and doc["date"][:2] == "20"
    result = load_calibration(path)
    assert result.name == "base_T_cam" and result.n_samples == 15
    assert result.residuals == {"rotation_deg": 0.07, "per_pair_mm": [0.1, 0.25]}
    assert (result.robot_id, result.camera_id) == ("UR5e #42: lab 3", "D435 123")
    assert np.array_equal(result.translation, pose[:3, 3]) and np.array_equal(
        result.rotation, pose[:3, :3]
    )
    assert isinstance(result.date, str)


def test_result_save_round_trips_including_the_date(tmp_path):
    result = _save(
        tmp_path / "a.yaml",
        pose_from_rotvec([0, 0, 1.0], [0, 0, 0.1]),
        date="2024-05-01T12:00:00+00:00",
    )
    result.save(tmp_path / "b.yaml")
    assert load_calibration(tmp_path / "b.yaml") == result
    assert (tmp_path / "a.yaml").read_text() == (tmp_path / "b.yaml").read_text()


def _edit(path, **changes):
    doc = yaml.safe_load(path.read_text())
    for key, value in changes.items():
        if value is None:
            del doc[key]
        else:
            doc[key] = value
    path.write_text(yaml.safe_dump(doc))


def test_a_hand_edited_quaternion_that_disagrees_is_refused(tmp_path):
    path = tmp_path / "x.yaml"
    result = _save(path, pose_from_rotvec([0.3, 0.1, -0.2], [0.01, 0.02, 0.03]))
    q = result.quat_xyzw
    q[0] += 1e-4
    _edit(path, quat_xyzw=[float(v) for v in q / np.linalg.norm(q)])
    with pytest.raises(ValueError, match="quat_xyzw and matrix disagree.*matrix is authoritative"):
        load_calibration(path)


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1.01]]}, "not orthonormal"),
        ({"matrix": [[1, 0, 0], [0, 1, 0]]}, "3x3"),
        ({"n_samples": None}, "missing"),
        ({"format": "something-else"}, "not a cobotlab calibration file"),
        ({"residuals": {"rotation_deg": float("nan")}}, "not finite"),
        ({"parent": ""}, "frame name"),
    ],
)
def test_malformed_files_are_refused(tmp_path, changes, match):
    path = tmp_path / "x.yaml"
    _save(path, np.eye(4))
    _edit(path, **changes)
    with pytest.raises(ValueError, match=match):
        load_calibration(path)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"pose": np.full((4, 4), np.nan)}, "NaN"),
        ({"residuals": {"rms": np.inf}}, "not finite"),
        ({"residuals": [0.1]}, "dict"),
        ({"n_samples": 2.5}, "whole number"),
        ({"child": None}, "frame name"),
    ],
)
def test_bad_results_are_not_written(tmp_path, kwargs, match):
    pose = kwargs.pop("pose", np.eye(4))
    with pytest.raises(ValueError, match=match):
        _save(tmp_path / "x.yaml", pose, **kwargs)
    assert not (tmp_path / "x.yaml").exists()


def test_calibration_result_equality_is_exact():
    a = CalibrationResult(np.eye(4), "flange", "cam", "tsai", 10, {}, "2024-01-01")
    b = CalibrationResult(np.eye(4), "flange", "cam", "tsai", 10, {}, "2024-01-01")
    assert a == b
    b.pose = np.eye(4)
    b.pose[0, 3] = 1e-17
    assert a != b
