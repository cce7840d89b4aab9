"""One pose error for a session: the label (seesys/core/labels.py), the study's tracking error (study/metrics.py)
and the advice analysis's true error (study/advice.py) are the same per-pair numbers, monocular (a scale drifting
from 0.5 to 0.8 within a stretch) and RGB-D, each equal to evo's RPE computed by hand on every tracked stretch."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from seesys.core import session_layout
from seesys.core.trajectory import Poses
from seesys.io.core_settings import load_label_config
from seesys.io.session_labels import label_session
from seesys.io.trajectory_files import read_tum, write_tum
from study.advice import advice_outcome
from study.config import load_study_config
from study.sessions import advice_thresholds, participant_advice, participant_metrics

TRUTH = Path(__file__).parent / "data" / "trajectories" / "freiburg1_xyz-groundtruth.txt"
FRAMES = 600  # 20 s at 30 Hz
LOST = slice(300, 330)  # a loss through LOST: the second stretch is a new map, at another scale and origin
WORLDS = [
    Rotation.from_euler("zyx", [40, -10, 5], degrees=True),
    Rotation.from_euler("zyx", [-70, 20, 3], degrees=True),
]
OFFSETS = [np.array([2.0, -1.0, 0.5]), np.array([-3.0, 0.5, 1.0])]


def _session(folder: Path, monocular: bool) -> None:
    """A device session folder of one attempt (frames.csv, trajectory.tum, groundtruth.tum, session.json,
    run.json, advisory.csv) over the real TUM fr1_xyz motion-capture trajectory (100 Hz): the estimate is the
    truth with 1 mm of noise, in each map's own frame and, monocular, a scale drifting from 0.5 to 0.8 over the
    first stretch and 0.3 in the second."""
    truth = read_tum(TRUTH)
    # Every third motion-capture pose (about 30 Hz): each frame has its reference pose within both the label's and
    # the study's association tolerance (where one has and the other has not, docs/labels.md says what differs).
    nearest = 50 + 3 * np.arange(FRAMES)
    times = truth.timestamps[nearest]
    rng = np.random.default_rng(7)
    scale = (
        np.where(np.arange(FRAMES) < LOST.start, np.linspace(0.5, 0.8, FRAMES), 0.3) if monocular else np.ones(FRAMES)
    )
    second = np.arange(FRAMES) >= LOST.stop
    centre = truth.positions.mean(axis=0)
    positions = np.empty((FRAMES, 3))
    quaternions = np.empty((FRAMES, 4))
    for in_map, world, offset in zip((~second, second), WORLDS, OFFSETS):
        noisy = truth.positions[nearest[in_map]] + rng.normal(0, 0.001, (in_map.sum(), 3))
        positions[in_map] = world.apply((noisy - centre) * scale[in_map, None]) + offset
        quaternions[in_map] = (world * truth.rotations[nearest[in_map]]).as_quat()
    estimate = Poses(times, positions, quaternions)
    states = np.full(FRAMES, "OK", dtype=object)
    states[LOST] = "LOST"
    folder.mkdir(parents=True)
    with open(folder / session_layout.FRAMES_CSV, "w") as f:
        f.write(session_layout.FRAMES_HEADER + "\n")
        f.writelines(f"{i},{t:.6f},{s},500,10.0\n" for i, (t, s) in enumerate(zip(times, states)))
    write_tum(folder / session_layout.TRAJECTORY, estimate.take(states == "OK"))
    write_tum(folder / session_layout.GROUND_TRUTH, truth)
    (folder / "session.json").write_text(json.dumps({"mode": "mono" if monocular else "rgbd"}))
    (folder / "run.json").write_text(json.dumps({"status": "completed"}))
    # Advisory buffers every 1/3 s on the camera's clock (no estimate log: one clock), warning at random.
    pd.DataFrame(
        {
            "wall_time": times[0] + np.arange(0, times[-1] - times[0], 1 / 3),
            "played_pulses": rng.integers(0, 2, int(np.ceil((times[-1] - times[0]) * 3))),
        }
    ).to_csv(folder / "advisory.csv", index=False)


def _evo_by_hand(folder: Path, stretch: slice, monocular: bool, delta: int, max_dt: float) -> np.ndarray:
    """evo alone on one stretch of the session's files, from its own TUM reader on, as `evo_rpe tum REF EST
    --delta 10 --delta_unit f --pose_relation trans_part --align [--correct_scale] --all_pairs` on that stretch's
    poses: its association, alignment and RPE."""
    from evo.core import sync
    from evo.core.metrics import PoseRelation
    from evo.core.units import Unit
    from evo.main_rpe import rpe
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(folder / session_layout.GROUND_TRUTH))
    est = file_interface.read_tum_trajectory_file(str(folder / session_layout.TRAJECTORY))
    frames = pd.read_csv(folder / session_layout.FRAMES_CSV).timestamp.to_numpy()[stretch]
    est.reduce_to_ids(np.flatnonzero((est.timestamps >= frames[0]) & (est.timestamps <= frames[-1])))
    ref, est = sync.associate_trajectories(ref, est, max_diff=max_dt)
    return rpe(
        ref,
        est,
        PoseRelation.translation_part,
        delta=delta,
        delta_unit=Unit.frames,
        all_pairs=True,
        align=True,
        correct_scale=monocular,
    ).np_arrays["error_array"]


@pytest.mark.parametrize("monocular", [True, False])
def test_the_label_the_study_metrics_and_the_advice_analysis_use_one_error(tmp_path, monocular):
    folder = tmp_path / "attempt-1"
    _session(folder, monocular)
    label_cfg, cfg = load_label_config(), load_study_config().metrics
    assert label_cfg.delta_frames == cfg.delta_frames

    labels = label_session(folder, monocular, label_cfg)
    labelled = labels.labelled
    assert labelled.sum() == FRAMES - len(range(*LOST.indices(FRAMES))) - 2 * label_cfg.delta_frames

    # evo by hand on each tracked stretch.
    by_hand = np.concatenate(
        [
            _evo_by_hand(folder, part, monocular, cfg.delta_frames, cfg.association_max_dt_s)
            for part in (slice(0, LOST.start), slice(LOST.stop, FRAMES))
        ]
    )
    np.testing.assert_allclose(labels.error_m[labelled], by_hand, rtol=1e-9, atol=1e-12)

    # The study's tracking error: the same pairs, at the same end frames.
    metrics, attempts = participant_metrics([folder], cfg)
    assert attempts[0].monocular is monocular and metrics.stretches == 2
    np.testing.assert_allclose(attempts[0].rpe.timestamps, labels.timestamps[labelled], atol=1e-6)
    np.testing.assert_allclose(attempts[0].rpe.errors_m, labels.error_m[labelled], rtol=1e-9, atol=1e-12)
    assert metrics.rpe_mean_m == pytest.approx(float(np.mean(labels.error_m[labelled])), rel=1e-9)

    # The advice analysis judges the advisory against the labels: the same false alarms and misses.
    thresholds = advice_thresholds()
    advisory = pd.read_csv(folder / "advisory.csv")
    from_labels = advice_outcome(
        advisory,
        labels.timestamps[labelled],
        labels.error_m[labelled],
        0.0,
        thresholds.window_s,
        thresholds.alpha_m,
        cfg.advice_high_error_m,
    )
    judged = participant_advice(attempts, cfg, thresholds)
    assert judged["false_alarm_rate"] == from_labels.false_alarm_rate
    assert judged["miss_rate"] == (from_labels.miss_rate if monocular else pytest.approx(np.nan, nan_ok=True))
    if monocular:
        # The drift within the first stretch is error: large enough for misses to be counted, and the first
        # stretch's pairs (drifting scale) far above the second's (constant scale, noise only).
        assert from_labels.high > 0 and from_labels.low > 0
        first = labels.error_m[: LOST.start][labelled[: LOST.start]]
        second = labels.error_m[LOST.stop :][labelled[LOST.stop :]]
        assert np.median(first) > 2 * np.median(second)
