"""The pieces the hand-eye benchmarks judge with: held-out corner error, the oracle fit, and the
paired-bootstrap verdicts (small, fast cases; the long runs live in benchmarks/)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import handeye_accuracy as acc  # noqa: E402
import handeye_real as real  # noqa: E402

from autograder.synthetic import NoiseModel, make_real_like_hand_eye  # noqa: E402
from robots import geometry as geo  # noqa: E402


def test_held_out_error_is_zero_at_the_truth_and_grows_with_a_wrong_X():
    p = make_real_like_hand_eye(2, n_poses=5, robot_rot_deg=0, robot_trans_mm=0, robot_gain=0,
                                board_scale=1.0, pixel_px=0.0)
    board = p.board.object_points()
    Y = real.board_pose_from_views(p.base_T_flange, p.true_cam_T_target, p.X_true)
    assert np.allclose(Y, p.Y_true, atol=1e-9)
    exact = real.held_out_rms(p.X_true, Y, p.base_T_flange[0], board, p.pixels[0], p.camera.K,
                              p.camera.dist)
    assert exact < 1e-6
    off = p.X_true @ geo.make_pose(np.eye(3), [0.001, 0.0, 0.0])
    assert real.held_out_rms(off, Y, p.base_T_flange[0], board, p.pixels[0], p.camera.K,
                             p.camera.dist) > 1.0


def test_a_miss_is_called_real_only_when_the_whole_interval_is_past_the_target():
    assert acc._verdict(1.00, 0.95, 1.04, 1.05) == "met"
    assert acc._verdict(1.00, 0.95, 1.10, 1.05) == "met (within noise)"
    assert acc._verdict(1.08, 1.02, 1.15, 1.05) == "missed (within noise)"
    assert acc._verdict(1.12, 1.07, 1.18, 1.05).startswith("MISSED (real")


def test_paired_ratio_of_medians_and_its_interval():
    rng = np.random.default_rng(0)
    theirs = rng.uniform(1, 2, 300)
    ratio, lo, hi = acc.paired_ratio(0.9 * theirs, theirs, rng)
    # Paired: the same trials for both, so a uniform 10 % gain has no spread at all.
    assert ratio == pytest.approx(0.9) and lo == pytest.approx(0.9) and hi == pytest.approx(0.9)
    ratio, lo, hi = acc.paired_ratio(rng.uniform(1, 2, 300), theirs, rng)
    assert lo < ratio < hi


def test_the_oracle_knows_the_true_noise_and_only_runs_where_that_is_the_whole_model():
    scenario = acc.Scenario("pose-noise 0.1 deg/0.5 mm", "eye_in_hand", 10, "careful",
                            NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5))
    p = scenario.problem(0)
    X = acc.oracle_fit(scenario, p)
    assert geo.rotation_error_deg(X, p.X_true) < 0.3
    assert geo.translation_error(X, p.X_true) < 0.003
    pixels = acc.Scenario("pixel-noise 0.5 px", "eye_in_hand", 10, "careful",
                          NoiseModel(pixel_px=0.5, robot_rot_deg=0.02, robot_trans_mm=0.1))
    assert acc.oracle_fit(pixels, pixels.problem(0)) is None


def test_the_fold_cache_round_trips_and_is_ignored_for_other_sources(tmp_path, capsys):
    """--cache lets a long run be split into bounded pieces; a fold written by other solver
    sources must never be reused (its numbers would describe other code)."""
    path = str(tmp_path / "folds.json")
    folds = {("kuka_2", 3): {"tsai": (1.5, 7.0), "opencv RW LI": (np.nan, 2.0)}}
    real.save_cache(path, "abc", folds)
    back = real.load_cache(path, "abc")
    assert back[("kuka_2", 3)]["tsai"] == (1.5, 7.0)
    assert back[("kuka_2", 3)]["opencv RW LI"][0] is None  # a failed method stays a failure
    assert real.load_cache(path, "other") == {}
    assert "written by other sources" in capsys.readouterr().err
    assert real.source_fingerprint() == real.source_fingerprint()


def test_eye_to_hand_folds_predict_through_the_fixed_camera():
    """Eye-to-hand: X = base_T_cam, Y = flange_T_target; the held-out corners come through
    inv(X) @ base_T_flange_i @ Y, and a fold keeps a capture's given intrinsics."""
    from autograder.synthetic import make_hand_eye

    p = make_hand_eye(1, "eye_to_hand", n_poses=6)
    board = p.board.object_points()
    Y = real.board_pose_from_views(p.base_T_flange, p.true_cam_T_target, p.X_true, "eye_to_hand")
    assert np.allclose(Y, p.Y_true, atol=1e-9)
    clean = real.held_out_rms(p.X_true, Y, p.base_T_flange[0], board, p.pixels[0], p.camera.K,
                              p.camera.dist, "eye_to_hand")
    assert clean < 1e-6
    assert real.training_views(8, 3, 0).tolist() == [0, 1, 2, 4, 5, 6, 7]
    picked = real.training_views(30, 3, 8)
    assert len(picked) == 8 and 3 not in picked
    assert picked.tolist() == real.training_views(30, 3, 8).tolist()  # the same for every method
