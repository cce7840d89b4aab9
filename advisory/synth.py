"""Synthesis of one advisory buffer: N short tone pulses, one every pulse + interval seconds, from the start."""

from __future__ import annotations

import numpy as np

from advisory.config import AudioConfig
from seesys.core.equation2 import Equation2Config


def buffer_samples(buffer_s: float, sample_rate: int) -> int:
    """Length of every buffer in samples (a silent buffer is as long as a full one)."""
    return int(round(buffer_s * sample_rate))


def pulse_onsets(n_pulses: int, eq: Equation2Config, sample_rate: int) -> list[int]:
    """Sample index of the start of each pulse in a buffer."""
    return [int(round(k * (eq.pulse_s + eq.interval_s) * sample_rate)) for k in range(n_pulses)]


def synthesise(n_pulses: int, eq: Equation2Config, audio: AudioConfig, buffer_s: float) -> np.ndarray:
    """A mono float32 buffer of ``buffer_s`` seconds holding ``n_pulses`` tone bursts of ``pulse_s`` seconds.

    Each burst is a cosine at ``tone_hz`` and ``level``: its first sample is at full level, so the onset is a sharp
    click, like a Geiger counter's, and lies on an exact sample (which the tests and the latency logs rely on).
    """
    out = np.zeros(buffer_samples(buffer_s, audio.sample_rate), dtype=np.float32)
    length = max(1, int(round(eq.pulse_s * audio.sample_rate)))
    t = np.arange(length) / audio.sample_rate
    burst = (audio.level * np.cos(2 * np.pi * audio.tone_hz * t)).astype(np.float32)
    for onset in pulse_onsets(n_pulses, eq, audio.sample_rate):
        end = min(onset + length, out.size)
        out[onset:end] = burst[: end - onset]
    return out
