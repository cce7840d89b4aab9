"""Equation 2, the rotation rule and buffer synthesis, at and around every threshold."""

import subprocess
import sys

import numpy as np
import pytest

from advisory.config import load_advisory_config
from advisory.synth import buffer_samples, pulse_onsets, synthesise
from seesys.core.equation2 import error_pulses, max_pulses, rotation_pulses
from seesys.core.errors import ConfigError
from seesys.io.config import write_config_dir

CFG = load_advisory_config()
EQ, ROT, BUFFER_S = CFG.equation2, CFG.rotation, CFG.timing.buffer_s


def n_error(e):
    return error_pulses(e, EQ, BUFFER_S)


def test_paper_values_are_the_defaults():
    assert (EQ.alpha_m, EQ.beta_m, EQ.pulse_s, EQ.interval_s) == (0.004, 0.012, 0.001, 0.099)
    assert (CFG.timing.window_s, CFG.timing.cadence_hz, BUFFER_S) == (0.33, 3.0, 0.33)
    assert max_pulses(EQ, BUFFER_S) == 3  # ⌊0.33 / 0.1⌋


@pytest.mark.parametrize(
    "error_m, n",
    [
        (0.0, 0),
        (0.002, 0),
        (0.0039999, 0),
        (0.003999999, 0),
        (0.004, 1),
        (0.0040001, 1),
        (0.0079999, 1),
        (0.007999999, 1),
        (0.008, 2),
        (0.0080001, 2),
        (0.011999, 2),
        (0.011999999, 2),
        (0.012, 3),
        (0.0120001, 3),
        (0.02, 3),
        (1.0, 3),
    ],
)
def test_equation2_at_and_around_every_threshold(error_m, n):
    assert n_error(error_m) == n


def test_float_noise_at_a_threshold_counts_as_the_threshold():
    # The mean of ten 0.012 m estimates is 0.011999999999999999 in binary floating point: still β, so 3 pulses.
    mean = sum([0.012] * 10) / 10
    assert mean < 0.012 and n_error(mean) == 3
    assert n_error(0.012 - 1e-12) == 3 and n_error(0.004 - 1e-12) == 1
    # Half a nanometre below is still below: the resolution is 1 nm.
    assert n_error(0.004 - 6e-10) == 0


@pytest.mark.parametrize(
    "speed, n",
    [
        (0.0, 0),
        (99.999, 0),
        (99.9999999, 1),
        (100.0, 1),
        (149.999, 1),
        (150.0, 2),
        (199.999, 2),
        (200.0, 3),
        (249.999, 3),
        (250.0, 3),
        (1000.0, 3),
    ],
)
def test_rotation_rule_at_and_around_every_threshold(speed, n):
    # N = max(⌊θ/50⌋ − 1, 0) capped at 3; 99.9999999 rounds to 100 at the 1e-6 °/s resolution.
    assert rotation_pulses(speed, ROT, EQ, BUFFER_S) == n


@pytest.mark.parametrize("bad", [-0.001, float("nan"), float("inf")])
def test_rules_reject_impossible_inputs(bad):
    with pytest.raises(ValueError):
        n_error(bad)
    with pytest.raises(ValueError):
        rotation_pulses(bad, ROT, EQ, BUFFER_S)


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_buffer_holds_n_pulses_of_length_p_spaced_p_plus_i(n):
    rate = CFG.audio.sample_rate
    x = synthesise(n, EQ, CFG.audio, BUFFER_S)
    assert x.dtype == np.float32 and x.size == buffer_samples(BUFFER_S, rate) == round(0.33 * rate)
    loud = np.abs(x) > 1e-6
    starts = np.flatnonzero(loud & ~np.concatenate([[False], loud[:-1]]))
    onsets = [s for s in starts if s == 0 or not loud[max(0, s - 5) : s].any()]  # zero crossings inside a pulse
    assert onsets == pulse_onsets(n, EQ, rate) == [round(k * 0.1 * rate) for k in range(n)]
    for onset in onsets:
        assert x[onset] == pytest.approx(CFG.audio.level)
        assert not loud[onset + round(0.001 * rate) : onset + round(0.1 * rate)].any()  # silent for i seconds
    assert np.abs(x).max() <= CFG.audio.level + 1e-6


def _config_with(tmp_path, **overrides):
    return load_advisory_config(write_config_dir(tmp_path, overrides))


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"alpha_m": 0.02}, "alpha_m < beta_m"),
        ({"interval_s": 0.5}, "within buffer_s"),
        ({"buffer_s": 0.5}, "must not exceed the cadence period"),
        ({"level": 1.5}, "level must be in"),
        ({"sample_rate": 0}, "sample_rate must be positive"),
    ],
)
def test_inconsistent_settings_are_refused(tmp_path, overrides, message):
    with pytest.raises(ConfigError, match=message):
        _config_with(tmp_path, **overrides)


@pytest.mark.system
def test_cli_pulses_prints_n():
    def run(*args):
        return subprocess.run(
            [sys.executable, "-m", "seesys", "advisory", "pulses", *args], capture_output=True, text=True
        )

    assert run("0.008").stdout.strip() == "2"
    assert run("0.0039999").stdout.strip() == "0"
    assert run("--rotation", "150").stdout.strip() == "2"
    bad = run("nan")
    assert bad.returncode == 2 and "finite non-negative" in bad.stderr
