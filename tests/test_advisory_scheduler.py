"""The generator's logic with a simulated clock: moving average, 3 Hz cadence, prompt changes, stale input; the
rotation speed; the offline renderer; the hand-off codec; the estimate-log reader."""

import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from testkit.audio import PUBLISH_HZ, cue_tones, pulse_onsets, pulses_per_buffer, rotation_frame, run_lengths

from advisory.conditions import Condition, pulse_rule
from advisory.config import load_advisory_config
from advisory.estimate_log import read_estimate_log
from advisory.handoff import AudioBuffer, HandoffError, decode_buffer, encode_buffer
from advisory.render import render_estimates
from advisory.rotation import RotationSpeed
from advisory.scheduler import CHANGE, LIVE, NO_INFORMATION, TICK, WAITING, PulseScheduler
from advisory.synth import synthesise, synthesise_cue
from advisory.wav import read_wav
from seesys.core.errors import SeesysError
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState

CFG = load_advisory_config()
PERIOD = CFG.timing.cadence_s


def scheduler(start=0.0):
    t = CFG.timing
    return PulseScheduler(pulse_rule(Condition.SEESYS, CFG), t.window_s, t.cadence_s, t.stale_after_s, start)


def test_ticks_every_third_of_a_second_on_schedule_even_when_woken_late():
    s = scheduler()
    times = []
    for _k in range(6):
        d = s.tick(s.next_tick + 0.004)  # the caller wakes 4 ms late
        times.append(d.time)
        waiting = WAITING if d.time <= CFG.timing.stale_after_s else NO_INFORMATION  # no input since the start
        assert d.trigger == TICK and d.status == waiting and d.n_pulses == 0 and math.isnan(d.value)
    assert np.allclose(np.diff(times), PERIOD)


def test_moving_average_over_the_window_decides_n_at_the_tick():
    # 0.002 for a while, then 0.006, then nothing until the tick. The window (t − 0.33, t] has by then lost the
    # oldest 0.002 samples, and the mean crosses α exactly when half the window holds 0.006: at a tick whose window
    # starts exactly on a sample's arrival (that sample is out) the mean is α = 0.004 → N = 1; a microsecond
    # earlier that sample is in and the mean is 0.034 / 9 ≈ 0.0038 → N = 0. No sample changes N on arrival (the
    # newest mean is 0.0036), so only the tick decides.
    tick_at = 1.0
    window_start = tick_at - CFG.timing.window_s  # the boundary, computed as the scheduler computes it
    arrivals = window_start + (np.arange(10) - 1) / 30  # the second 0.002 sample arrives exactly on the boundary
    values = [0.002] * 6 + [0.006] * 4
    for at, (n, mean) in ((tick_at - 1e-6, (0, 0.034 / 9)), (tick_at, (1, 0.004))):
        s = scheduler(start=at)
        for arrival, value in zip(arrivals, values):
            assert s.add(float(arrival), value) is None
        d = s.tick(at)
        assert (d.time, d.trigger, d.status) == (at, TICK, LIVE)
        assert d.value == pytest.approx(mean, abs=1e-12) and d.n_pulses == n, (at, d)


def test_a_change_of_n_is_emitted_at_once_and_restarts_the_cadence():
    s = scheduler()
    s.tick(0.0)
    t = 0.0
    for k in range(10):
        t = 0.01 + k / 30
        s.add(t, 0.002)
    changes = []
    for k in range(10):
        t += 1 / 30
        d = s.add(t, 0.006)
        if d:
            changes.append((k, d))
    # The mean over the ten samples in the window reaches α with the fifth 0.006 (0.0036 with the fourth).
    assert [k for k, _ in changes] == [4]
    d = changes[0][1]
    assert d.trigger == CHANGE and d.n_pulses == 1 and d.arrival == d.time
    assert d.value == pytest.approx(0.004, abs=1e-12)
    assert s.next_tick == pytest.approx(d.time + PERIOD)


def test_flip_back_within_a_period_waits_for_the_tick():
    s = scheduler()
    s.tick(0.0)
    first = s.add(0.1, 0.006)  # mean 0.006 → N = 1, emitted at once
    assert first is not None and first.n_pulses == 1
    back = s.add(0.12, 0.0)  # mean 0.003 → N = 0 would undo the change 20 ms later: left to the tick
    assert back is None
    d = s.tick(s.next_tick)
    assert d.trigger == TICK and d.n_pulses == 0


def test_no_input_since_the_start_is_no_information_after_the_stale_limit():
    s = scheduler()
    assert s.tick(CFG.timing.stale_after_s).status == WAITING
    d = s.tick(CFG.timing.stale_after_s + PERIOD)
    assert d.status == NO_INFORMATION and d.n_pulses == 0


