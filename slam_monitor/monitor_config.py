"""The typed form of ``configs/monitor.toml``: every default of the RTS monitor."""

from __future__ import annotations

import socket
from dataclasses import asdict, dataclass
from pathlib import Path

from seesys.core.camera_normalisation import ReferenceCamera
from seesys.core.errors import ConfigError
from seesys.core.windows import WindowConfig
from seesys.io.config import ConfigSet, build
from seesys.io.core_settings import load_label_config, load_window_config
from slam_monitor.depth_features import DepthQualityConfig
from slam_monitor.observability import NoiseModel
from slam_monitor.second_opinion import FlowConfig


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


#: The ``device_id`` setting that derives the id from the host and the source (:func:`resolve_device_id`).
AUTO_DEVICE_ID = "auto"


def resolve_device_id(configured: str, source: str, host: str | None = None) -> str:
    """The device id of a device reading ``source`` (``KIND:PATH``): ``configured`` itself, or, where it is empty
    or ``auto``, ``HOST:KIND:NAME``, NAME being the last part of the path (a camera's serial number, a
    recording's folder or file name; ``default`` for ``realsense:`` without a serial). Two devices on two hosts, or
    two cameras on one host, get two ids; the same device gets the same id each time it starts."""
    if configured and configured != AUTO_DEVICE_ID:
        return configured
    kind, _, path = source.partition(":")
    name = Path(path.rstrip("/")).name or path or "default"
    device_id = f"{host or socket.gethostname()}:{kind}:{name}"
    return device_id.encode("utf-8")[:255].decode("utf-8", "ignore")


#: The file of :class:`MonitorConfig` in the configuration folder.
SECTION = "monitor"


@dataclass(frozen=True)
class MonitorConfig:
    device_id: str
    queue_size: int
    reference_camera: ReferenceCamera
    features: FeatureConfig
    psd: PsdConfig
    local_map: LocalMapConfig
    depth: DepthQualityConfig
    windows: WindowConfig
    log: LogConfig
    observability: NoiseModel
    second_opinion: FlowConfig


def load_monitor_config(directory: Path | None = None) -> MonitorConfig:
    """``configs/monitor.toml``, with the shared model windows of ``configs/windows.toml`` and the second opinion's
    span, the label's ``delta_frames`` of ``configs/labels.toml``."""
    configs = ConfigSet.read(directory)
    path, data = configs.path(SECTION), configs.data(SECTION)
    if "windows" in data:
        raise ConfigError(f"{path}: [windows] belongs in windows.toml, the definition every part shares")
    if "span_frames" in data.get("second_opinion", {}):
        raise ConfigError(f"{path}: the second opinion's span is the label's delta_frames (labels.toml)")
    windows = asdict(load_window_config(directory))
    second_opinion = {**data.get("second_opinion", {}), "span_frames": load_label_config(directory).delta_frames}
    return build(MonitorConfig, {**data, "windows": windows, "second_opinion": second_opinion}, str(path))
