"""Typed defaults of the frame sources, from ``configs/camera.toml``, and the per-folder calibration file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core.camera import Intrinsics
from seesys.core.camera_scale import ScaleSettings
from seesys.io.config import load_section
from slam_monitor.sources.base import DepthLimits, SourceError, read_yaml

CALIBRATION_FILE = "calibration.yaml"


@dataclass(frozen=True)
class FileSourceDefaults:
    intrinsics: Intrinsics
    fps: float
    depth_units_per_metre: float
    association_max_dt_s: float


@dataclass(frozen=True)
class RealSenseSettings:
    stream: str
    width: int
    height: int
    fps: int
    depth: bool
    frame_timeout_ms: int


@dataclass(frozen=True)
class RecordingSettings:
    real_time: bool
    frame_timeout_ms: int


@dataclass(frozen=True)
class RosbagSettings:
    """Topics of a ROS bag source; an empty name means found by message type (docs/device.md)."""

    image_topic: str
    depth_topic: str
    camera_info_topic: str
    ground_truth_topic: str
    ground_truth_child_frame: str


@dataclass(frozen=True)
class CameraConfig:
    files: FileSourceDefaults
    depth_check: DepthLimits
    realsense: RealSenseSettings
    recording: RecordingSettings
    rosbag: RosbagSettings
    scale: ScaleSettings


def load_camera_config(directory: Path | None = None) -> CameraConfig:
    """``configs/camera.toml`` as a :class:`CameraConfig`."""
    config = load_section("camera", CameraConfig, directory)
    if config.realsense.stream not in ("color", "infrared"):
        raise SourceError(
            f"camera.toml: realsense.stream must be 'color' or 'infrared', not {config.realsense.stream!r}"
        )
    return config


def _distortion(values: tuple[float, ...] | list[float]) -> tuple[float, float, float, float, float]:
    padded = tuple(float(v) for v in values) + (0.0,) * (5 - len(values))
    if len(padded) != 5:
        raise SourceError(f"distortion has {len(values)} coefficients, expected at most 5 (k1 k2 p1 p2 k3)")
    k1, k2, p1, p2, k3 = padded
    return k1, k2, p1, p2, k3


@dataclass(frozen=True)
class FolderCalibration:
    intrinsics: Intrinsics
    fps: float | None
    depth_units_per_metre: float


def folder_calibration(folder: Path, defaults: FileSourceDefaults) -> FolderCalibration:
    """The calibration of a dataset folder: its ``calibration.yaml`` if present, else the configured defaults."""
    path = folder / CALIBRATION_FILE
    if not path.is_file():
        return FolderCalibration(defaults.intrinsics, None, defaults.depth_units_per_metre)
    data = read_yaml(path)
    try:
        intrinsics = Intrinsics(
            int(data["width"]),
            int(data["height"]),
            float(data["fx"]),
            float(data["fy"]),
            float(data["cx"]),
            float(data["cy"]),
            _distortion(data.get("distortion", [])),
        )
    except (TypeError, ValueError) as e:
        raise SourceError(f"{path}: not a valid calibration file ({e})") from None
    except KeyError as e:
        raise SourceError(f"{path}: missing key {e.args[0]}") from None
    fps = data.get("fps")
    return FolderCalibration(
        intrinsics,
        float(fps) if fps else None,
        float(data.get("depth_factor", defaults.depth_units_per_metre)),
    )