def test_the_no_information_cue_is_two_soft_tones_unlike_a_pulse():
    cue, rate = CFG.no_information, CFG.audio.sample_rate
    samples = synthesise_cue(cue, rate, CFG.timing.buffer_s)
    starts = cue_tones(samples, rate, cue)
    assert len(starts) == 2 and starts[1] - starts[0] == pytest.approx(
        (cue.cue_tone_s + cue.cue_gap_s) * rate, abs=0.02 * rate
    )
    pulses = synthesise(3, CFG.equation2, CFG.audio, CFG.timing.buffer_s)
    assert cue_tones(pulses, rate, cue) == []  # pulses are clicks, never taken for the cue
    assert samples[0] == 0 and np.abs(samples).max() <= cue.cue_level  # faded in, never louder than its level
    assert np.abs(samples).max() < CFG.audio.level


def test_slow_input_holds_the_newest_value_until_it_is_stale_then_recovers():
    s = scheduler()
    s.add(0.0, 0.010)
    assert s.tick(0.5).n_pulses == 2 and s.status == LIVE  # window empty: the newest sample stands in
    d = s.tick(1.2)
    assert d.status == NO_INFORMATION and d.n_pulses == 0 and s.status == NO_INFORMATION
    d = s.add(2.0, 0.010)
    assert s.status == LIVE and d is not None and d.n_pulses == 2 and d.trigger == CHANGE


def frame(index, t, state=TrackingState.OK, per_axis=0.01):
    return FeatureFrame("d", index, t, state, rotation_frame(index, t, 0.0).rts + np.float32(per_axis))


def test_rotation_speed_is_rms_of_roll_pitch_yaw_in_degrees_per_second():
    speed = RotationSpeed(CFG.rotation)
    assert speed.update(rotation_frame(0, 0.0, 120.0)) is None  # no previous frame
    assert speed.update(rotation_frame(1, 1 / PUBLISH_HZ, 120.0)) == pytest.approx(120.0, rel=1e-5)
    rts = rotation_frame(2, 0.1, 0.0).rts.copy()
    from seesys.core import rts_schema

    rts[rts_schema.index_of("rel_roll")] = 0.03  # RMS of (0.03, 0, 0) = 0.03/√3 rad over 1/30 s
    got = speed.update(FeatureFrame("test-device", 2, 2 / PUBLISH_HZ, TrackingState.OK, rts))
    assert got == pytest.approx(math.degrees(0.03 / math.sqrt(3)) * PUBLISH_HZ, rel=1e-5)


def test_rotation_speed_handles_untracked_frames_gaps_and_bad_values():
    speed = RotationSpeed(CFG.rotation)
    speed.update(frame(0, 0.0))
    assert speed.update(frame(1, 0.033, TrackingState.LOST, per_axis=math.nan)) is None
    # The next tracked frame's rotation spans the untracked one: Δt is from the last tracked frame.
    assert speed.update(frame(2, 0.066)) == pytest.approx(math.degrees(0.01) / 0.066, rel=1e-4)
    assert speed.update(frame(3, 0.066 + CFG.rotation.max_frame_gap_s + 0.01)) is None  # a pause
    assert speed.update(frame(4, 0.0)) is None  # time went backwards (device restarted)
    assert speed.update(frame(5, 0.033, per_axis=math.inf)) is None


def write_log(path, timestamps, errors):
    pd.DataFrame({"timestamp": timestamps, "error_m": errors}).to_csv(path, index=False)
    return path


def steps_log(tmp_path):
    t = np.arange(0, 4, 1 / 30)
    e = np.select([t < 1, t < 2, t < 3], [0.002, 0.006, 0.010], 0.02)
    return write_log(tmp_path / "est.csv", t + 1000.0, e)


def test_render_gives_the_pulses_a_listener_hears(tmp_path):
    rate = CFG.audio.sample_rate
    rendering = render_estimates(read_estimate_log(steps_log(tmp_path)), CFG)
    decisions = rendering.decisions
    starts = [round(d.time * rate) for d in decisions]
    sizes = pulses_per_buffer(rendering.samples, rate, starts, [d.n_pulses for d in decisions], CFG.equation2)
    # Silence for the first second, then N = 1, 2, 3 as the mean crosses 4, 8 and 12 mm, each change at once
    # (the fifth 6 mm estimate, at 1 + 4/30 s, makes five of the ten in the window).
    assert run_lengths(sizes) == [0, 1, 2, 3]
    changes = [d for d in decisions if d.trigger == CHANGE]
    assert [d.n_pulses for d in changes] == [1, 2, 3]
    assert changes[0].time == pytest.approx(1.0 + 4 / 30)
    assert pulse_onsets(rendering.samples, rate)[0] == round((1.0 + 4 / 30) * rate)
    # Ticks 1/3 s apart, restarting from each change.
    for a, b in zip(decisions[:-1], decisions[1:]):
        assert b.trigger == CHANGE or b.time - a.time == pytest.approx(PERIOD)


