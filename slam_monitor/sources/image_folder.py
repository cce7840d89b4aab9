"""A folder of images with a timestamp list, and a video file. Both take their intrinsics from a
``calibration.yaml`` next to them, else from ``configs/camera.toml``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from slam_monitor.frame import Frame
from slam_monitor.sources.base import (
    FrameSource,
    SourceError,
    nominal_fps,
    read_gray,
    read_timestamped_list,
    require_file,
    require_folder,
    to_gray,
)
from slam_monitor.sources.settings import FileSourceDefaults, folder_calibration

TIMESTAMP_LIST = "timestamps.txt"


class ImageFolderSource(FrameSource):
    """Images listed in ``timestamps.txt`` (``timestamp filename`` per line, seconds), in the listed order."""

    has_depth = False

    def __init__(self, folder: Path, defaults: FileSourceDefaults):
        self.folder = require_folder(folder, "image")
        self._images = read_timestamped_list(self.folder / TIMESTAMP_LIST)
        calibration = folder_calibration(self.folder, defaults)
        self.intrinsics = calibration.intrinsics
        self.fps = calibration.fps or nominal_fps(np.array([t for t, _ in self._images]), defaults.fps)
        self.description = f"image folder {self.folder}"

    @property
    def frame_count(self) -> int:
        return len(self._images)

    def frames(self) -> Iterator[Frame]:
        for index, (timestamp, name) in enumerate(self._images):
            yield Frame(index, timestamp, read_gray(self.folder / name), self.intrinsics)


class VideoSource(FrameSource):
    """A video file decoded with OpenCV; timestamps are frame index / the container's frame rate."""

    has_depth = False

    def __init__(self, path: Path, defaults: FileSourceDefaults):
        import cv2

        self.path = require_file(path, "video file")
        self._capture = cv2.VideoCapture(str(path))
        if not self._capture.isOpened():
            raise SourceError(f"cannot open video {path} (unknown format or corrupt file)")
        calibration = folder_calibration(self.path.parent, defaults)
        self.intrinsics = calibration.intrinsics
        container_fps = self._capture.get(cv2.CAP_PROP_FPS)
        self.fps = calibration.fps or (container_fps if container_fps > 0 else defaults.fps)
        self._count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT)) or None
        self.description = f"video {self.path}"

    @property
    def frame_count(self) -> int | None:
        return self._count

    def frames(self) -> Iterator[Frame]:
        index = 0
        while True:
            ok, image = self._capture.read()
            if not ok:
                return
            yield Frame(index, index / self.fps, to_gray(image, f"{self.path} frame {index}"), self.intrinsics)
            index += 1

    def close(self) -> None:
        self._capture.release()
