"""Camera intrinsics: the pinhole model every frame, PSD grid and renderer uses."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

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
        return dataclasses.replace(
            self,
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )

    def without_distortion(self) -> Intrinsics:
        """The ideal pinhole camera of the same lens."""
        return dataclasses.replace(self, distortion=(0.0, 0.0, 0.0, 0.0, 0.0))
