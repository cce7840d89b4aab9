"""What a structured-light depth camera (Kinect v1 class) does to the exact depth of a render.

The camera finds the disparity d = f·b / z of its projector's dot pattern, b being the projector-camera baseline:

- **Disparity quantisation**: d is measured in steps of q px (1/8 on the Kinect v1), so 1/z comes in steps of
  q / (f·b) and the depth step grows as z² · q / (f·b).
- **Projector shadow**: beside a depth jump, on the side away from the projector, the background is hidden from
  the projector by the foreground: no pattern, no depth. The band is f·b·(1/z_near − 1/z_far) px wide.
- **Dark surfaces**: a surface that reflects too little of the pattern gives no depth.
- **Range limit**: nothing is measured nearer or farther than the sensor's range.

Pixels without a measurement read 0, as in the depth PNG.
"""

from __future__ import annotations

import numpy as np

from synth.config import CameraModel
from synth.renderer import Render


def quantise_inverse_depth(depth: np.ndarray, step_per_m: float) -> np.ndarray:
    """``depth`` with 1/z rounded to a multiple of ``step_per_m`` (1/m), i.e. the disparity to its step;
    pixels without depth stay 0."""
    valid = depth > 0
    with np.errstate(divide="ignore"):
        steps = np.maximum(np.rint(np.float32(1.0) / depth / np.float32(step_per_m)), 1.0)
    return np.where(valid, np.float32(1.0) / (steps * np.float32(step_per_m)), 0.0).astype(np.float32)


def projector_shadow(depth: np.ndarray, fx: float, projector_x_m: float) -> np.ndarray:
    """The pixels of ``depth`` that a projector at ``projector_x_m`` along the camera's x axis does not light.

    A pixel u at depth z is lit from the projector's image column u_p = u − fx·b / z (b = ``projector_x_m``; the
    projector's columns share the camera's rows and, for this comparison, its principal point). Along a row,
    scanning from the projector's side, a pixel whose u_p is not beyond every u_p already seen is behind a nearer
    surface as the projector sees it: in its shadow. Pixels without depth cast no shadow."""
    flip = projector_x_m < 0  # a projector on the left is the mirror image of one on the right
    z = depth[:, ::-1] if flip else depth
    u = np.arange(z.shape[1], dtype=np.float32)
    with np.errstate(divide="ignore"):
        projected = np.where(z > 0, u - np.float32(fx * abs(projector_x_m)) / z, np.inf).astype(np.float32)
    # The least projector column of the pixels right of each pixel (scanning from the projector on the right).
    right = np.full_like(projected, np.inf)
    right[:, :-1] = np.minimum.accumulate(projected[:, :0:-1], axis=1)[:, ::-1]
    shadow = (z > 0) & (projected >= right)
    return shadow[:, ::-1] if flip else shadow


def outside_range(depth: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """The pixels whose depth the sensor cannot measure: nearer than ``near_m`` or farther than ``far_m``
    (0: no limit on that side)."""
    mask = np.zeros(depth.shape, bool)
    if near_m > 0:
        mask |= depth < near_m
    if far_m > 0:
        mask |= depth > far_m
    return mask


def without_unlit(view: Render, fx: float, model: CameraModel) -> np.ndarray:
    """The depth of ``view`` with no measurement where the pattern does not come back: in the projector's shadow
    (``projector_offset_m``) and on surfaces darker than ``dark_albedo``."""
    unlit = view.albedo < np.float32(model.dark_albedo)
    if model.projector_offset_m != 0:
        unlit |= projector_shadow(view.depth, fx, model.projector_offset_m)
    return np.where(unlit, np.float32(0.0), view.depth)


def as_measured(depth: np.ndarray, model: CameraModel) -> np.ndarray:
    """``depth`` as the sensor reads it out: the disparity quantised to ``disparity_step_px`` at the sensor's own
    focal length and baseline, and nothing outside [``depth_min_m``, ``depth_max_m``]."""
    if model.disparity_step_px > 0:
        step = model.disparity_step_px / (model.disparity_focal_px * abs(model.projector_offset_m))
        depth = quantise_inverse_depth(depth, step)
    return np.where(outside_range(depth, model.depth_min_m, model.depth_max_m), np.float32(0.0), depth)
