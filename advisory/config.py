"""The advisory's settings: ``configs/advisory.toml`` as typed, frozen dataclasses, checked for consistency."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core.equation2 import Equation2Config, RotationConfig
from seesys.core.errors import ConfigError
from seesys.io.config import load_section


@dataclass(frozen=True)
class TimingConfig:
    window_s: float
    cadence_hz: float
    buffer_s: float
    stale_after_s: float
    listen_to_device: str

    @property
    def cadence_s(self) -> float:
        return 1.0 / self.cadence_hz


@dataclass(frozen=True)
class AudioConfig:
    sample_rate: int
    tone_hz: float
    level: float
    host_api: str
    output_device: str
    channels: int
    blocksize: int
    schedule_latency_s: float
    stall_after_s: float


@dataclass(frozen=True)
class NoInformationConfig:
    no_information_cue: bool
    cue_every_s: float
    cue_tone_hz: float
    cue_level: float
    cue_tone_s: float
    cue_gap_s: float


@dataclass(frozen=True)
class HandoffConfig:
    endpoint: str
    poll_ms: int
    send_high_water_mark: int


@dataclass(frozen=True)
class ReplayConfig:
    replay_device_id: str
    replay_model_version: str
    replay_settle_s: float


@dataclass(frozen=True)
class SupervisorConfig:
    restart_delay_s: float
    session_folder: str


#: ``[pulses] pulses_from``: the head's class where the estimates carry one for Equation 2's class boundaries, or
#: always Equation 2 of the moving-mean estimate.
HEAD_SOURCE = "head"
ESTIMATE_SOURCE = "estimate"


@dataclass(frozen=True)
class PulsesConfig:
    pulses_from: str  # HEAD_SOURCE or ESTIMATE_SOURCE


@dataclass(frozen=True)
class MotionConfig:
    """The ``motion`` condition: N = how many of ``thresholds_m_s`` (ascending) the moving mean of the motion
    statistic (``advisory.motion``, m/s) reaches, capped at Equation 2's maximum; ``calibration`` says where the
    thresholds came from."""

    thresholds_m_s: list[float]
    statistic_window_s: float
    motion_max_frame_gap_s: float
    calibration: str


@dataclass(frozen=True)
class AdvisoryConfig:
    equation2: Equation2Config
    rotation: RotationConfig
    motion: MotionConfig
    timing: TimingConfig
    audio: AudioConfig
    no_information: NoInformationConfig
    handoff: HandoffConfig
    replay: ReplayConfig
    supervisor: SupervisorConfig
    pulses: PulsesConfig


def _check(cfg: AdvisoryConfig, where: str) -> None:
    eq, tm, au, ni = cfg.equation2, cfg.timing, cfg.audio, cfg.no_information
    problems = []
    if not 0 < eq.alpha_m < eq.beta_m:
        problems.append(f"equation2 needs 0 < alpha_m < beta_m (got {eq.alpha_m}, {eq.beta_m})")
    if eq.pulse_s <= 0 or eq.interval_s < 0 or eq.pulse_s + eq.interval_s > tm.buffer_s:
        problems.append("equation2 needs pulse_s > 0, interval_s >= 0 and one pulse + interval within buffer_s")
    positive = {
        "pulses_per_metre": eq.pulses_per_metre,
        "error_resolution_m": eq.error_resolution_m,
        "degrees_per_step": cfg.rotation.degrees_per_step,
        "speed_resolution_deg_s": cfg.rotation.speed_resolution_deg_s,
        "max_frame_gap_s": cfg.rotation.max_frame_gap_s,
        "statistic_window_s": cfg.motion.statistic_window_s,
        "motion_max_frame_gap_s": cfg.motion.motion_max_frame_gap_s,
        "window_s": tm.window_s,
        "cadence_hz": tm.cadence_hz,
        "stale_after_s": tm.stale_after_s,
        "sample_rate": au.sample_rate,
        "tone_hz": au.tone_hz,
        "channels": au.channels,
        "blocksize": au.blocksize,
        "schedule_latency_s": au.schedule_latency_s,
        "stall_after_s": au.stall_after_s,
        "cue_every_s": ni.cue_every_s,
        "cue_tone_hz": ni.cue_tone_hz,
        "cue_tone_s": ni.cue_tone_s,
        "cue_gap_s": ni.cue_gap_s,
    }
    problems += [f"{name} must be positive (got {value})" for name, value in positive.items() if value <= 0]
    if tm.buffer_s > tm.cadence_s + 1e-9:
        problems.append(f"buffer_s ({tm.buffer_s}) must not exceed the cadence period ({tm.cadence_s:.4f} s)")
    if not 0 < au.level <= 1:
        problems.append(f"level must be in (0, 1] (got {au.level})")
    if not 0 < ni.cue_level <= 1:
        problems.append(f"cue_level must be in (0, 1] (got {ni.cue_level})")
    if 2 * ni.cue_tone_s + ni.cue_gap_s > tm.buffer_s:
        problems.append(f"the cue (two tones of cue_tone_s and cue_gap_s between) must fit in buffer_s ({tm.buffer_s})")
    thresholds = cfg.motion.thresholds_m_s
    if not thresholds or thresholds[0] <= 0 or any(b <= a for a, b in zip(thresholds, thresholds[1:])):
        problems.append(f"motion thresholds_m_s must be positive and strictly ascending (got {thresholds})")
    if cfg.pulses.pulses_from not in (HEAD_SOURCE, ESTIMATE_SOURCE):
        problems.append(f"pulses_from must be {HEAD_SOURCE!r} or {ESTIMATE_SOURCE!r} (got {cfg.pulses.pulses_from!r})")
    if problems:
        raise ConfigError(f"{where}: " + "; ".join(problems))


#: The file of :class:`AdvisoryConfig` in the configuration folder.
SECTION = "advisory"


def load_advisory_config(directory: Path | None = None) -> AdvisoryConfig:
    """Load and check ``configs/advisory.toml`` (``directory`` overrides the config folder)."""
    cfg = load_section(SECTION, AdvisoryConfig, directory)
    _check(cfg, "advisory.toml")
    return cfg
