"""Synthesis of one advisory buffer: N short tone pulses, one every pulse + interval seconds, from the start."""

from __future__ import annotations

import numpy as np

from advisory.config import AudioConfig, NoInformationConfig
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


def cue_onsets(cue: NoInformationConfig, sample_rate: int) -> list[int]:
    """Sample index of the start of each of the cue's two tones in a buffer."""
    return [0, int(round((cue.cue_tone_s + cue.cue_gap_s) * sample_rate))]


def synthesise_cue(cue: NoInformationConfig, sample_rate: int, buffer_s: float) -> np.ndarray:
    """The "no information" cue as one buffer of ``buffer_s`` seconds: two tones of ``cue_tone_s`` at
    ``cue_tone_hz`` and ``cue_level``, ``cue_gap_s`` apart. Each tone fades in and out (a Hann window), so it is
    soft, where a pulse is a click; its length and pitch tell it from a pulse by ear and in a recording."""
    out = np.zeros(buffer_samples(buffer_s, sample_rate), dtype=np.float32)
    length = int(round(cue.cue_tone_s * sample_rate))
    t = np.arange(length) / sample_rate
    tone = (cue.cue_level * np.hanning(length) * np.sin(2 * np.pi * cue.cue_tone_hz * t)).astype(np.float32)
    for onset in cue_onsets(cue, sample_rate):
        out[onset : onset + length] = tone
    return out
