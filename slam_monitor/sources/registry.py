"""``KIND:PATH`` source specifications and the one function that opens any source."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from slam_monitor.sources.base import FrameSource, SourceError
from slam_monitor.sources.settings import CameraConfig


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``--source KIND:PATH``; for ``realsense:`` the path is an optional serial number."""

    kind: str
    path: str

    def __str__(self) -> str:
        return f"{self.kind}:{self.path}"


def _tum(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.tum import TumSource

    return TumSource(Path(spec.path), config.files, config.depth_check, with_depth)


def _euroc(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.euroc import EurocSource

    return EurocSource(Path(spec.path))


def _images(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.image_folder import ImageFolderSource

    return ImageFolderSource(Path(spec.path), config.files)


def _video(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.image_folder import VideoSource

    return VideoSource(Path(spec.path), config.files)


def _realsense(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.realsense import open_realsense_camera

    return open_realsense_camera(spec.path, config.realsense, config.depth_check, with_depth)


def _rsbag(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.realsense import open_realsense_recording

    return open_realsense_recording(
        Path(spec.path), config.realsense.stream, config.recording, config.depth_check, with_depth
    )


def _rosbag(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    from slam_monitor.sources.rosbag import RosbagSource

    return RosbagSource(Path(spec.path), config.rosbag, config.files, config.depth_check, with_depth)


Opener = Callable[[SourceSpec, CameraConfig, bool], FrameSource]

# kind -> (opener, whether it can deliver depth, what PATH means)
SOURCE_KINDS: dict[str, tuple[Opener, bool, str]] = {
    "tum": (_tum, True, "TUM RGB-D folder (rgb.txt, depth.txt, optional groundtruth.txt, calibration.yaml)"),
    "euroc": (_euroc, False, "EuRoC MAV sequence folder (mav0/cam0)"),
    "images": (_images, False, "folder of images with timestamps.txt ('timestamp filename' lines)"),
    "video": (_video, False, "video file (intrinsics from calibration.yaml beside it)"),
    "realsense": (_realsense, True, "live RealSense camera; PATH is empty or a serial number"),
    "rsbag": (_rsbag, True, "RealSense recording (.bag or .db3)"),
    "rosbag": (_rosbag, True, "ROS 1 .bag, or ROS 2 bag folder / .db3 / .mcap (topics: configs/camera.toml [rosbag])"),
}


def parse_source_spec(text: str) -> SourceSpec:
    """Parse ``KIND:PATH``, checking the kind (the path is checked when the source opens)."""
    kind, sep, path = text.partition(":")
    if not sep:
        raise SourceError(f"source {text!r} is not KIND:PATH (kinds: {', '.join(SOURCE_KINDS)})")
    if kind not in SOURCE_KINDS:
        raise SourceError(f"unknown source kind {kind!r} in {text!r} (kinds: {', '.join(SOURCE_KINDS)})")
    if not path and kind != "realsense":
        raise SourceError(f"source {text!r} needs a path after '{kind}:'")
    return SourceSpec(kind, path)


def source_kinds_help() -> str:
    """One line per kind, for ``--help``."""
    return "; ".join(f"{kind}:PATH = {about}" for kind, (_, _, about) in SOURCE_KINDS.items())


def open_source(spec: SourceSpec, config: CameraConfig, with_depth: bool) -> FrameSource:
    """Open the source ``spec``; ``with_depth`` asks for metric depth (RGB-D), which the kind must provide."""
    opener, gives_depth, _ = SOURCE_KINDS[spec.kind]
    if with_depth and not gives_depth:
        raise SourceError(f"source kind {spec.kind!r} has no depth; use --mode mono")
    return opener(spec, config, with_depth)
