"""The camera's metric scale against ground truth (`seesys camera check`), and the depth correction it suggests,
applied by the device and recorded in the session."""

import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from testkit.sample import SAMPLE, run_seesys

from seesys.core.camera_scale import ScaleCheckError, ScaleSettings, describe, window_scales
from seesys.core.errors import ConfigError
from seesys.core.trajectory import Poses
from seesys.io.camera_check import load_scale_settings, session_scale, sessions_scale_line
from seesys.io.config import CONFIG_DIR_ENV, write_config_dir

SETTINGS = ScaleSettings(depth_correction=1.0, warn_above=0.02, window_frames=90, step_frames=15, min_path_m=0.3)


def walk(n: int, speed_m_per_frame: float, seed: int = 0) -> Poses:
    """A smooth 3-D path at 30 Hz."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(n) / 30.0
    heading = np.cumsum(rng.normal(0, 0.05, size=(n, 3)), axis=0)
    steps = speed_m_per_frame * np.stack([np.cos(heading[:, 0]), np.sin(heading[:, 0]), np.sin(heading[:, 1])], 1)
    return Poses.from_rotations(t, np.cumsum(steps, axis=0), Rotation.from_rotvec(heading * 0.1))


def test_a_trajectory_scaled_by_1_plus_s_gives_a_depth_scale_error_of_s_whatever_its_frame():
    truth = walk(400, 0.01)
    s = 0.07
    moved = Rotation.from_euler("xyz", [0.3, -1.0, 2.0])
    estimate = Poses(
        truth.timestamps, moved.apply(truth.positions * (1 + s)) + [5.0, -2.0, 1.0], truth.quaternions_xyzw
    )
    tracked = np.ones(400, bool)
    tracked[200:215] = False  # a loss: no window spans it
    fit = window_scales(estimate, tracked, truth, 0.01, SETTINGS)
    assert fit.windows == 15  # frames 0-199: windows starting at 0, 15, ..., 105 (8); 215-399: 215, ..., 305 (7)
    assert fit.depth_scale_error == pytest.approx(s, abs=1e-9)
    assert fit.correction() == pytest.approx(1 / (1 + s)) and fit.correction(0.9) == pytest.approx(0.9 / (1 + s))
    assert fit.depth_factor(5000.0) == pytest.approx(5000.0 * (1 + s))
    assert "7.0% long" in describe(fit)


def test_a_camera_that_hardly_moves_or_has_no_ground_truth_in_time_is_refused_by_name():
    still = walk(200, 0.001)
    with pytest.raises(ScaleCheckError, match="moves 0.3 m"):
        window_scales(still, np.ones(200, bool), still, 0.01, SETTINGS)
    truth = walk(200, 0.01)
    late = Poses(truth.timestamps + 100.0, truth.positions, truth.quaternions_xyzw)
    with pytest.raises(ScaleCheckError, match="cannot be measured"):
        window_scales(late, np.ones(200, bool), truth, 0.01, SETTINGS)


def test_the_startup_warning_names_the_recorded_error_above_the_threshold_only():
    assert ScaleSettings(1.0, 0.02, 90, 15, 0.3).warning() is None
    assert ScaleSettings(0.985, 0.02, 90, 15, 0.3).warning() is None
    warning = ScaleSettings(0.9346, 0.02, 90, 15, 0.3).warning()
    assert "7.0% long" in warning and "depth_correction = 0.9346" in warning


def test_a_correction_out_of_range_is_a_config_error_naming_the_table(tmp_path):
    with pytest.raises(ConfigError, match=r"\[scale\].*depth_correction"):
        load_scale_settings(write_config_dir(tmp_path, {"depth_correction": 5.0}))


def test_a_monocular_session_is_refused_with_the_reason(tmp_path):
    (tmp_path / "session.json").write_text(json.dumps({"mode": "mono"}))
    with pytest.raises(ScaleCheckError, match="monocular SLAM has no metric scale"):
        session_scale(tmp_path, SETTINGS, 0.05)
    assert sessions_scale_line([tmp_path], SETTINGS, 0.05).endswith(
        "not measured "
        f"({tmp_path}: a mono session; monocular SLAM "
        "has no metric scale, so the camera's scale is "
        "measured on RGB-D sessions)"
    )


@pytest.mark.slam
@pytest.mark.system
def test_a_7_percent_depth_scale_error_is_found_within_1_percent_and_the_suggested_correction_removes_it(tmp_path):
    """The sample with its calibration's depth_factor divided by 1.07: the depth reads 7 % long, ORB-SLAM3's
    world and trajectory are 7 % too large, and only the ground truth shows it."""
    source = tmp_path / "long_depth"
    shutil.copytree(SAMPLE, source)
    calibration = source / "calibration.yaml"
    text = calibration.read_text()
    assert "depth_factor: 5000.0" in text
    calibration.write_text(text.replace("depth_factor: 5000.0", f"depth_factor: {5000.0 / 1.07:.6f}"))
    first = tmp_path / "first"
    assert run_seesys("track", "--source", f"tum:{source}", "--out", str(first)).returncode == 0
    checked = run_seesys("camera", "check", str(first))
    assert checked.returncode == 0, checked.stderr
    measured = session_scale(first, load_scale_settings(), 0.05)
    assert abs(measured.fit.depth_scale_error - 0.07) < 0.01, describe(measured.fit)
    correction = measured.fit.correction()
    assert f"depth_correction = {correction:.4f}" in checked.stdout
    assert f"depth_factor: {5000.0 / 1.07 * (1 / correction):.2f}" in checked.stdout
    assert "warning: a depth scale error of +" in checked.stdout
    # What finetune prints of its sessions: fine-tuning cannot learn a scale error.
    assert sessions_scale_line([first], load_scale_settings(), 0.05) == (
        f"camera scale against the ground truth: {describe(measured.fit)}; no model can see a depth scale error: "
        "correct it (seesys camera check)"
    )

    # The device applies the correction from camera.toml, records it, and the trajectory is metric again.
    config = write_config_dir(tmp_path / "configs", {"depth_correction": round(correction, 4)})
    again = tmp_path / "again"
    result = run_seesys("track", "--source", f"tum:{source}", "--out", str(again), env={CONFIG_DIR_ENV: str(config)})
    assert result.returncode == 0, result.stderr
    manifest = json.loads((again / "session.json").read_text())
    assert manifest["config"]["camera"]["scale"]["depth_correction"] == round(correction, 4)
    corrected = session_scale(again, load_scale_settings(), 0.05)
    assert corrected.applied_correction == round(correction, 4)
    assert abs(corrected.fit.depth_scale_error) < 0.01, describe(corrected.fit)
    assert corrected.fit.correction(corrected.applied_correction) == pytest.approx(correction, rel=0.01)


def test_a_gap_in_a_trajectory_of_tracked_poses_ends_a_stretch():
    truth = walk(300, 0.01)
    kept = np.r_[0:150, 160:300]  # ten frames lost: the file holds only the tracked poses
    estimate = truth.take(kept)
    fit = window_scales(estimate, np.ones(len(kept), bool), truth, 0.01, SETTINGS, max_gap_s=0.1)
    assert fit.windows == 9  # 150 poses: windows at 0, 15, ..., 60 (5); 140 poses: at 0, 15, 30, 45 (4)
    whole = window_scales(estimate, np.ones(len(kept), bool), truth, 0.01, SETTINGS)
    assert whole.windows == 14  # 290 poses as one stretch: windows at 0, 15, ..., 195
