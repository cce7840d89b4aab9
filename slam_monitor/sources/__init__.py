"""Frame sources: datasets, videos, a live RealSense camera and RealSense recordings, behind one interface.

``open_source(parse_source_spec("tum:PATH"), load_camera_config(), with_depth=True)`` returns a
:class:`FrameSource`; iterate ``source.frames()`` for :class:`slam_monitor.frame.Frame` records.
"""

from slam_monitor.sources.base import DepthLimits, FrameSource, SourceError
from slam_monitor.sources.registry import SOURCE_KINDS, SourceSpec, open_source, parse_source_spec, source_kinds_help
from slam_monitor.sources.settings import CameraConfig, load_camera_config

__all__ = [
    "SOURCE_KINDS",
    "CameraConfig",
    "DepthLimits",
    "FrameSource",
    "SourceError",
    "SourceSpec",
    "load_camera_config",
    "open_source",
    "parse_source_spec",
    "source_kinds_help",
]
