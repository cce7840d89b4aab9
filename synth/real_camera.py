"""What a real RGB-D camera does that the ideal one of the renderer does not (a preset's ``camera_model``).

Each effect is off when its parameter is zero (``damping`` 1, ``colour_noise_scale`` 1), and a camera model with
every effect off renders exactly as before the models existed (same bytes):

- **Depth not registered to colour**: the depth camera sits at ``depth_offset_m`` from the colour camera (its
  own frame) and its depth image is written as it sees it, not reprojected onto the colour image.
- **Misregistered depth**: the depth image is shifted by ``depth_misregistration_px`` (a calibration error).
- **Colour and depth not synchronised**: depth is captured ``depth_delay_s`` after the colour frame's mid-exposure.
- **Rolling shutter** (colour only; RGB-D depth imagers are global shutter): row r is read
  ``rolling_shutter_s · (r / (H − 1) − 1/2)`` after the middle row, so the image is sheared by the motion
  during the readout.
- **Auto-exposure lag and overshoot**: the exposure follows its target as a damped second-order loop with time
  constant ``auto_exposure_time_constant_s`` and damping ``auto_exposure_damping`` (< 1 overshoots), so light
  changes show as brightness flashes until the loop settles.
- **Depth noise growing with z²**, as on an active-stereo camera: σ_z = ``depth_noise_m_per_m2`` · z².
- **Colour noise level**: shot and read noise of ``[sensor]`` scaled by ``colour_noise_scale`` (in σ).
- **JPEG colour**: the 8-bit image goes through JPEG at ``jpeg_quality`` (1–100; 0: off), as from a camera that
  streams MJPEG; the PNG written holds the decoded pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from seesys.core.errors import SeesysError
from synth.renderer import RayGrid

# Sub-steps per frame of the auto-exposure loop's integration (stable for time constants down to ~1 frame).
_AE_SUBSTEPS = 20


def auto_exposure_response(target_log: np.ndarray, fps: float, time_constant_s: float, damping: float) -> np.ndarray:
    """The log exposure an auto-exposure loop reaches on each frame while following ``target_log``.

    A second-order loop x'' = ω²(target − x) − 2ζω x' with ω = 1 / ``time_constant_s`` and ζ = ``damping``,
    settled on the first frame's target. A step in the target is reached after about ``time_constant_s`` and,
    for ζ < 1, overshot by exp(−πζ / √(1 − ζ²)). ``time_constant_s`` 0 follows the target exactly.
    """
    target = np.asarray(target_log, dtype=np.float64)
    if time_constant_s <= 0 or len(target) == 0:
        return target.copy()
    omega, h = 1.0 / time_constant_s, 1.0 / (fps * _AE_SUBSTEPS)
    x, v = float(target[0]), 0.0
    out = np.empty_like(target)
    for i, goal in enumerate(target):
        for _ in range(_AE_SUBSTEPS):
            v += h * (omega * omega * (goal - x) - 2.0 * damping * omega * v)
            x += h * v
        out[i] = x
    return out


def rolling_shutter(
    image: np.ndarray, grid: RayGrid, flow_first_row: np.ndarray, flow_last_row: np.ndarray
) -> np.ndarray:
    """The image of a rolling-shutter sensor from a global-shutter render at the middle row's time.

    ``flow_first_row`` / ``flow_last_row`` (H×W×2) are the image motions from the render's pose to the poses at
    which the first and the last row are read; row r sees the motion interpolated at r / (H − 1). Like the motion
    blur, the render is backward-warped with the flow at the output pixel (no occlusion handling).
    """
    height = image.shape[0]
    fraction = np.linspace(0.0, 1.0, height, dtype=np.float32)[:, None]
    flow_x = flow_first_row[..., 0] + fraction * (flow_last_row[..., 0] - flow_first_row[..., 0])
    flow_y = flow_first_row[..., 1] + fraction * (flow_last_row[..., 1] - flow_first_row[..., 1])
    map_x = grid.x * np.float32(grid.lens.fx) + np.float32(grid.lens.cx) - flow_x
    map_y = grid.y * np.float32(grid.lens.fy) + np.float32(grid.lens.cy) - flow_y
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def shift_depth(depth: np.ndarray, shift_px: tuple[float, float]) -> np.ndarray:
    """``depth`` moved by (dx, dy) pixels, without interpolating across edges; uncovered pixels have no depth."""
    matrix = np.array([[1.0, 0.0, shift_px[0]], [0.0, 1.0, shift_px[1]]], np.float32)
    return cv2.warpAffine(
        depth,
        matrix,
        (depth.shape[1], depth.shape[0]),
        flags=cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )


def depth_noise(depth: np.ndarray, sigma_m_per_m2: float, rng: np.random.Generator) -> np.ndarray:
    """``depth`` with Gaussian noise of σ = ``sigma_m_per_m2`` · z² on every pixel that has a depth.

    Active stereo measures disparity d = f·b / z with a roughly constant sub-pixel error, so the depth error grows
    as z² · error / (f·b) (Intel's formula for the D400 series)."""
    valid = depth > 0
    noisy = depth + np.float32(sigma_m_per_m2) * depth * depth * rng.standard_normal(depth.shape, np.float32)
    return np.where(valid, np.maximum(noisy, 0.0), 0.0).astype(np.float32)


def jpeg_roundtrip(gray: np.ndarray, quality: int) -> np.ndarray:
    """``gray`` encoded as JPEG at ``quality`` (1–100) and decoded: blocking and ringing as a streaming camera's
    compression gives them. A :class:`SeesysError` if OpenCV cannot encode it."""
    ok, data = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise SeesysError(f"cannot JPEG-encode a {gray.shape} image at quality {quality}")
    decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if decoded is None:  # OpenCV's answer to data it cannot decode
        raise SeesysError(f"cannot decode the JPEG of a {gray.shape} image at quality {quality}")
    return decoded
