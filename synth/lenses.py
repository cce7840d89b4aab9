"""The lens a camera model's images are rendered through, and the intrinsics ``calibration.yaml`` tells SLAM.

A real camera's calibration is never exactly its lens: the focal length and the principal point are a little off,
and a radial distortion may be left uncorrected. The images are rendered through the true lens; the calibration
says the told one, as a user's calibration file would.
"""

from __future__ import annotations

import dataclasses
import math

from seesys.core.camera import Intrinsics
from synth.config import CameraConfig, CameraModel


def model_camera(camera: CameraConfig, model: CameraModel) -> CameraConfig:
    """``camera`` with the model's own sensor (``resolution_px``) and horizontal field of view
    (``horizontal_fov_deg``), each as ``[camera.lens]`` has it where the model leaves it at 0.

    A model that sets either gets fx = (width / 2) / tan(fov / 2), the lens's pixel aspect fy / fx and the
    principal point in the middle of its sensor; the lens's distortion coefficients (normalised) are kept."""
    if not model.own_sensor:
        return camera
    lens = camera.lens
    width, height = model.resolution_px if any(model.resolution_px) else (lens.width, lens.height)
    fov = (
        math.radians(model.horizontal_fov_deg) if model.horizontal_fov_deg else 2 * math.atan(lens.width / 2 / lens.fx)
    )
    fx = width / 2 / math.tan(fov / 2)
    return dataclasses.replace(
        camera,
        lens=dataclasses.replace(
            lens, width=width, height=height, fx=fx, fy=fx * lens.fy / lens.fx, cx=(width - 1) / 2, cy=(height - 1) / 2
        ),
    )


def true_lens(lens: Intrinsics, model: CameraModel, distorted: bool) -> Intrinsics:
    """The lens the images are seen through: ``lens`` with its distortion when the render applies it
    (``distorted``), plus the model's uncorrected radial distortion ``radial_k1``."""
    base = lens if distorted else lens.without_distortion()
    k1, k2, p1, p2, k3 = base.distortion
    return dataclasses.replace(base, distortion=(k1 + model.radial_k1, k2, p1, p2, k3))


def told_lens(lens: Intrinsics, model: CameraModel, distorted: bool, native_width: int) -> Intrinsics:
    """The intrinsics SLAM is told for images rendered through ``lens``: the focal lengths times
    (1 + ``told_focal_error``), the principal point moved by ``told_principal_point_px`` and the distortion the
    render applies (``distorted``) without the model's ``radial_k1``.

    The principal point error is in pixels of the camera's own sensor (``native_width`` wide) and scales with the
    rendered size, as the lens itself does."""
    base = lens if distorted else lens.without_distortion()
    scale = lens.width / native_width
    dx, dy = model.told_principal_point_px
    return dataclasses.replace(
        base,
        fx=base.fx * (1 + model.told_focal_error),
        fy=base.fy * (1 + model.told_focal_error),
        cx=base.cx + dx * scale,
        cy=base.cy + dy * scale,
    )
