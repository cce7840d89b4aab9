"""Camera effects applied to a sharp render, each computed from the true motion and the sensor model.

- Motion blur: the sharp frame is warped along the image motion that the true camera motion and the true depth
  cause over the exposure, and the warped copies are averaged (one copy per pixel of the longest streak).
- Exposure and gain: the signal scales with the light level, the exposure time and the gain.
- Sensor noise: shot noise on the photo-electrons, Gaussian read noise, black level, 8-bit quantisation.
- Lens distortion: OpenCV's radial-tangential model, applied by resampling the undistorted render.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seesys.core.camera import Intrinsics
from synth.renderer import RayGrid


def image_motion(depth: np.ndarray, grid: RayGrid, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Pixel displacement (H×W×2) of every pixel when the camera moves by (rotation, translation), which maps
    points of the render's camera frame into the moved camera's frame. Pixels without depth do not move."""
    r = rotation.astype(np.float32)
    t = translation.astype(np.float32)
    px = grid.x * depth
    py = grid.y * depth
    qx = r[0, 0] * px + r[0, 1] * py + r[0, 2] * depth + t[0]
    qy = r[1, 0] * px + r[1, 1] * py + r[1, 2] * depth + t[1]
    qz = r[2, 0] * px + r[2, 1] * py + r[2, 2] * depth + t[2]
    valid = (depth > 0) & (qz > grid.near_m)
    qz = np.where(valid, qz, 1.0)
    flow = np.empty(depth.shape + (2,), np.float32)
    flow[..., 0] = np.where(valid, grid.lens.fx * (qx / qz - grid.x), 0.0)
    flow[..., 1] = np.where(valid, grid.lens.fy * (qy / qz - grid.y), 0.0)
    return flow


def motion_blur(
    image: np.ndarray, grid: RayGrid, flow_start: np.ndarray, flow_end: np.ndarray, max_samples: int
) -> tuple[np.ndarray, float]:
    """Average of the image moved along the flow from exposure start to exposure end.

    The image seen at a sub-time is approximated by a backward warp of the sharp render with the flow at the
    pixel itself (no occlusion handling), the flow being interpolated linearly between start and end. Returns
    the blurred image and the 99th percentile streak length in pixels.
    """
    streak = np.linalg.norm(flow_end[::4, ::4] - flow_start[::4, ::4], axis=-1)
    p99 = float(np.percentile(streak, 99))
    samples = int(np.clip(np.ceil(p99), 1, max_samples))
    # Backward-warp maps: pixel − flow(s), flow(s) = start + s · (end − start).
    base_x = grid.x * np.float32(grid.lens.fx) + np.float32(grid.lens.cx) - flow_start[..., 0]
    base_y = grid.y * np.float32(grid.lens.fy) + np.float32(grid.lens.cy) - flow_start[..., 1]
    step_x = flow_start[..., 0] - flow_end[..., 0]
    step_y = flow_start[..., 1] - flow_end[..., 1]
    fractions = np.linspace(0.0, 1.0, samples, dtype=np.float32) if samples > 1 else np.array([0.5], np.float32)
    acc = np.zeros_like(image, np.float32)
    for s in fractions:
        acc += cv2.remap(
            image, base_x + s * step_x, base_y + s * step_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
    return acc / np.float32(len(fractions)), p99


@dataclass(frozen=True)
class Photometry:
    """The exposure of one frame: the signal level (fraction of full scale per unit radiance) and the noise."""

    signal_scale: float
    shot_noise_dn_per_e: float
    read_noise_dn: float
    black_level_dn: float

    def expose(self, radiance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The 8-bit image the sensor reads out for ``radiance``.

        Shot noise is Poisson in the photo-electrons; at the signal levels here (tens of electrons and more) its
        normal approximation with variance ``signal · dn_per_e`` (in DN²) is indistinguishable and much cheaper.
        """
        signal_dn = np.maximum(radiance * np.float32(255.0 * self.signal_scale), 0.0)
        sigma = np.sqrt(signal_dn * np.float32(self.shot_noise_dn_per_e) + np.float32(self.read_noise_dn**2))
        dn = signal_dn + np.float32(self.black_level_dn) + sigma * rng.standard_normal(radiance.shape, np.float32)
        return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class LensDistortion:
    """Resampling maps that turn an undistorted render into the image of a lens with OpenCV distortion."""

    map_x: np.ndarray
    map_y: np.ndarray

    @classmethod
    def for_lens(cls, lens: Intrinsics) -> LensDistortion:
        k = lens.matrix()
        u, v = np.meshgrid(np.arange(lens.width, dtype=np.float64), np.arange(lens.height, dtype=np.float64))
        distorted = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        # For each pixel of the distorted image, the point of the undistorted render it shows.
        undistorted = cv2.undistortPoints(
            distorted,
            k,
            np.array(lens.distortion),
            None,
            None,
            k,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6),
        )
        maps = undistorted.reshape(lens.height, lens.width, 2).astype(np.float32)
        return cls(np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]))

    def apply(self, image: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        warped = cv2.remap(image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        # Depth is resampled without interpolation so that edges keep true depths.
        warped_depth = cv2.remap(depth, self.map_x, self.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
        return warped, warped_depth
