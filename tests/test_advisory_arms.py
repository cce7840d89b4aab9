"""The conditions that tell information from pacing: the motion statistic and its rule, the shared advice step on
any clock, the yoked replay, the oracle's true error, the yoked partner, and the motion calibration's quantiles."""

import dataclasses
import math

import numpy as np
import pytest

from advisory.advice import REPLAY_ENDED, Advice, RecordedBuffer, ReplayedAdvice
from advisory.conditions import (
    LIVE_CONDITIONS,
    Condition,
    condition_input,
    pulse_rule,
    rule_name,
    threshold_pulses,
)
from advisory.config import load_advisory_config
from advisory.motion import MotionStatistic
from advisory.scheduler import CUE, LIVE, TICK, Reading
from seesys.core import rts_schema
from seesys.core.errors import ConfigError, SeesysError
from seesys.core.labels import stretch_errors
from seesys.core.messages import FeatureFrame
from seesys.core.motion import translation_spread
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io.config import write_config_dir
from seesys.io.network import load_network_config
from seesys_app.simulate.oracle import TrueError
from seesys_app.simulate.yoking import partner_of
from study.config import load_study_config
from study.motion_calibration import _quantile_thresholds
from study.protocol import make_protocol

CFG = load_advisory_config()
PERIOD = CFG.timing.cadence_s
FPS = 30.0


def moving_frame(index: int, velocity_m_s, state=TrackingState.OK, dt: float = 1 / FPS) -> FeatureFrame:
    rts = np.zeros(rts_schema.NUM_CHANNELS, dtype=np.float32)
    for name, v in zip(rts_schema.TRANSLATION_CHANNELS, velocity_m_s):
        rts[rts_schema.index_of(name)] = v * dt
    return FeatureFrame("dev", index, index * dt, state, rts)


def test_a_steady_walk_has_no_spread_and_a_shaking_hand_the_spread_of_its_velocities():
    steady, shaking = MotionStatistic(CFG.motion), MotionStatistic(CFG.motion)
    for k in range(60):
        calm = steady.update(moving_frame(k, (0.5, 0.0, 0.0)))
        wobble = shaking.update(moving_frame(k, (0.5 + (0.2 if k % 2 else -0.2), 0.0, 0.0)))
    assert calm == pytest.approx(0.0, abs=1e-4)  # float32 RTS rows
    assert wobble == pytest.approx(0.2, rel=1e-3)  # ±0.2 m/s about the mean
    assert translation_spread(np.array([[1.0, 0, 0], [-1.0, 0, 0]])) == pytest.approx(1.0)


def test_the_motion_statistic_skips_untracked_frames_and_starts_afresh_after_a_gap():
    s = MotionStatistic(CFG.motion)
    values = [s.update(moving_frame(k, (0.1 * k, 0, 0))) for k in range(5)]
    assert values[:3] == [None, None, None] and values[3] is not None  # a first frame, then three velocities
    assert s.update(moving_frame(5, (0.1, 0, 0), TrackingState.LOST)) is None
    assert s.update(moving_frame(6, (0.1, 0, 0))) is not None  # its displacement spans the untracked frame
    late = dataclasses.replace(moving_frame(7, (0.1, 0, 0)), timestamp=100.0)
    assert s.update(late) is None
    after = [
        s.update(dataclasses.replace(moving_frame(8 + k, (0.1, 0, 0)), timestamp=100.0 + (k + 1) / FPS))
        for k in range(3)
    ]
    assert after[:2] == [None, None] and after[2] is not None  # the window starts afresh after the gap


def test_the_motion_rule_counts_the_thresholds_reached_and_caps_at_equation_2s_maximum():
    rule = pulse_rule(Condition.MOTION, CFG)
    t = CFG.motion.thresholds_m_s
    assert rule(0.0) == 0 and rule(math.nextafter(t[0], 0)) == 0 and rule(t[0]) == 1 and rule(t[-1]) == len(t)
    assert threshold_pulses(10.0, [0.1, 0.2, 0.3, 0.4, 0.5], 3) == 3
    with pytest.raises(ConfigError, match="strictly ascending"):
        load_advisory_config(write_config_dir_for({"thresholds_m_s": [0.2, 0.1]}))


