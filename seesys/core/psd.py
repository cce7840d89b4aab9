"""The point spatial distribution (PSD) matrix of paper §4.1.2: geometry, layers and encoding, in one place.

The expanded frustum covers ``expansion`` (K_p) times the image width and height, centred on the image, and is
cut into cells of ``patch_px`` (K_c) pixels: for a 640×480 frame, K_c = 10 and K_p = 2 give a 96×128 grid whose
central 48×64 block is the image itself. The matrix is (rows, cols, 3) uint8, zero where nothing falls, with the
layers (in the authors' memory order):

- :data:`KEYPOINT_LAYER`: the mean keypoint response of the cell's keypoints (FAST-circle contrast in gray
  levels, :func:`slam_monitor.image_features.keypoint_responses`), rounded, clipped to 1..255 (a cell with
  keypoints is never 0);
- :data:`INLIER_LAYER`: 255 where a keypoint matched to a map point (an inlier) lies;
- :data:`MAP_POINT_LAYER`: the monitor's local-map points in front of the camera that project into the expanded
  frustum, as inverse depth ``round(255 · near_depth / max(z, near_depth))``, at least 1; 255 at or nearer than
  ``near_depth``, halving with each doubling of depth; the nearest point of a cell wins. z is in map units (metres
  in RGB-D mode, the arbitrary monocular scale otherwise).

All three layers use the same undistorted pixel coordinates and the same cell arithmetic (the authors' inlier
layer uses distorted coordinates and a hard-coded divisor; see docs/rts-features.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KEYPOINT_LAYER = 0
INLIER_LAYER = 1
MAP_POINT_LAYER = 2
NUM_LAYERS = 3


@dataclass(frozen=True)
class PsdGeometry:
    """Cell arithmetic of the PSD for one image size."""

    width: int
    height: int
    patch_px: int
    expansion: int

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1 or self.patch_px < 1 or self.expansion < 1:
            raise ValueError(f"invalid PSD geometry {self}")

    @property
    def image_rows(self) -> int:
        return math.ceil(self.height / self.patch_px)

    @property
    def image_cols(self) -> int:
        return math.ceil(self.width / self.patch_px)

    @property
    def row_offset(self) -> int:
        """Grid row of the image's top cell row."""
        return self.image_rows * (self.expansion - 1) // 2

    @property
    def col_offset(self) -> int:
        """Grid column of the image's left cell column."""
        return self.image_cols * (self.expansion - 1) // 2

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.image_rows * self.expansion, self.image_cols * self.expansion, NUM_LAYERS

    def cells(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat cell index (row · cols + col) of each pixel position (N, 2), and which fall inside the grid (the
        index of a position outside, or not finite, is 0)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        rows, cols, _ = self.shape
        # Both coordinates at once and in floating point (exact for any grid index): comparisons with NaN are false,
        # so a non-finite position falls outside without a test of its own, and no NaN is cast to an integer.
        grid = np.floor(uv / self.patch_px)
        grid += (self.col_offset, self.row_offset)
        col, row = grid[:, 0], grid[:, 1]
        inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
        return np.where(inside, row * cols + col, 0).astype(np.int64), inside


def inverse_depth_code(z: np.ndarray, near_depth: float) -> np.ndarray:
    """The map-point layer's encoding of camera depth ``z`` (> 0): 255 at ``near_depth`` or nearer, then
    255·near/z, never below 1."""
    code = np.rint(255.0 * near_depth / np.maximum(z, near_depth))
    return np.clip(code, 1, 255).astype(np.uint8)


def build_psd(
    geometry: PsdGeometry,
    *,
    keypoints: np.ndarray,
    responses: np.ndarray,
    inliers: np.ndarray,
    map_points_uv: np.ndarray,
    map_points_depth: np.ndarray,
    near_depth: float,
) -> np.ndarray:
    """The PSD matrix of one frame.

    ``keypoints`` (N, 2) undistorted pixels with ``responses`` (N,) and the ``inliers`` mask (N,);
    ``map_points_uv`` (M, 2) projections of local-map points in front of the camera, with their camera depths
    ``map_points_depth`` (M,).
    """
    rows, cols, layers = geometry.shape
    psd = np.zeros((rows * cols, layers), dtype=np.uint8)

    cell, inside = geometry.cells(keypoints)
    cell, resp, inl = cell[inside], np.asarray(responses, dtype=np.float64)[inside], np.asarray(inliers)[inside]
    if len(cell):
        count = np.bincount(cell, minlength=rows * cols)
        total = np.bincount(cell, weights=resp, minlength=rows * cols)
        occupied = count > 0
        psd[occupied, KEYPOINT_LAYER] = np.clip(np.rint(total[occupied] / count[occupied]), 1, 255)
        psd[cell[inl], INLIER_LAYER] = 255

    cell, inside = geometry.cells(map_points_uv)
    if inside.any():
        layer = np.zeros(rows * cols, dtype=np.uint8)
        np.maximum.at(layer, cell[inside], inverse_depth_code(np.asarray(map_points_depth)[inside], near_depth))
        psd[:, MAP_POINT_LAYER] = layer
    return psd.reshape(rows, cols, layers)
