"""ORB-SLAM3 through ``pyorbslam3``: one call per frame, returning everything observers need as a record.

The vocabulary and the settings file are validated before ``pyorbslam3.Slam`` is constructed, because
ORB-SLAM3 answers a bad file by exiting the process (missing setting) or segfaulting (garbage vocabulary).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seesys.core.camera import Intrinsics
from seesys.core.tracking_state import TrackingState
from slam_monitor.frame import Frame
from slam_monitor.orbslam_settings import SlamMode, validate_settings_file
from slam_monitor.pacing import thread_ids
from slam_monitor.vocabulary import validate_vocabulary

MS_PER_S = 1000.0


@dataclass(frozen=True)
class TrackOutput:
    """What ORB-SLAM3 made of one frame.

    ``pose_cw`` (T_camera_world) and ``pose_wc`` (T_world_camera) are 4x4 float64, ``None`` when ORB-SLAM3 has
    no valid pose. ``keypoints`` (N, 2) float32 are all undistorted keypoints of the frame; ``map_points``
    (M, 3) float32 are the world positions of the map points tracked in it. The two are **not** row-aligned
    (docs/device.md). ``map_changed`` is true after a loop closure or global bundle adjustment.
    """

    frame_index: int
    timestamp: float
    state: TrackingState
    pose_cw: np.ndarray | None
    pose_wc: np.ndarray | None
    num_tracked_points: int
    track_ms: float
    keypoints: np.ndarray
    map_points: np.ndarray
    map_changed: bool

    @property
    def tracked(self) -> bool:
        """A good pose: tracking state OK (or OK_KLT) and a valid pose."""
        return self.state.tracked and self.pose_wc is not None


class Tracker:
    """A running ORB-SLAM3 system in monocular or RGB-D mode. Call :meth:`shutdown` when done."""

    def __init__(self, vocabulary: Path, settings: Path, mode: SlamMode, intrinsics: Intrinsics):
        validate_vocabulary(vocabulary)
        validate_settings_file(settings, mode, intrinsics)
        import pyorbslam3

        sensor = pyorbslam3.Sensor.RGBD if mode is SlamMode.RGBD else pyorbslam3.Sensor.MONOCULAR
        self.mode = mode
        existing = thread_ids()
        self._slam = pyorbslam3.Slam(vocabulary, settings, sensor, use_viewer=False)
        # ORB-SLAM3's local-mapping and loop-closing threads, watched by the pacer
        self.background_thread_ids = thread_ids() - existing

    def track(self, frame: Frame) -> TrackOutput:
        start = time.perf_counter()
        if self.mode is SlamMode.RGBD:
            result = self._slam.track_rgbd(frame.gray, frame.depth, frame.timestamp)
        else:
            result = self._slam.track_monocular(frame.gray, frame.timestamp)
        track_ms = (time.perf_counter() - start) * MS_PER_S
        valid = bool(result.pose_valid)
        return TrackOutput(
            frame_index=frame.index,
            timestamp=frame.timestamp,
            state=TrackingState(int(result.state)),
            pose_cw=np.array(result.pose_cw, dtype=np.float64) if valid else None,
            pose_wc=np.array(result.pose_wc, dtype=np.float64) if valid else None,
            num_tracked_points=int(result.num_tracked_points),
            track_ms=track_ms,
            keypoints=np.asarray(self._slam.tracked_keypoints(), dtype=np.float32).reshape(-1, 2),
            map_points=np.asarray(self._slam.tracked_map_points(), dtype=np.float32).reshape(-1, 3),
            map_changed=bool(self._slam.map_changed()),
        )

    def shutdown(self) -> None:
        self._slam.shutdown()
