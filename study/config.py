"""The study kit's settings (``configs/study.toml``), one dataclass per table."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.io.config import load_section


@dataclass(frozen=True)
class ProtocolConfig:
    conditions: list[str]
    participants_per_condition: int
    design: str
    phases: list[str]
    objects: int
    assignment_seed: int
    participant_prefix: str


@dataclass(frozen=True)
class MetricsConfig:
    delta_frames: int
    all_pairs: bool
    association_max_dt_s: float
    loss_gap_factor: float
    stretch_gap_s: float
    speed_sample_s: float
    advice_high_error_m: float


@dataclass(frozen=True)
class MocapConfig:
    backend: str
    hostname: str
    port: int
    connect_timeout_s: float
    body: str
    mock_rigid_bodies: str
    mock_frequency_hz: int
    clock: str
    stats_interval_s: float


@dataclass(frozen=True)
class CalibrationConfig:
    max_offset_s: float
    offset_grid_s: float
    speed_smoothing_s: float
    station_step_s: float
    max_stations: int
    max_pair_span_s: float


@dataclass(frozen=True)
class RunnerConfig:
    source: str
    mode: str
    record_mocap: bool
    status_interval_s: float
    ready_timeout_s: float
    device_interrupt_timeout_s: float
    stop_timeout_s: float
    calibrate_at_end: bool


@dataclass(frozen=True)
class StudyConfig:
    protocol: ProtocolConfig
    metrics: MetricsConfig
    mocap: MocapConfig
    calibration: CalibrationConfig
    runner: RunnerConfig


def load_study_config(directory: Path | None = None) -> StudyConfig:
    return load_section("study", StudyConfig, directory)
