"""EuRoC MAV folders (ASL layout): the left camera ``mav0/cam0`` and, when present, the ground truth."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.camera import Intrinsics
from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_euroc_groundtruth
from slam_monitor.frame import Frame
from slam_monitor.sources.base import (
    FrameSource,
    SourceError,
    read_gray,
    read_timestamped_list,
    read_yaml,
    require_file,
    require_folder,
)

NS_PER_S = 1e9


class EurocSource(FrameSource):
    """The cam0 images of an EuRoC MAV sequence (``PATH`` is the sequence folder or its ``mav0``)."""

    has_depth = False

    def __init__(self, folder: Path):
        folder = require_folder(folder, "EuRoC")
        self.mav0 = folder / "mav0" if (folder / "mav0").is_dir() else folder
        self.cam0 = require_folder(self.mav0 / "cam0", "EuRoC cam0")
        sensor = read_yaml(require_file(self.cam0 / "sensor.yaml", "EuRoC camera file"))
        try:
            fu, fv, cu, cv = (float(v) for v in sensor["intrinsics"])
            width, height = (int(v) for v in sensor["resolution"])
            coefficients = [float(v) for v in sensor["distortion_coefficients"]] + [0.0]
            self.fps = float(sensor["rate_hz"])
            self._body_from_camera = np.array(sensor["T_BS"]["data"], dtype=float).reshape(4, 4)
        except (KeyError, TypeError, ValueError) as e:
            raise SourceError(f"{self.cam0 / 'sensor.yaml'}: missing or malformed camera field ({e})") from None
        self.intrinsics = Intrinsics(width, height, fu, fv, cu, cv, tuple(coefficients[:5]))  # type: ignore[arg-type]
        self._images = read_timestamped_list(self.cam0 / "data.csv")
        self.description = f"EuRoC MAV folder {self.mav0}"

    @property
    def frame_count(self) -> int:
        return len(self._images)

    def ground_truth(self) -> Poses | None:
        """The ground-truth body poses moved to cam0 with the camera's T_BS extrinsics."""
        path = self.mav0 / "state_groundtruth_estimate0" / "data.csv"
        if not path.is_file():
            return None
        body = read_euroc_groundtruth(path)
        world_camera = body.matrices @ self._body_from_camera
        return Poses.from_rotations(
            body.timestamps, world_camera[:, :3, 3], Rotation.from_matrix(world_camera[:, :3, :3])
        )

    def frames(self) -> Iterator[Frame]:
        for index, (stamp_ns, name) in enumerate(self._images):
            yield Frame(index, stamp_ns / NS_PER_S, read_gray(self.cam0 / "data" / name), self.intrinsics)