def write_config_dir_for(overrides):
    import tempfile
    from pathlib import Path

    return write_config_dir(Path(tempfile.mkdtemp()) / "configs", overrides)


def test_only_the_live_conditions_run_live_and_the_others_say_why():
    assert set(LIVE_CONDITIONS) == {"seesys", "rotation", "none", "motion"}
    network = load_network_config()
    for condition in (Condition.YOKED, Condition.ORACLE):
        with pytest.raises(SeesysError, match="runs only in a simulated study"):
            condition_input(condition, CFG, network)
    motion = condition_input(Condition.MOTION, CFG, network)
    assert motion.endpoint == network.features_endpoint and rule_name(Condition.MOTION) == "motion"
    with pytest.raises(SeesysError, match="no pulse rule"):
        pulse_rule(Condition.YOKED, CFG)


def test_the_advice_step_ticks_at_its_own_times_and_a_change_comes_at_once():
    advice = Advice(Condition.SEESYS, CFG, 0.0, 0.1)
    first = advice.until(0.0)
    assert [b.decision.time for b in first] == [0.0] and first[0].play_at == pytest.approx(0.1)
    change = advice.take(0.5, Reading(0.013))  # the tick at 1/3 s is due before this reading
    assert [b.decision.trigger for b in change] == [TICK, "change"]
    assert change[0].decision.time == pytest.approx(PERIOD) and change[1].played == 3
    assert [b.buffer_id for b in first + change] == [0, 1, 2]
    row = change[1].row(12.0, Condition.SEESYS)
    assert row[0] == 12.0 and row[2] == "seesys" and row[7] == 3 and row[-1] == "estimate"


def test_a_silent_condition_decides_as_seesys_but_plays_nothing_and_the_cue_is_no_warning():
    silent = Advice(Condition.NONE, CFG, 0.0, 0.0)
    buffers = silent.take(0.1, Reading(0.013))
    assert buffers[-1].decision.n_pulses == 3 and buffers[-1].played == 0
    waiting = Advice(Condition.SEESYS, CFG, 0.0, 0.0)
    late = [b for b in waiting.until(3.0) if b.trigger == CUE]
    assert late and all(b.heard_pulses == 0 for b in late)


def test_a_yoked_advice_replays_the_recorded_pulses_at_the_same_offsets_whatever_it_is_told():
    recording = [RecordedBuffer(0.0, 0, 0, TICK), RecordedBuffer(0.2, 2, 2, "change"), RecordedBuffer(0.5, 1, 1, TICK)]
    yoked = ReplayedAdvice(recording, CFG, 100.0, 0.1)
    played = yoked.take(100.25, Reading(1.0)) + yoked.until(100.6)
    assert [(b.decision.time - 100.0, b.played, b.trigger) for b in played] == [
        (0.0, 0, TICK),
        (pytest.approx(0.2), 2, "change"),
        (pytest.approx(0.5), 1, TICK),
    ]
    after = yoked.until(100.5 + 2 * PERIOD)
    assert [b.decision.status for b in after] == [REPLAY_ENDED, REPLAY_ENDED]
    assert all(b.played == 0 for b in after) and played[1].decision.status == LIVE
    assert played[1].row(0.0, Condition.YOKED)[2] == "yoked"


