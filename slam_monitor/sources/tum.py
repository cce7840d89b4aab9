"""TUM RGB-D folders: ``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt`` and ``calibration.yaml``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum
from slam_monitor.frame import Frame
from slam_monitor.sources.base import (
    DepthLimits,
    FrameSource,
    SourceError,
    check_depth,
    nominal_fps,
    read_depth_png,
    read_gray,
    read_timestamped_list,
    require_folder,
)
from slam_monitor.sources.settings import FileSourceDefaults, folder_calibration


class TumSource(FrameSource):
    """A TUM RGB-D sequence. Depth images are paired with the image nearest in time."""

    def __init__(self, folder: Path, defaults: FileSourceDefaults, depth_limits: DepthLimits, with_depth: bool):
        self.folder = require_folder(folder, "TUM")
        calibration = folder_calibration(self.folder, defaults)
        self.intrinsics = calibration.intrinsics
        self._images = read_timestamped_list(self.folder / "rgb.txt")
        times = np.array([t for t, _ in self._images])
        self.fps = calibration.fps or nominal_fps(times, defaults.fps)
        self._depth_units = calibration.depth_units_per_metre
        self._depth_limits = depth_limits
        self._depth_files: list[str | None] = [None] * len(self._images)
        self.has_depth = with_depth
        if with_depth:
            self._pair_with_depth(times, defaults.association_max_dt_s)
        self.description = f"TUM RGB-D folder {self.folder}"

    def _pair_with_depth(self, times: np.ndarray, max_dt: float) -> None:
        """Keep the images that have a depth image within ``max_dt`` seconds (as TUM's associate.py does)."""
        depth = read_timestamped_list(self.folder / "depth.txt")
        depth_times = np.array([t for t, _ in depth])
        nearest = np.abs(depth_times[None, :] - times[:, None]).argmin(axis=1)
        paired = [
            (image, depth[j][1])
            for image, t, j in zip(self._images, times, nearest)
            if abs(depth_times[j] - t) <= max_dt
        ]
        if not paired:
            raise SourceError(f"{self.folder}: no depth image within {max_dt} s of any image")
        self._images = [image for image, _ in paired]
        self._depth_files = [name for _, name in paired]

    @property
    def frame_count(self) -> int:
        return len(self._images)

    def ground_truth(self) -> Poses | None:
        path = self.folder / "groundtruth.txt"
        return read_tum(path) if path.is_file() else None

    def frames(self) -> Iterator[Frame]:
        for index, ((timestamp, name), depth_name) in enumerate(zip(self._images, self._depth_files)):
            gray = read_gray(self.folder / name)
            depth = None
            if self.has_depth and depth_name is not None:  # every image has its depth when depth is read
                depth_path = self.folder / depth_name
                depth = check_depth(
                    read_depth_png(depth_path, self._depth_units), gray, self._depth_limits, str(depth_path)
                )
            yield Frame(index, timestamp, gray, self.intrinsics, depth)