@pytest.mark.system
def test_cli_render_writes_a_wav(tmp_path):
    out = tmp_path / "out.wav"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "advisory",
            "render",
            "--estimates",
            str(steps_log(tmp_path)),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr
    assert "24 pulses" in result.stdout
    x, rate = read_wav(out)
    assert rate == CFG.audio.sample_rate and len(pulse_onsets(x, rate)) == 24


@pytest.mark.parametrize(
    "text, message",
    [
        ("time,error\n1,0.1\n", "missing column(s) timestamp, error_m"),
        ("timestamp,error_m\n", "no estimates"),
        ("timestamp,error_m\n1,0.1\n2,-0.1\n", "row 3: error_m"),
        ("timestamp,error_m\n1,0.1\n2,abc\n", "row 3: error_m"),
        ("timestamp,error_m\n2,0.1\n1,0.1\n", "row 3: timestamps go backwards"),
    ],
)
def test_bad_estimate_logs_are_named_errors(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(SeesysError) as e:
        read_estimate_log(path)
    assert message in str(e.value)


@pytest.mark.system
def test_missing_estimate_log_is_a_clear_cli_error(tmp_path):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "advisory",
            "render",
            "--estimates",
            str(tmp_path / "nope.csv"),
            "--out",
            str(tmp_path / "x.wav"),
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and "seesys: error: estimate log not found" in result.stderr


def test_handoff_buffer_round_trip_and_rejects_garbage():
    b = AudioBuffer(7, CHANGE, 2, 2, 48000, 1.5, 1.525, 1.49, np.arange(10, dtype=np.float32))
    back = decode_buffer(encode_buffer(b))
    assert back.samples.tolist() == b.samples.tolist()
    assert (back.buffer_id, back.trigger, back.n_pulses, back.play_at) == (7, CHANGE, 2, 1.525)
    body = encode_buffer(b)
    for bad in (body[:10], b"XXXX" + body[4:], body[:-4]):
        with pytest.raises(HandoffError):
            decode_buffer(bad)


@pytest.mark.system
def test_an_estimate_log_whose_timestamps_collapsed_is_refused_in_one_line(tmp_path):
    """Epoch times written with 9 significant digits: 24 estimates of 0.8 s fall on 1 or 2 distinct times. Rendered,
    every pulse would sound at 0 s; render (and replay, which reads the log the same way) refuse it instead."""
    times = 1305031102.175 + np.arange(24) / 30
    path = tmp_path / "collapsed.csv"
    path.write_text("frame_index,timestamp,error_m\n" + "".join(f"{k},{t:.9g},0.02\n" for k, t in enumerate(times)))
    with pytest.raises(SeesysError, match=r"24 estimates at only [12] distinct time"):
        read_estimate_log(path)
    for command in ("render", "replay"):
        args = ["--out", str(tmp_path / "x.wav")] if command == "render" else []
        result = subprocess.run(
            [sys.executable, "-m", "seesys", "advisory", command, "--estimates", str(path), *args],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert "lost their precision" in result.stderr
    # Two rows at one time (a duplicate) are no collapse; the frame index column is read when there is one.
    path.write_text("frame_index,timestamp,error_m\n7,1.5,0.01\n9,1.5,0.02\n12,2.0,0.0\n")
    log = read_estimate_log(path)
    assert log.frame_indices.tolist() == [7, 9, 12] and log.frame_index(2) == 12
    assert read_estimate_log(steps_log(tmp_path)).frame_index(5) == 5  # no column: the row number


HEAD_BOUNDS = (0.004, 0.008, 0.012)


def _estimate(error_m, probabilities=None, thresholds=HEAD_BOUNDS):
    from seesys.core.messages import Estimate, Exceedance, decode, encode

    head = () if probabilities is None else tuple(Exceedance(t, p) for t, p in zip(thresholds, probabilities))
    return decode(encode(Estimate("dev", 0, 0.0, error_m, "m", head=head)))  # as received: float32 on the wire


def test_the_head_class_of_the_window_mean_decides_n_where_every_estimate_carries_it():
    """A 6 mm estimate (Equation 2: 1 pulse) whose head says ≥ 12 mm plays 3 pulses; the probabilities are averaged
    over the same window as the estimates: 0.9 and 0.2 for 12 mm average to 0.55, still ≥ 0.5."""
    from advisory.conditions import estimate_reading
    from advisory.scheduler import HEAD

    read = estimate_reading(CFG)
    s = scheduler()
    r = read(_estimate(0.006, (0.95, 0.9, 0.9)))
    d = s.add(0.0, r.value, r.head)
    assert (d.n_pulses, d.pulses_from, d.value) == (3, HEAD, 0.006)
    r = read(_estimate(0.006, (0.95, 0.6, 0.2)))
    assert s.add(0.05, r.value, r.head) is None  # means (0.95, 0.75, 0.55): class 3 still, no change
    d = s.tick(s.next_tick)  # 1/3 s after the change: the first estimate has left the window
    assert (d.n_pulses, d.pulses_from, d.time) == (2, HEAD, pytest.approx(PERIOD))


@pytest.mark.parametrize("case", ["no head", "other thresholds", "fewer thresholds", "pulses_from estimate"])
def test_equation_2_of_the_estimate_decides_n_otherwise(case):
    import dataclasses

    from advisory.conditions import estimate_reading

    cfg = CFG
    messages = [_estimate(0.006, (0.95, 0.9, 0.9))] * 3
    if case == "no head":
        messages = [_estimate(0.006)] * 3
    elif case == "other thresholds":
        messages = [_estimate(0.006, (0.95, 0.9, 0.9), (0.004, 0.008, 0.016))] * 3
    elif case == "fewer thresholds":
        messages = [_estimate(0.006, (0.95, 0.9), (0.004, 0.008))] * 3
    else:
        cfg = dataclasses.replace(CFG, pulses=dataclasses.replace(CFG.pulses, pulses_from="estimate"))
    read = estimate_reading(cfg)
    s = scheduler()
    for k, message in enumerate(messages):
        r = read(message)
        s.add(0.03 * k, r.value, r.head)
    d = s.tick(s.next_tick)
    assert (d.n_pulses, d.pulses_from, d.value) == (1, "estimate", pytest.approx(0.006))


def test_pulses_from_must_be_head_or_estimate(tmp_path):
    from seesys.core.errors import ConfigError
    from seesys.io.config import write_config_dir

    assert CFG.pulses.pulses_from == "head"
    with pytest.raises(ConfigError, match="pulses_from must be 'head' or 'estimate'"):
        load_advisory_config(write_config_dir(tmp_path, {"pulses_from": "forest"}))


def test_a_window_where_some_estimates_carry_no_head_is_decided_by_equation_2():
    """A model without a head takes over mid-window: the head's mean would be of some estimates only."""
    from advisory.conditions import estimate_reading

    read = estimate_reading(CFG)
    s = scheduler()
    first = read(_estimate(0.006, (0.95, 0.9, 0.9)))
    assert s.add(0.0, first.value, first.head).pulses_from == "head"
    plain = read(_estimate(0.006))
    d = s.add(0.03, plain.value, plain.head)
    assert (d.n_pulses, d.pulses_from) == (1, "estimate")


def test_render_plays_the_heads_class_of_an_estimate_log_with_equation_2s_thresholds(tmp_path):
    """A log of 6 mm estimates (Equation 2: 1 pulse) whose head says 8-12 mm: 2 pulses from the head; the same log
    with other thresholds, or rendered with pulses_from = "estimate", plays Equation 2's 1 pulse."""
    import dataclasses

    t = np.arange(0, 2, 1 / 30)
    probabilities = {"p_ge_0.004": 0.97, "p_ge_0.008": 0.7, "p_ge_0.012": 0.1}
    path = tmp_path / "head.csv"
    pd.DataFrame({"timestamp": t, "error_m": 0.006, **probabilities, "head_class": 2}).to_csv(path, index=False)
    log = read_estimate_log(path)
    assert log.head_thresholds_m == HEAD_BOUNDS and log.head(0) == (0.97, 0.7, 0.1)
    live = [d for d in render_estimates(log, CFG).decisions if d.status == LIVE]
    assert {(d.n_pulses, d.pulses_from) for d in live} == {(2, "head")}
    by_estimate = dataclasses.replace(CFG, pulses=dataclasses.replace(CFG.pulses, pulses_from="estimate"))
    other = tmp_path / "other.csv"
    pd.DataFrame({"timestamp": t, "error_m": 0.006, "p_ge_0.004": 0.97, "p_ge_0.009": 0.7, "p_ge_0.012": 0.1}).to_csv(
        other, index=False
    )
    for rendering in (render_estimates(log, by_estimate), render_estimates(read_estimate_log(other), CFG)):
        assert {(d.n_pulses, d.pulses_from) for d in rendering.decisions if d.status == LIVE} == {(1, "estimate")}


def test_an_estimate_log_with_a_probability_outside_0_1_is_refused(tmp_path):
    path = tmp_path / "bad.csv"
    pd.DataFrame({"timestamp": [0.0, 0.1], "error_m": 0.006, "p_ge_0.004": [0.5, 1.2]}).to_csv(path, index=False)
    with pytest.raises(SeesysError, match=r"row 3: p_ge_0.004 1.2 is not a probability"):
        read_estimate_log(path)
