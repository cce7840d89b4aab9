"""Camera normalisation: the device's inputs measured as a reference camera would measure them, so that a model
trained on one camera reads the same numbers from another camera of the same field of view.

The reference camera (``[reference_camera]`` of configs/monitor.toml: the renderer's ideal 640×480 camera, fx = fy =
525) fixes what one pixel means. For a camera of intrinsics K, the monitor

- places keypoints and map points on the PSD grid by their direction, not their pixel: a position (u, v) of the
  camera is the reference camera's ``(u − cx)·fx_ref/fx + cx_ref`` (likewise v), and the grid is the reference
  camera's (``patch_px`` reference pixels a cell), so every camera gives the same grid, cells of the same angle;
- divides pixel-valued channels (``local_mapping_visual_error``) by :attr:`CameraNormalisation.pixel_ratio`, the
  camera's focal length over the reference's;
- computes the image statistics whose value depends on the pixel size (the Laplacian variance, the keypoint
  responses of the PSD's keypoint layer) on the image resampled to the reference camera's pixel size
  (:meth:`CameraNormalisation.resampled_size`).

For the reference camera itself every mapping is the identity and nothing is resampled, so its inputs are those
of the monitor before camera normalisation to the bit: models trained on it stay valid.

:data:`VERSION` names this definition. Every device states it with its settings
(:class:`~seesys.core.device_settings.DeviceSettings`), every model records the version and the reference camera
it was trained with, and a model refuses inputs made under another version; version 0 is the monitor before camera
normalisation (raw camera pixels, the PSD grid of the camera's resolution).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seesys.core.camera import Intrinsics
from seesys.core.errors import SeesysError

#: The camera normalisation the monitor applies (see the module's docstring); 0: none (inputs made before it).
VERSION = 1
#: The version of inputs made before camera normalisation existed (their logs and datasets state none).
BEFORE_NORMALISATION = 0


@dataclass(frozen=True)
class ReferenceCamera:
    """The pinhole camera whose pixels the normalised inputs are measured in (``[reference_camera]`` of
    configs/monitor.toml)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1 or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"invalid reference camera {self}: the size and focal lengths must be positive")


@dataclass(frozen=True)
class CameraNormalisation:
    """How the pixels of ``camera`` (undistorted coordinates) map to the ``reference`` camera's."""

    reference: ReferenceCamera
    camera: Intrinsics

    @property
    def identity(self) -> bool:
        """True where the camera has the reference's focal lengths and principal point: nothing is mapped or
        resampled, so the inputs are bit for bit those of the monitor before camera normalisation."""
        r, c = self.reference, self.camera
        return (c.fx, c.fy, c.cx, c.cy) == (r.fx, r.fy, r.cx, r.cy)

    @property
    def pixel_ratio(self) -> float:
        """The camera's focal length over the reference's (geometric means of fx and fy): how many of the camera's
        pixels one reference pixel spans. A length in camera pixels divided by it is in reference pixels; exactly
        1.0 for a camera of the reference's focal lengths."""
        return math.sqrt(self.camera.fx * self.camera.fy) / math.sqrt(self.reference.fx * self.reference.fy)

    def reference_px(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted camera pixel positions (N, 2) as the reference camera's positions of the same directions."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.identity:
            return uv
        r, c = self.reference, self.camera
        return (uv - (c.cx, c.cy)) * (r.fx / c.fx, r.fy / c.fy) + (r.cx, r.cy)

    def resampled_size(self) -> tuple[int, int]:
        """(width, height) of the camera's image resampled to the reference camera's pixel size."""
        c = self.camera
        return (max(1, round(c.width * self.reference.fx / c.fx)), max(1, round(c.height * self.reference.fy / c.fy)))

    def resampled_px(self, uv: np.ndarray) -> np.ndarray:
        """Camera pixel positions (N, 2) as positions in the resampled image (:meth:`resampled_size`; pixel centres
        at integer coordinates, so the scaling is about the image corner −0.5)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.identity:
            return uv
        width, height = self.resampled_size()
        return (uv + 0.5) * (width / self.camera.width, height / self.camera.height) - 0.5


class CameraNormalisationMismatch(SeesysError):
    """Inputs made under another camera normalisation version than a model's."""


def check_version(model_version: int, inputs_version: int, source: str) -> None:
    """Raise :class:`CameraNormalisationMismatch` naming ``source`` and both versions unless they are equal."""
    if model_version != inputs_version:
        raise CameraNormalisationMismatch(
            f"{source}: made under camera normalisation v{inputs_version}, the model takes "
            f"v{model_version}: its pixel-valued channels, image statistics and PSD grid mean other numbers; "
            f"record it again with this SEESys, or use a model of v{inputs_version}"
        )
