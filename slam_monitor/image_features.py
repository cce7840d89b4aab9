"""Sensor-input RTS channels of the gray frame SLAM tracked, and the keypoint response used by the PSD.

The first three channels are computed on the full-resolution 8-bit gray frame handed to ORB-SLAM3 (the authors
downscale by 0.2 first and apply CLAHE in their dataset runner; see docs/rts-features.md); they are shares of the
image and do not depend on its resolution:

- brightness = mean gray level / 255;
- contrast   = population standard deviation of the gray level / 255 (RMS contrast);
- entropy    = Shannon entropy, in bits, of the 256-bin gray-level histogram.

The Laplacian and the keypoint responses measure detail per pixel, so they are computed on the frame resampled to
the reference camera's pixel size (:func:`reference_scale`; camera normalisation,
:mod:`seesys.core.camera_normalisation`); for the reference camera that is the frame itself:

- laplacian  = variance of the 3×3 Laplacian ``[[0,1,0],[1,-4,1],[0,1,0]]`` of the 8-bit frame at the reference
  scale, borders reflected without repeating the edge pixel (OpenCV's default), in (gray level)².
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seesys.core.camera_normalisation import CameraNormalisation

#: The 16 pixels of the radius-3 Bresenham circle FAST (and ORB) tests around a corner candidate, as (dx, dy).
FAST_CIRCLE: np.ndarray = np.array(
    [
        (0, -3),
        (1, -3),
        (2, -2),
        (3, -1),
        (3, 0),
        (3, 1),
        (2, 2),
        (1, 3),
        (0, 3),
        (-1, 3),
        (-2, 2),
        (-3, 1),
        (-3, 0),
        (-3, -1),
        (-2, -2),
        (-1, -3),
    ],
    dtype=np.intp,
)
_RADIUS = 3


@dataclass(frozen=True)
class ImageFeatures:
    brightness: float
    contrast: float
    entropy: float
    laplacian: float


def _check_gray(gray: np.ndarray) -> None:
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) uint8 gray frame, got {gray.dtype} {gray.shape}")


def reference_scale(gray: np.ndarray, normalisation: CameraNormalisation) -> np.ndarray:
    """The gray frame resampled to the reference camera's pixel size: area-averaged when the camera's pixels are
    finer (each reference pixel the mean of the camera pixels it covers, as a coarser sensor integrates them),
    bilinear when they are coarser (no detail is invented). The frame itself for a camera of the reference's focal
    lengths."""
    _check_gray(gray)
    if normalisation.identity:
        return gray
    size = normalisation.resampled_size()
    finer = size[0] * size[1] < gray.shape[0] * gray.shape[1]
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA if finer else cv2.INTER_LINEAR)


def intensity_statistics(gray: np.ndarray) -> tuple[float, float, float]:
    """Brightness, contrast and entropy of a gray frame (see the module docstring). Raises ValueError for a frame
    that is not (H, W) uint8."""
    _check_gray(gray)
    mean, std = cv2.meanStdDev(gray)
    hist = cv2.calcHist([gray], [0], None, [256], [0, 256]).ravel()
    p = hist[hist > 0] / gray.size
    return float(mean[0, 0]) / 255.0, float(std[0, 0]) / 255.0, float(-(p * np.log2(p)).sum())


def laplacian_variance(reference_gray: np.ndarray) -> float:
    """The ``laplacian`` channel of a gray frame at the reference scale (:func:`reference_scale`). Raises
    ValueError for a frame that is not (H, W) uint8."""
    _check_gray(reference_gray)
    # int16 holds the 3x3 Laplacian of 8-bit values exactly (|value| <= 4 * 255) and is faster than float32. Its
    # sum and sum of squares (exact in float64: at most 1020² per pixel) give the variance; cv2.meanStdDev on int16
    # took twice as long as the Laplacian itself.
    laplacian = cv2.Laplacian(reference_gray, cv2.CV_16S, ksize=1)
    mean = cv2.sumElems(laplacian)[0] / laplacian.size
    return cv2.norm(laplacian, cv2.NORM_L2SQR) / laplacian.size - mean * mean


def image_features(gray: np.ndarray, reference_gray: np.ndarray | None = None) -> ImageFeatures:
    """The four sensor-input channels of one gray frame; ``reference_gray``: the frame at the reference scale
    (:func:`reference_scale`), by default the frame itself (a frame of the reference camera)."""
    brightness, contrast, entropy = intensity_statistics(gray)
    laplacian = laplacian_variance(gray if reference_gray is None else reference_gray)
    return ImageFeatures(brightness=brightness, contrast=contrast, entropy=entropy, laplacian=laplacian)


def keypoint_responses(gray: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """FAST-circle contrast of each keypoint: mean |I(circle pixel) − I(centre)| over the 16 FAST circle pixels.

    pyorbslam3 does not expose ORB-SLAM3's keypoint responses, so they are recomputed from the image at the
    keypoint positions (rounded to the nearest pixel, edge pixels replicated). The monitor passes the frame at the
    reference scale and the keypoints as positions in it, so that the circle spans the same angle on any camera. The
    value is in gray levels (0–255), like the FAST scores ORB-SLAM3 stores, and higher means a more distinctive corner.
    """
    _check_gray(gray)
    kp = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    if kp.size == 0:
        return np.zeros(0, dtype=np.float32)
    h, w = gray.shape
    x = np.clip(np.rint(kp[:, 0]).astype(np.intp), 0, w - 1)
    y = np.clip(np.rint(kp[:, 1]).astype(np.intp), 0, h - 1)
    padded = cv2.copyMakeBorder(gray, _RADIUS, _RADIUS, _RADIUS, _RADIUS, cv2.BORDER_REPLICATE)
    centre = padded[y + _RADIUS, x + _RADIUS].astype(np.int16)
    ring = padded[y[:, None] + _RADIUS + FAST_CIRCLE[:, 1], x[:, None] + _RADIUS + FAST_CIRCLE[:, 0]]
    return np.abs(ring.astype(np.int16) - centre[:, None]).mean(axis=1).astype(np.float32)