def _pose(position, yaw: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    pose[:3, 3] = position
    return pose


def test_the_oracle_reads_the_labels_error_of_the_pair_ending_at_each_frame():
    from scipy.spatial.transform import Rotation

    delta = 10
    oracle = TrueError(monocular=False, delta_frames=delta)
    rng = np.random.default_rng(3)
    times, truth, estimate, errors = [], [], [], []
    for k in range(40):
        t = k / FPS
        true_position = np.array([0.02 * k, 0.0, 0.0])
        drift = rng.normal(0, 0.003, 3)
        pose = _pose(true_position + drift + np.array([5.0, 0, 0]), 0.01 * k)  # another origin: RGB-D ignores it
        true_quat = Rotation.from_euler("z", 0.01 * k).as_quat()
        times.append(t)
        truth.append(np.concatenate([true_position, true_quat]))
        estimate.append(np.concatenate([pose[:3, 3], true_quat]))
        errors.append(oracle.update(t, pose, truth[-1]))
    assert errors[:delta] == [None] * delta
    est, ref = np.array(estimate), np.array(truth)
    expected = stretch_errors(
        Poses(np.array(times), est[:, :3], est[:, 3:]), Poses(np.array(times), ref[:, :3], ref[:, 3:]), False, delta
    ).errors_m
    np.testing.assert_allclose(errors[delta:], expected, rtol=1e-9)
    assert oracle.update(2.0, None, ref[-1]) is None and oracle.update(2.1, _pose([0, 0, 0], 0), ref[-1]) is None


def test_every_participant_is_yoked_to_another_and_one_alone_cannot_be():
    cfg = load_study_config().protocol
    protocol = make_protocol(cfg, 3, "within", conditions=["seesys", "yoked"], known=("seesys", "yoked"))
    ids = [p.id for p in protocol.participants]
    partners = [partner_of(protocol, i) for i in ids]
    assert sorted(partners) == sorted(ids) and all(a != b for a, b in zip(ids, partners))
    alone = make_protocol(cfg, 1, "within", conditions=["seesys", "yoked"], known=("seesys", "yoked"))
    with pytest.raises(SeesysError, match="at least two participants"):
        partner_of(alone, alone.participants[0].id)


def test_the_calibrations_quantiles_give_the_wanted_shares_and_stay_ascending():
    values = np.linspace(0.0, 1.0, 1001)
    thresholds = _quantile_thresholds(values, [0.5, 0.1, 0.0])
    assert np.mean(values >= thresholds[0]) == pytest.approx(0.5, abs=0.002)
    assert np.mean(values >= thresholds[1]) == pytest.approx(0.1, abs=0.002)
    assert len(thresholds) == 2  # three pulses never came: the rule never plays them
    same = _quantile_thresholds(np.zeros(10), [1.0, 1.0, 1.0])
    assert same[0] > 0 and same[0] < same[1] < same[2]
    with pytest.raises(SeesysError, match="never warned"):
        _quantile_thresholds(values, [0.0, 0.0, 0.0])


def test_the_shipped_motion_thresholds_are_the_pilots_and_warn_as_often_as_seesys_did_there():
    """The committed calibration record: the thresholds in advisory.toml are the ones it set, and on the pilot they
    were set from, the motion rule warns within 10 % as often as SEESys did."""
    import json

    from testkit.sample import REPO

    record = json.loads((REPO / "docs/simulated-study/pilot-forest/motion-calibration.json").read_text())
    assert CFG.motion.thresholds_m_s == record["thresholds_m_s"]
    # The pilot ran the served model: the motion arm pulses as often as SEESys does with the model it serves.
    from estimator.service.config import load_service_config
    from estimator.service.model import model_version
    from seesys.io.resources import resolve

    served = load_service_config().model
    assert record["pilot_record"]["model_version"] == model_version(resolve(served))
    assert abs(record["motion_warning_share"] / record["seesys_warning_share"] - 1) <= 0.10
    assert record["pilot_record"]["settings"]["study"]["operator_seed"] != 1  # not the study's operators
    assert len(record["sessions"]) >= 5


def test_a_simulated_study_with_a_yoked_arm_and_no_seesys_arm_is_refused(tmp_path):
    from seesys_app.simulate.config import load_simulate_config
    from seesys_app.simulate.study import prepare_study

    cfg = load_simulate_config()
    cfg = dataclasses.replace(cfg, study=dataclasses.replace(cfg.study, conditions=["none", "yoked"]))
    with pytest.raises(SeesysError, match="replays the seesys sessions"):
        prepare_study(tmp_path / "study", cfg, tmp_path / "model.onnx")
    assert not (tmp_path / "study").exists()
