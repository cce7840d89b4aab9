"""The typed form of ``configs/monitor.toml``: every default of the RTS monitor."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.config import load_section
from slam_monitor.windows import WindowConfig


@dataclass(frozen=True)
class FeatureConfig:
    match_gate_px: float
    min_depth: float


@dataclass(frozen=True)
class PsdConfig:
    patch_px: int
    expansion: int
    near_depth: float


@dataclass(frozen=True)
class LocalMapConfig:
    voxel: float
    max_age_frames: int
    max_points: int


@dataclass(frozen=True)
class LogConfig:
    psd_chunk_records: int


@dataclass(frozen=True)
class MonitorConfig:
    device_id: str
    queue_size: int
    features: FeatureConfig
    psd: PsdConfig
    local_map: LocalMapConfig
    windows: WindowConfig
    log: LogConfig


def load_monitor_config(directory: Path | None = None) -> MonitorConfig:
    return load_section("monitor", MonitorConfig, directory)


def load_window_config(directory: Path | None = None) -> WindowConfig:
    """The model windows (``[windows]`` of ``configs/monitor.toml``), for the estimator and the dataset builder."""
    return load_monitor_config(directory).windows
