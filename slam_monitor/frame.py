"""The record every frame source yields, and the camera intrinsics that travel with it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels, with OpenCV/ORB-SLAM3 radial-tangential distortion (k1, k2, p1, p2, k3)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        """The 3×3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same lens on a sensor of ``width``×``height`` (focal lengths and centre scaled; pixel centres at
        integer coordinates, so the centre scales about the image corner −0.5)."""
        sx, sy = width / self.width, height / self.height
        return dataclasses.replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                                   cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5)

    def without_distortion(self) -> Intrinsics:
        """The ideal pinhole camera of the same lens."""
        return dataclasses.replace(self, distortion=(0.0, 0.0, 0.0, 0.0, 0.0))


@dataclass(frozen=True)
class Frame:
    """One camera frame as SLAM consumes it.

    ``index`` counts frames from 0 in the order the source delivered them; ``timestamp`` is in seconds on the
    source's clock; ``gray`` is (H, W) uint8; ``depth``, when the source has it, is (H, W) float32 metres aligned
    to ``gray``, 0 where unknown.
    """

    index: int
    timestamp: float
    gray: np.ndarray
    intrinsics: Intrinsics
    depth: np.ndarray | None = field(default=None)
