"""The typed form of ``configs/monitor.toml``: every default of the RTS monitor."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from seesys.core.errors import ConfigError
from seesys.core.windows import WindowConfig
from seesys.io.config import build, config_dir, read_toml
from seesys.io.core_settings import load_window_config


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
    """``configs/monitor.toml``, with the shared model windows of ``configs/windows.toml``."""
    path = (directory or config_dir()) / "monitor.toml"
    data = read_toml(path)
    if "windows" in data:
        raise ConfigError(f"{path}: [windows] belongs in windows.toml, the definition every part shares")
    windows = asdict(load_window_config(directory))
    return build(MonitorConfig, {**data, "windows": windows}, str(path))
