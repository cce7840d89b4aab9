"""The pose-error label (seesys/core/labels.py): a real ground-truth trajectory (TUM fr1_xyz, re-timed to 30 Hz)
is perturbed by known amounts, and the labels are checked against the known errors and against evo's RPE."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from evo.core import metrics
from scipy.spatial.transform import Rotation

from seesys.core.labels import LabelConfig, LabelError, LabelStatus, LabelSummary, label_frames
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io.core_settings import load_label_config
from seesys.io.session_labels import label_session
from seesys.io.trajectory_files import write_tum
from synth.config import load_synth_config
from synth.trajectories import load_tum

OK = int(TrackingState.OK)
LOST = int(TrackingState.LOST)


@pytest.fixture(scope="module")
def config() -> LabelConfig:
    return load_label_config()


@pytest.fixture(scope="module")
def ground_truth() -> Poses:
    """600 frames (20 s) of the real TUM fr1_xyz ground truth at 30 Hz."""
    synth = load_synth_config()
    real = load_tum(synth.trajectory_path(synth.real_trajectory("tum_fr1_xyz")))
    times = real.times[0] + 1.0 + np.arange(600) / 30.0
    positions, rotations = real.interpolate(times)
    return Poses(times, positions, rotations.as_quat())


def _moved(series: Poses, rotation: Rotation, translation: np.ndarray, scale: float = 1.0) -> Poses:
    """The same trajectory in another world frame (and, for monocular, another scale)."""
    return Poses(
        series.timestamps.copy(),
        scale * rotation.apply(series.positions) + translation,
        (rotation * Rotation.from_quat(series.quaternions_xyzw)).as_quat(),
    )


def _evo_rpe(ground_truth: Poses, estimate: Poses, delta: int, sim3: bool) -> tuple[np.ndarray, np.ndarray]:
    """evo's RPE (translation part, all pairs) after evo's SE(3) or Sim(3) alignment: (end ids, errors)."""
    gt, est = ground_truth.to_evo(), copy.deepcopy(estimate.to_evo())
    est.align(gt, correct_scale=sim3)
    rpe = metrics.RPE(
        metrics.PoseRelation.translation_part, delta=delta, delta_unit=metrics.Unit.frames, all_pairs=True
    )
    rpe.process_data((gt, est))
    return np.asarray(rpe.delta_ids), np.asarray(rpe.error)


WORLD = Rotation.from_euler("zyx", [40, -10, 5], degrees=True)
OFFSET = np.array([2.0, -1.0, 0.5])


def test_a_step_of_known_size_gives_that_error_exactly_on_the_pairs_that_span_it(ground_truth, config):
    """A 7 mm jump of the estimate at frame 300 (in another world frame): every pair spanning the jump is
    off by exactly 7 mm, every other pair by nothing; and the labels equal evo's SE(3)-aligned RPE."""
    step = np.zeros_like(ground_truth.positions)
    step[300:] = [0.004, -0.005, 0.0031]
    size = np.linalg.norm(step[300])
    jumped = Poses(ground_truth.timestamps, ground_truth.positions + step, ground_truth.quaternions_xyzw)
    estimate = _moved(jumped, WORLD, OFFSET)
    labels = label_frames(estimate, np.full(600, OK), ground_truth, monocular=False, config=config)

    delta = config.delta_frames
    assert (labels.status[:delta] == LabelStatus.WARMUP.value).all()
    assert labels.labelled[delta:].all()
    spanning = np.zeros(600, bool)
    spanning[300 : 300 + delta] = True
    np.testing.assert_allclose(labels.error_m[spanning], size, rtol=1e-9)
    np.testing.assert_allclose(labels.error_m[delta:][~spanning[delta:]], 0.0, atol=1e-9)

    ids, errors = _evo_rpe(ground_truth, estimate, delta, sim3=False)
    np.testing.assert_allclose(labels.error_m[ids], errors, rtol=1e-9, atol=1e-12)


