"""ORB-SLAM3 settings: the typed ``configs/slam.toml``, the settings file generated from it and a source's
intrinsics, and the validation every settings file passes before ORB-SLAM3 sees it.

ORB-SLAM3 does not raise on a bad settings file: a missing required key makes it print a message and exit the
whole process with status 255, and a missing ``File.version`` silently selects its old parser. So every file,
generated or given by the user, is read back with OpenCV's FileStorage (ORB-SLAM3's own parser) and checked for
the keys ORB-SLAM3 1.0 requires before the SLAM system is constructed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from seesys.core.camera import Intrinsics
from seesys.core.errors import SeesysError
from seesys.io import resources
from seesys.io.config import load_section
from slam_monitor.vocabulary import TrainingConfig

SETTINGS_VERSION = "1.0"
# Frames reach ORB-SLAM3 as 8-bit gray and depth in metres, so its colour order is moot and its depth factor 1.
GRAY_IS_RGB = 1
DEPTH_IN_METRES_FACTOR = 1.0
VOCABULARY_ENV = "PYORBSLAM3_VOCAB"


class SettingsError(SeesysError):
    """An ORB-SLAM3 settings file is unreadable, lacks a required key, or does not fit the source."""


class SlamMode(str, Enum):
    MONO = "mono"
    RGBD = "rgbd"


@dataclass(frozen=True)
class OrbConfig:
    features: int
    scale_factor: float
    levels: int
    ini_fast_threshold: int
    min_fast_threshold: int


@dataclass(frozen=True)
class RgbdConfig:
    th_depth: float
    virtual_baseline_m: float


@dataclass(frozen=True)
class PacingConfig:
    """``[pacing]``: which modes are paced, and the wait for ORB-SLAM3's mapping (slam_monitor/pacing.py)."""

    mono: bool
    rgbd: bool
    wait_for_mapping: bool
    contention_fraction: float
    idle_window_s: float
    idle_busy_fraction: float
    max_mapping_wait_s: float

    def paces(self, mode: SlamMode) -> bool:
        return self.mono if mode is SlamMode.MONO else self.rgbd


@dataclass(frozen=True)
class ViewerConfig:
    key_frame_size: float
    key_frame_line_width: float
    graph_line_width: float
    point_size: float
    camera_size: float
    camera_line_width: float
    viewpoint_x: float
    viewpoint_y: float
    viewpoint_z: float
    viewpoint_f: float


@dataclass(frozen=True)
class SupervisorConfig:
    stall_timeout_s: float


@dataclass(frozen=True)
class SlamConfig:
    vocabulary: str
    orb: OrbConfig
    rgbd: RgbdConfig
    pacing: PacingConfig
    supervisor: SupervisorConfig
    viewer: ViewerConfig
    vocabulary_training: TrainingConfig


def load_slam_config(directory: Path | None = None) -> SlamConfig:
    """``configs/slam.toml`` as a :class:`SlamConfig`."""
    return load_section("slam", SlamConfig, directory)


def vocabulary_path(config: SlamConfig) -> Path:
    """The vocabulary to load: ``$PYORBSLAM3_VOCAB`` if set, else the configured file (relative to the SEESys
    home, :mod:`seesys.io.resources`)."""
    return resources.resolve(os.environ.get(VOCABULARY_ENV) or config.vocabulary)


# Keys ORB-SLAM3 1.0's Settings class requires (it exits when one is missing), by mode.
REQUIRED_KEYS: dict[SlamMode, tuple[str, ...]] = {
    SlamMode.MONO: (
        "File.version",
        "Camera.type",
        "Camera1.fx",
        "Camera1.fy",
        "Camera1.cx",
        "Camera1.cy",
        "Camera.width",
        "Camera.height",
        "Camera.fps",
        "Camera.RGB",
        "ORBextractor.nFeatures",
        "ORBextractor.scaleFactor",
        "ORBextractor.nLevels",
        "ORBextractor.iniThFAST",
        "ORBextractor.minThFAST",
        "Viewer.KeyFrameSize",
        "Viewer.KeyFrameLineWidth",
        "Viewer.GraphLineWidth",
        "Viewer.PointSize",
        "Viewer.CameraSize",
        "Viewer.CameraLineWidth",
        "Viewer.ViewpointX",
        "Viewer.ViewpointY",
        "Viewer.ViewpointZ",
        "Viewer.ViewpointF",
    ),
}
REQUIRED_KEYS[SlamMode.RGBD] = REQUIRED_KEYS[SlamMode.MONO] + ("RGBD.DepthMapFactor", "Stereo.ThDepth", "Stereo.b")
STRING_KEYS = ("File.version", "Camera.type")


