"""Study metrics: the tracking error equals evo's RPE with the same parameters on real trajectories (TUM RGB-D
ground truth and SLAM estimates recorded by others), and completeness and losses count what they say."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum
from study.config import load_study_config
from study.metrics import completeness_from_frames, completeness_from_poses, tracking_metrics

DATA = Path(__file__).parent / "data" / "trajectories"
REPO = Path(__file__).resolve().parent.parent
PAIRS = [("freiburg1_xyz-rgbdslam.txt", "freiburg1_xyz-groundtruth.txt", False),
         ("fr2_desk_ORB.txt", "fr2_desk_groundtruth.txt", True)]


def evo_rpe_errors(estimate: Path, reference: Path, monocular: bool, delta: int, max_dt: float,
                   all_pairs: bool) -> np.ndarray:
    """evo alone, from its own TUM reader on: the reference result."""
    from evo.core import sync
    from evo.core.metrics import PoseRelation
    from evo.core.units import Unit
    from evo.main_rpe import rpe
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(reference))
    est = file_interface.read_tum_trajectory_file(str(estimate))
    ref, est = sync.associate_trajectories(ref, est, max_diff=max_dt)
    result = rpe(ref, est, PoseRelation.translation_part, delta=delta, delta_unit=Unit.frames, all_pairs=all_pairs,
                 align=True, correct_scale=monocular)
    return result.np_arrays["error_array"]


@pytest.mark.parametrize("estimate,reference,monocular", PAIRS)
@pytest.mark.parametrize("all_pairs", [True, False])
def test_tracking_error_equals_evo_rpe(estimate, reference, monocular, all_pairs):
    cfg = load_study_config().metrics
    cfg = type(cfg)(**{**cfg.__dict__, "all_pairs": all_pairs})
    ours = tracking_metrics(read_tum(DATA / estimate), read_tum(DATA / reference), monocular, cfg)
    evo = evo_rpe_errors(DATA / estimate, DATA / reference, monocular, cfg.delta_frames, cfg.association_max_dt_s,
                         all_pairs)
    assert ours.pairs == len(evo) > 50
    assert ours.rpe_mean_m == pytest.approx(float(np.mean(evo)), rel=1e-9)
    assert ours.rpe_rmse_m == pytest.approx(float(np.sqrt(np.mean(evo ** 2))), rel=1e-9)
    assert ours.alignment == ("Sim(3)" if monocular else "SE(3)")


def test_metrics_command_json_keys_and_values():
    estimate, reference, _ = PAIRS[0]
    out = subprocess.run([sys.executable, "-m", "seesys", "study", "metrics", "--slam", str(DATA / estimate),
                          "--mocap", str(DATA / reference), "--json"], capture_output=True, text=True, cwd=REPO,
                         env=os.environ, timeout=120, check=True).stdout
    data = json.loads(out)
    evo = evo_rpe_errors(DATA / estimate, DATA / reference, False, 10, data["association_max_dt_s"], True)
    assert data["pairs"] == len(evo)
    assert data["rpe_mean_m"] == pytest.approx(float(np.mean(evo)), rel=1e-9)
    assert data["rpe_rmse_m"] == pytest.approx(float(np.sqrt(np.mean(evo ** 2))), rel=1e-9)
    assert 0.9 < data["completeness"] <= 1.0


def test_no_overlap_gives_no_pairs_and_nan_error():
    cfg = load_study_config().metrics
    poses = read_tum(DATA / PAIRS[0][0])
    later = Poses(poses.timestamps + 1000.0, poses.positions, poses.quaternions_xyzw)
    result = tracking_metrics(poses, later, False, cfg)
    assert result.pairs == 0 and np.isnan(result.rpe_mean_m)


def test_completeness_from_frame_log_counts_after_initialisation():
    states = ["NOT_INITIALIZED"] * 5 + ["OK"] * 10 + ["RECENTLY_LOST"] * 3 + ["LOST"] * 2 + ["OK"] * 5
    frames = pd.DataFrame({"timestamp": np.arange(len(states)) / 10.0, "state": states})
    result = completeness_from_frames(frames)
    assert result.fraction == pytest.approx(15 / 20)
    assert result.losses == 1
    assert result.loss_duration_s == pytest.approx(0.5)
    ending_lost = pd.concat([frames, pd.DataFrame({"timestamp": [2.5, 2.6, 2.7], "state": ["LOST"] * 3})])
    result = completeness_from_frames(ending_lost)
    assert result.losses == 2 and result.loss_duration_s == pytest.approx(0.5 + 0.2)


def test_completeness_from_poses_finds_gaps():
    cfg = load_study_config().metrics
    times = np.concatenate([np.arange(0, 100), np.arange(130, 200)]) / 30.0
    estimate = Poses(times, np.zeros((len(times), 3)), np.tile([0, 0, 0, 1.0], (len(times), 1)))
    result = completeness_from_poses(estimate, estimate, cfg)
    assert result.losses == 1
    assert result.loss_duration_s == pytest.approx(30 / 30.0)
    assert result.fraction == pytest.approx(170 / 200)