def test_random_perturbation_matches_evo_rpe_and_its_known_spread(ground_truth, config):
    """Independent 2 mm (per axis) position noise: labels equal evo's RPE pair by pair, and their RMS is the
    known √2·√3·2 mm (two independent noisy ends of each pair)."""
    rng = np.random.default_rng(3)
    sigma = 0.002
    noisy = Poses(
        ground_truth.timestamps, ground_truth.positions + rng.normal(0, sigma, (600, 3)), ground_truth.quaternions_xyzw
    )
    estimate = _moved(noisy, WORLD, OFFSET)
    labels = label_frames(estimate, np.full(600, OK), ground_truth, monocular=False, config=config)
    ids, errors = _evo_rpe(ground_truth, estimate, config.delta_frames, sim3=False)
    np.testing.assert_allclose(labels.error_m[ids], errors, rtol=1e-9, atol=1e-12)
    rms = np.sqrt(np.nanmean(labels.error_m**2))
    assert rms == pytest.approx(np.sqrt(6) * sigma, rel=0.1)


@pytest.mark.system
def test_monocular_labels_remove_the_unknown_scale(ground_truth, config):
    """A monocular estimate is the truth at scale 0.37 in another frame, plus 1 mm noise: its labels are evo's
    Sim(3)-aligned RPE, and an exact scaled copy gives zero error and the inverse scale."""
    exact = _moved(ground_truth, WORLD, OFFSET, scale=0.37)
    labels = label_frames(exact, np.full(600, OK), ground_truth, monocular=True, config=config)
    assert labels.labelled[config.delta_frames :].all()
    np.testing.assert_allclose(labels.error_m[labels.labelled], 0.0, atol=1e-9)
    np.testing.assert_allclose(labels.scale[labels.labelled], 1 / 0.37, rtol=1e-9)

    rng = np.random.default_rng(4)
    noisy = Poses(
        ground_truth.timestamps, ground_truth.positions + rng.normal(0, 0.001, (600, 3)), ground_truth.quaternions_xyzw
    )
    estimate = _moved(noisy, WORLD, OFFSET, scale=0.37)
    labels = label_frames(estimate, np.full(600, OK), ground_truth, monocular=True, config=config)
    ids, errors = _evo_rpe(ground_truth, estimate, config.delta_frames, sim3=True)
    np.testing.assert_allclose(labels.error_m[ids], errors, rtol=1e-9, atol=1e-12)