def build_settings(intrinsics: Intrinsics, fps: float, mode: SlamMode, config: SlamConfig) -> dict[str, object]:
    """The ORB-SLAM3 settings for a pinhole camera with these intrinsics, in file order."""
    k1, k2, p1, p2, k3 = intrinsics.distortion
    settings: dict[str, object] = {
        "File.version": SETTINGS_VERSION,
        "Camera.type": "PinHole",
        "Camera1.fx": float(intrinsics.fx),
        "Camera1.fy": float(intrinsics.fy),
        "Camera1.cx": float(intrinsics.cx),
        "Camera1.cy": float(intrinsics.cy),
        "Camera1.k1": float(k1),
        "Camera1.k2": float(k2),
        "Camera1.p1": float(p1),
        "Camera1.p2": float(p2),
    }
    if k3:
        settings["Camera1.k3"] = float(k3)
    settings.update(
        {
            "Camera.width": intrinsics.width,
            "Camera.height": intrinsics.height,
            "Camera.fps": max(1, round(fps)),
            "Camera.RGB": GRAY_IS_RGB,
        }
    )
    if mode is SlamMode.RGBD:
        settings.update(
            {
                "RGBD.DepthMapFactor": DEPTH_IN_METRES_FACTOR,
                "Stereo.ThDepth": config.rgbd.th_depth,
                "Stereo.b": config.rgbd.virtual_baseline_m,
            }
        )
    orb, viewer = config.orb, config.viewer
    settings.update(
        {
            "ORBextractor.nFeatures": orb.features,
            "ORBextractor.scaleFactor": orb.scale_factor,
            "ORBextractor.nLevels": orb.levels,
            "ORBextractor.iniThFAST": orb.ini_fast_threshold,
            "ORBextractor.minThFAST": orb.min_fast_threshold,
            "Viewer.KeyFrameSize": viewer.key_frame_size,
            "Viewer.KeyFrameLineWidth": viewer.key_frame_line_width,
            "Viewer.GraphLineWidth": viewer.graph_line_width,
            "Viewer.PointSize": viewer.point_size,
            "Viewer.CameraSize": viewer.camera_size,
            "Viewer.CameraLineWidth": viewer.camera_line_width,
            "Viewer.ViewpointX": viewer.viewpoint_x,
            "Viewer.ViewpointY": viewer.viewpoint_y,
            "Viewer.ViewpointZ": viewer.viewpoint_z,
            "Viewer.ViewpointF": viewer.viewpoint_f,
        }
    )
    return settings


def _yaml_value(value: object) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return repr(value)  # always has a decimal point, so OpenCV reads a real, as ORB-SLAM3 expects
    return str(value)


def write_settings(path: Path, settings: dict[str, object]) -> Path:
    """Write ``settings`` as an OpenCV YAML file that ORB-SLAM3 reads."""
    lines = ["%YAML:1.0", "# Generated by SEESys (slam_monitor/orbslam_settings.py) for this session."]
    lines += [f"{key}: {_yaml_value(value)}" for key, value in settings.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def validate_settings_file(path: Path, mode: SlamMode, intrinsics: Intrinsics) -> None:
    """Check a settings file as ORB-SLAM3 will read it; raise :class:`SettingsError` naming the first problem."""
    import cv2

    if not path.is_file():
        raise SettingsError(f"ORB-SLAM3 settings file not found: {path}")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:
        # OpenCV's binding raises SystemError wrapping the cv2.error of the parser.
        detail = str(e.__cause__ or e).strip().splitlines()[-1]
        raise SettingsError(f"ORB-SLAM3 settings {path} cannot be parsed: {detail}") from None
    try:
        if not storage.isOpened():
            raise SettingsError(f"ORB-SLAM3 settings {path} cannot be opened as OpenCV YAML")
        for key in REQUIRED_KEYS[mode]:
            node = storage.getNode(key)
            if node.empty() or node.isNone():
                raise SettingsError(f"ORB-SLAM3 settings {path} lack the required key {key} ({mode.value} mode)")
            if key in STRING_KEYS and not node.isString():
                raise SettingsError(f"ORB-SLAM3 settings {path}: {key} must be a quoted string")
            if key not in STRING_KEYS and not (node.isReal() or node.isInt()):
                raise SettingsError(f"ORB-SLAM3 settings {path}: {key} must be a number")
        version = storage.getNode("File.version").string()
        if version != SETTINGS_VERSION:
            raise SettingsError(
                f"ORB-SLAM3 settings {path}: File.version is {version!r}, expected {SETTINGS_VERSION!r}"
            )
        camera_type = storage.getNode("Camera.type").string()
        if camera_type != "PinHole":
            raise SettingsError(f"ORB-SLAM3 settings {path}: Camera.type {camera_type!r} is not supported (PinHole)")
        size = (int(storage.getNode("Camera.width").real()), int(storage.getNode("Camera.height").real()))
        if size != (intrinsics.width, intrinsics.height):
            raise SettingsError(
                f"ORB-SLAM3 settings {path} are for {size[0]}x{size[1]} images, but the source delivers "
                f"{intrinsics.width}x{intrinsics.height}"
            )
    finally:
        storage.release()
