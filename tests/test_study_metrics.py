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
PAIRS = [
    ("freiburg1_xyz-rgbdslam.txt", "freiburg1_xyz-groundtruth.txt", False),
    ("fr2_desk_ORB.txt", "fr2_desk_groundtruth.txt", True),
]


def evo_rpe_errors(
    estimate: Path, reference: Path, monocular: bool, delta: int, max_dt: float, all_pairs: bool
) -> np.ndarray:
    """evo alone, from its own TUM reader on: the reference result."""
    from evo.core import sync
    from evo.core.metrics import PoseRelation
    from evo.core.units import Unit
    from evo.main_rpe import rpe
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(reference))
    est = file_interface.read_tum_trajectory_file(str(estimate))
    ref, est = sync.associate_trajectories(ref, est, max_diff=max_dt)
    result = rpe(
        ref,
        est,
        PoseRelation.translation_part,
        delta=delta,
        delta_unit=Unit.frames,
        all_pairs=all_pairs,
        align=True,
        correct_scale=monocular,
    )
    return result.np_arrays["error_array"]


@pytest.mark.parametrize("estimate,reference,monocular", PAIRS)
@pytest.mark.parametrize("all_pairs", [True, False])
def test_tracking_error_equals_evo_rpe(estimate, reference, monocular, all_pairs):
    cfg = load_study_config().metrics
    cfg = type(cfg)(**{**cfg.__dict__, "all_pairs": all_pairs})
    ours = tracking_metrics(read_tum(DATA / estimate), read_tum(DATA / reference), monocular, cfg)
    evo = evo_rpe_errors(
        DATA / estimate, DATA / reference, monocular, cfg.delta_frames, cfg.association_max_dt_s, all_pairs
    )
    assert ours.pairs == len(evo) > 50
    assert ours.rpe_mean_m == pytest.approx(float(np.mean(evo)), rel=1e-9)
    assert ours.rpe_rmse_m == pytest.approx(float(np.sqrt(np.mean(evo**2))), rel=1e-9)
    assert ours.alignment == ("Sim(3)" if monocular else "SE(3)")


@pytest.mark.system
def test_metrics_command_json_keys_and_values():
    estimate, reference, _ = PAIRS[0]
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "study",
            "metrics",
            "--slam",
            str(DATA / estimate),
            "--mocap",
            str(DATA / reference),
            "--json",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=os.environ,
        timeout=120,
        check=True,
    ).stdout
    data = json.loads(out)
    evo = evo_rpe_errors(DATA / estimate, DATA / reference, False, 10, data["association_max_dt_s"], True)
    assert data["pairs"] == len(evo)
    assert data["rpe_mean_m"] == pytest.approx(float(np.mean(evo)), rel=1e-9)
    assert data["rpe_rmse_m"] == pytest.approx(float(np.sqrt(np.mean(evo**2))), rel=1e-9)
    assert 0.9 < data["completeness"] <= 1.0
    # TUM's fr1/xyz (a Kinect v1 whose depth TUM calibrated) through RGB-D SLAM: metric within 2 %
    scale = data["camera_scale"]
    assert scale["windows"] > 20 and abs(scale["depth_scale_error"]) < 0.02, scale


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


def _loss_and_new_map(rng: np.random.Generator) -> tuple[Poses, Poses, pd.DataFrame, list[slice]]:
    """20 s at 30 Hz: tracked 0–8 s in the first map, lost for 3 s (LOST: ORB-SLAM3 starts a new map), tracked again
    11–20 s in a second map whose origin is elsewhere; 1 mm of noise on the estimate."""
    from scipy.spatial.transform import Rotation

    t = np.arange(600) / 30.0
    truth = np.column_stack([np.cos(t / 3), np.sin(t / 3), 0.1 * t])
    turning = Rotation.from_rotvec(np.column_stack([0.1 * np.sin(t), t / 5, np.zeros_like(t)]))
    reference = Poses.from_rotations(t, truth, turning)
    stretches = [slice(0, 240), slice(330, 600)]
    maps = [Rotation.from_rotvec([0.0, 0.0, 0.3]), Rotation.from_rotvec([0.2, -0.5, 1.0])]
    offsets = [np.array([0.5, -0.2, 0.0]), np.array([-3.0, 2.0, 1.0])]
    times, positions, rotations = [], [], []
    for part, world, offset in zip(stretches, maps, offsets):
        times.append(t[part])
        positions.append(world.apply(truth[part]) + offset + rng.normal(0, 0.001, (len(t[part]), 3)))
        rotations.append((world * turning[part]).as_quat())
    estimate = Poses(np.concatenate(times), np.concatenate(positions), np.concatenate(rotations))
    states = np.full(600, "OK", dtype=object)
    states[240:330] = "LOST"
    frames = pd.DataFrame({"timestamp": t, "state": states})
    return estimate, reference, frames, stretches