def test_monocular_scale_drift_within_a_stretch_is_labelled(ground_truth, config):
    """Scale drifting from 0.5 to 0.8 within a stretch, a loss, then a second stretch (a new map) at another
    scale: each stretch's labels are evo's RPE after evo's Sim(3) alignment of that stretch alone, so the drift
    shows as error while the second stretch's constant scale does not."""
    drift = np.linspace(0.5, 0.8, 600)
    drift[330:] = 0.3
    centre = ground_truth.positions.mean(axis=0)
    drifting = Poses(
        ground_truth.timestamps,
        centre + (ground_truth.positions - centre) * drift[:, None],
        ground_truth.quaternions_xyzw,
    )
    estimate = _moved(drifting, WORLD, OFFSET)
    states = np.full(600, OK)
    states[300:330] = LOST
    labels = label_frames(estimate, states, ground_truth, monocular=True, config=config)
    for part in (slice(0, 300), slice(330, 600)):
        ids, errors = _evo_rpe(ground_truth.take(part), estimate.take(part), config.delta_frames, sim3=True)
        ends = np.arange(600)[part][ids]
        assert labels.labelled[ends].all()
        np.testing.assert_allclose(labels.error_m[ends], errors, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(labels.error_m[340:], 0.0, atol=1e-9)
    assert np.median(labels.error_m[10:300]) > 1e-3  # the drift is error, millimetres per 10 frames
    assert len(np.unique(labels.scale[labels.labelled])) == 2  # one scale per stretch


def test_frames_around_tracking_loss_are_flagged_not_labelled(ground_truth, config):
    states = np.full(600, OK)
    states[200:205] = LOST
    estimate = _moved(ground_truth, WORLD, OFFSET)
    labels = label_frames(estimate, states, ground_truth, monocular=False, config=config)
    delta = config.delta_frames
    assert (labels.status[200:205] == LabelStatus.NOT_TRACKED.value).all()
    assert (labels.status[205 : 205 + delta] == LabelStatus.WARMUP.value).all()
    assert labels.status[205 + delta] == LabelStatus.LABELLED.value
    # No pair reaches across the loss, and unlabelled frames carry no number.
    assert np.isnan(labels.error_m[~labels.labelled]).all()
    assert (labels.status[190:200] == LabelStatus.LABELLED.value).all()


def test_association_tolerance(ground_truth, config):
    """Frames 0.03 s off the ground truth are paired (tolerance 0.05 s); a 0.5 s gap in the ground truth
    leaves its frames without ground truth and restarts the stretch."""
    shifted = Poses(ground_truth.timestamps + 0.03, ground_truth.positions, ground_truth.quaternions_xyzw)
    keep = np.ones(600, bool)
    keep[400:415] = False
    gappy = Poses(ground_truth.timestamps[keep], ground_truth.positions[keep], ground_truth.quaternions_xyzw[keep])
    labels = label_frames(shifted, np.full(600, OK), gappy, monocular=False, config=config)
    # Frame k (at t_k + 0.03) is paired with the truth at t_(k+1), 3 ms away; next to the gap, frame 399 falls
    # back on t_399 (30 ms) and frame 413 reaches t_415 (37 ms); frames 400-412 have nothing within 50 ms.
    assert labels.labelled[config.delta_frames : 400].all()
    assert (labels.status[400:413] == LabelStatus.NO_GROUND_TRUTH.value).all()
    assert (labels.status[413 : 413 + config.delta_frames] == LabelStatus.WARMUP.value).all()
    assert labels.labelled[413 + config.delta_frames :].all()


def test_summary_and_bad_input(ground_truth, config):
    estimate = _moved(ground_truth, WORLD, OFFSET)
    table = label_frames(estimate, np.array(["OK"] * 600), ground_truth, False, config).to_frame()
    summary = LabelSummary.of(table, (0.004, 0.012))
    assert summary.labelled == 600 - config.delta_frames
    assert summary.tracked_fraction == 1.0
    assert summary.fraction_above[0.004] == 0.0
    with pytest.raises(LabelError, match="tracking states"):
        label_frames(estimate, np.full(10, OK), ground_truth, False, config)
    with pytest.raises(LabelError, match="unknown tracking state"):
        label_frames(estimate, np.array(["FINE"] * 600), ground_truth, False, config)


def test_label_session_reads_a_device_session_folder(ground_truth, config, tmp_path):
    """A session folder as the device writes it: every frame in frames.csv, poses only for tracked frames."""
    from seesys.core import session_layout

    estimate = _moved(ground_truth, WORLD, OFFSET)
    states = np.array(["OK"] * 600, object)
    states[:5] = "NOT_INITIALIZED"
    states[300:303] = "RECENTLY_LOST"
    with open(tmp_path / session_layout.FRAMES_CSV, "w") as f:
        f.write(session_layout.FRAMES_HEADER + "\n")
        for i, (t, s) in enumerate(zip(estimate.timestamps, states)):
            f.write(f"{i},{t:.6f},{s},500,10.0\n")

    tracked = [i for i in range(600) if states[i] == "OK" and i != 450]  # frame 450: OK but no valid pose
    write_tum(tmp_path / session_layout.TRAJECTORY, estimate.take(np.array(tracked)))
    write_tum(tmp_path / session_layout.GROUND_TRUTH, ground_truth)
    labels = label_session(tmp_path, monocular=False, config=config)
    assert (labels.status[:5] == LabelStatus.NOT_TRACKED.value).all()
    assert labels.status[450] == LabelStatus.NOT_TRACKED.value
    assert labels.labelled[15:300].all() and labels.labelled[313:450].all()
    np.testing.assert_allclose(labels.error_m[labels.labelled], 0.0, atol=1e-6)

    write_tum(tmp_path / session_layout.TRAJECTORY, estimate.take(np.zeros(0, int)))
    assert not label_session(tmp_path, monocular=False, config=config).labelled.any()