def _evo_stretch_errors(estimate: Poses, reference: Poses, cfg) -> np.ndarray:
    """evo alone on one stretch: evo's own trajectory type, association, alignment and RPE."""
    from evo.core import sync
    from evo.core.metrics import PoseRelation
    from evo.core.trajectory import PoseTrajectory3D
    from evo.core.units import Unit
    from evo.main_rpe import rpe

    def evo(p: Poses) -> PoseTrajectory3D:
        return PoseTrajectory3D(
            positions_xyz=p.positions,
            orientations_quat_wxyz=p.quaternions_xyzw[:, [3, 0, 1, 2]],
            timestamps=p.timestamps,
        )

    ref, est = sync.associate_trajectories(evo(reference), evo(estimate), max_diff=cfg.association_max_dt_s)
    return rpe(
        ref,
        est,
        PoseRelation.translation_part,
        delta=cfg.delta_frames,
        delta_unit=Unit.frames,
        all_pairs=cfg.all_pairs,
        align=True,
        correct_scale=False,
    ).np_arrays["error_array"]


@pytest.mark.parametrize("with_frame_log", [True, False])
@pytest.mark.system
def test_a_loss_and_a_new_map_give_the_per_stretch_evo_rpe(with_frame_log):
    cfg = load_study_config().metrics
    estimate, reference, frames, stretches = _loss_and_new_map(np.random.default_rng(3))
    result = tracking_metrics(estimate, reference, False, cfg, frames if with_frame_log else None)

    first = len(range(*stretches[0].indices(600)))
    parts = [estimate.take(slice(0, first)), estimate.take(slice(first, len(estimate)))]
    expected = np.concatenate([_evo_stretch_errors(p, reference, cfg) for p in parts])
    assert result.pairs == len(expected)
    assert result.rpe_mean_m == pytest.approx(float(expected.mean()), rel=1e-9)
    assert result.rpe_rmse_m == pytest.approx(float(np.sqrt(np.mean(expected**2))), rel=1e-9)
    assert result.stretches == 2
    # 1 mm of noise per pose: the error is that of each map, not of the reset between them.
    assert result.rpe_max_m < 0.01
    whole = _evo_stretch_errors(estimate, reference, cfg)  # one alignment over both maps, pairs across the loss
    assert whole.max() > 1.0
    assert result.tracking_losses == 1
    assert result.map_resets == (1 if with_frame_log else None)


def test_a_loss_relocalised_in_the_same_map_is_no_reset():
    estimate, reference, frames, _ = _loss_and_new_map(np.random.default_rng(4))
    frames.loc[frames.state == "LOST", "state"] = "RECENTLY_LOST"
    result = completeness_from_frames(frames)
    assert (result.losses, result.map_resets) == (1, 0)


def _line(times: np.ndarray, speed_m_s: float, yaw_rate: float) -> Poses:
    from scipy.spatial.transform import Rotation

    positions = np.column_stack([speed_m_s * times, np.zeros_like(times), np.zeros_like(times)])
    return Poses(times, positions, Rotation.from_euler("z", (yaw_rate * times)[:, None]).as_quat())


def test_the_error_per_metre_and_per_radian_divide_the_pairs_errors_by_the_motion_over_them():
    """The same estimate noise on a slow and a fast walk: the 10-frame error is the same, the error per metre half
    as large on the walk twice as fast; the motion is the reference's, over the very pairs of the error."""
    cfg = load_study_config().metrics
    times = np.arange(300) / 30.0
    rng = np.random.default_rng(7)
    noise = rng.normal(0, 0.002, (len(times), 3))
    per_metre = []
    for speed in (0.3, 0.6):
        reference = _line(times, speed, 0.5)
        estimate = Poses(times, reference.positions + noise, reference.quaternions_xyzw)
        m = tracking_metrics(estimate, reference, False, cfg)
        moved = speed * cfg.delta_frames / 30.0  # metres over each pair
        turned = 0.5 * cfg.delta_frames / 30.0
        assert m.error_per_metre == pytest.approx(m.rpe_mean_m / moved, rel=1e-6)
        assert m.error_per_radian == pytest.approx(m.rpe_mean_m / turned, rel=1e-6)
        per_metre.append(m.error_per_metre)
    assert per_metre[1] == pytest.approx(per_metre[0] / 2, rel=1e-6)
    still = tracking_metrics(Poses(times, noise, _line(times, 0, 0).quaternions_xyzw), _line(times, 0, 0), False, cfg)
    assert np.isnan(still.error_per_metre) and still.rpe_mean_m > 0  # no motion: no error per metre
