"""Depth-quality RTS channels of an RGB-D frame: the depth camera's faults, measured on the device without ground truth.

The colour and tracking channels cannot tell an ideal depth camera from a noisy, misregistered one (a wrongly
scaled or noisy RGB-D world is self-consistent to the tracker), yet those faults multiply the pose error. These
channels look at the depth image itself. None needs ground truth, and each is normalised so that it describes the
sensor, not the room or the lens. The last two are computed on the depth image subsampled by ``stride`` (the
middle pixel of each stride × stride cell: nothing is interpolated across an edge) and, where an edge must be
placed to the pixel, on short full-resolution segments around the edges found there:

- ``depth_holes``: the share of the pixels with no depth (0, as every source writes it): structured-light shadows,
  dark or shiny surfaces, out of range, the border a misregistration uncovers.
- ``depth_noise``: the depth noise σ_z divided by z², in 1/m. Inverse depth w = 1/z is affine in the pixel
  coordinates on a plane, so its second difference along a row is 0 there; depth noise σ_z becomes
  w noise σ_z / z², and a second difference of independent noise has σ·√6. The channel is
  median(|Δ²w|) / (0.6745·√6) over every three valid neighbours along the rows of the subsampled grid,
  leaving out those that span a depth edge (|Δ²w| above ``edge_jump`` of w); curved surfaces, a minority, do not
  move a median. Active-stereo noise (σ_z ∝ z²) gives the same value at every distance; disparity quantisation
  (steps constant in disparity, so in w) shows here too.
- ``depth_edge_offset``: how far depth discontinuities sit from the colour edges they coincide with in the
  scene, in focal lengths (pixels / f, i.e. radians). Where neighbours of the subsampled grid differ in depth by
  more than ``edge_jump`` (relative), the jump is placed on the full-resolution depth row (or column) and the
  strongest gray-level step within ``search_px`` of it on the gray image (to a sub-pixel by a parabola); the
  channel is the length of the median signed offset (median along x over row crossings, along y over column
  crossings, divided by fx and fy). A misregistration, an unregistered depth camera or depth captured later than
  colour moves every depth edge the same way; texture beside an edge scatters both ways and cancels in the
  median. NaN with fewer than ``min_edges`` crossings.

In monocular mode there is no depth image and every channel is NaN.

ORB-SLAM3 does not say (through pyorbslam3) which map points it made from depth and which it triangulated, so the
share of map points whose depth disagrees with the depth image is not a channel: measured on renders, matched map
points disagree with an exact depth image (by more than 0.005 z²) about as often as with a D435-like one, near
points alone included; the tracker's own triangulation and bundle adjustment, not the sensor, decide it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# median(|x|) = 0.6745 σ for a normal x; a second difference of independent noise of σ has σ·√6.
_SECOND_DIFFERENCE_MAD = 0.6745 * np.sqrt(6.0)


@dataclass(frozen=True)
class DepthQualityConfig:
    """``[depth]`` of ``configs/monitor.toml``."""

    stride: int
    edge_jump: float
    search_px: int
    max_edges: int
    min_edges: int

    def __post_init__(self) -> None:
        if self.stride < 1 or self.search_px < 1 or self.max_edges < 1 or self.min_edges < 1:
            raise ValueError(f"stride, search_px, max_edges and min_edges must be at least 1: {self}")
        if not 0 < self.edge_jump < 1:
            raise ValueError(f"edge_jump is a relative depth jump in (0, 1): {self}")


@dataclass(frozen=True)
class DepthFeatures:
    depth_holes: float
    depth_noise: float
    depth_edge_offset: float

    @classmethod
    def absent(cls) -> DepthFeatures:
        """No depth image (monocular): every channel unknown."""
        nan = float("nan")
        return cls(nan, nan, nan)


def _inverse_depth(depth: np.ndarray) -> np.ndarray:
    """1/z, NaN where there is no depth."""
    with np.errstate(divide="ignore", invalid="ignore"):
        w = 1.0 / depth.astype(np.float32, copy=False)
    w[~np.isfinite(w) | (w <= 0)] = np.nan
    return w


def noise_over_z2(w: np.ndarray, edge_jump: float) -> float:
    """σ_z / z² (1/m) from the second differences of inverse depth ``w`` (NaN: no depth) along its rows; a second
    difference above ``edge_jump`` of its middle value spans a depth edge and is left out (edges, a tenth of the
    triples in a cluttered room, would otherwise lift the median by about as much). Rows alone: the noise of a
    depth sensor is the same along both axes, and one axis costs half."""
    d2 = np.abs(w[:, :-2] - 2.0 * w[:, 1:-1] + w[:, 2:])
    with np.errstate(invalid="ignore"):
        d2 = d2[d2 <= edge_jump * w[:, 1:-1]]
    return float(np.median(d2) / _SECOND_DIFFERENCE_MAD) if d2.size else float("nan")


def _peak(values: np.ndarray) -> np.ndarray:
    """Sub-pixel position of each row's maximum (a parabola through it and its neighbours)."""
    k = np.argmax(values, axis=1)
    rows = np.arange(len(values))
    inner = (k > 0) & (k < values.shape[1] - 1)
    a = np.where(inner, values[rows, np.clip(k - 1, 0, None)], 0.0)
    b = values[rows, k]
    c = np.where(inner, values[rows, np.clip(k + 1, None, values.shape[1] - 1)], 0.0)
    denominator = a - 2.0 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(inner & (denominator < 0), 0.5 * (a - c) / denominator, 0.0)
    return k + np.clip(delta, -0.5, 0.5)


def _evenly(index: tuple[np.ndarray, np.ndarray], most: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``most`` of the (row, column) pairs, evenly over the image: the same ones for the same frame."""
    rows, cols = index
    if rows.size > most:
        keep = np.linspace(0, rows.size - 1, most).astype(np.intp)
        return rows[keep], cols[keep]
    return rows, cols


def edge_offsets(depth: np.ndarray, gray: np.ndarray, w_sub: np.ndarray,
                 cfg: DepthQualityConfig) -> tuple[np.ndarray, np.ndarray]:
    """Signed offsets, in pixels, from each depth jump to the strongest gray step near it: of the jumps between
    horizontal neighbours of ``w_sub`` (the inverse depth subsampled by ``cfg.stride``) along the rows, and of those
    between vertical neighbours along the columns; positive = the depth edge lies right of (below) the colour edge.

    Each jump is a short line through the full-resolution images (a row or a column), handled in one pass through
    flat indices: the largest depth step between the two subsampled pixels is the depth edge, at its middle; the
    largest gray-level step within ``search_px`` of it is the colour edge."""
    s, r = cfg.stride, cfg.search_px
    height, width = depth.shape
    first = s // 2  # the subsampled grid's first full-resolution pixel
    with np.errstate(invalid="ignore"):
        across_x = np.abs(w_sub[:, 1:] - w_sub[:, :-1]) > cfg.edge_jump * np.fmax(w_sub[:, 1:], w_sub[:, :-1])
        across_y = np.abs(w_sub[1:, :] - w_sub[:-1, :]) > cfg.edge_jump * np.fmax(w_sub[1:, :], w_sub[:-1, :])
    rows_x, cols_x = _evenly(np.nonzero(across_x), cfg.max_edges)
    rows_y, cols_y = _evenly(np.nonzero(across_y), cfg.max_edges)
    n_x = rows_x.size
    if n_x + rows_y.size == 0:
        return np.zeros(0), np.zeros(0)
    # Per line: where the subsampled pair starts along it, its flat offset across, one pixel's flat step, its length.
    start = first + np.concatenate([cols_x, rows_y]) * s
    across = np.concatenate([(first + rows_x * s) * width, first + cols_y * s])
    step = np.concatenate([np.ones(n_x, np.intp), np.full(rows_y.size, width, np.intp)])[:, None]
    last = np.concatenate([np.full(n_x, width - 1), np.full(rows_y.size, height - 1)])[:, None]
    flat_depth, flat_gray = depth.ravel(), gray.ravel()
    segment = flat_depth[across[:, None] + np.minimum(start[:, None] + np.arange(s + 1), last) * step]
    steps = np.abs(np.diff(segment, axis=1))
    steps[(segment[:, :-1] <= 0) | (segment[:, 1:] <= 0)] = 0.0  # a hole is not an edge position
    at_depth = start + np.argmax(steps, axis=1) + 0.5
    base = np.floor(at_depth).astype(np.intp)
    around = base[:, None] + np.arange(-r, r + 1)
    inside = (around >= 0) & (around < last)
    index = across[:, None] + np.clip(around, 0, last - 1) * step
    strength = np.where(inside, np.abs(flat_gray[index + step].astype(np.float32) - flat_gray[index]), 0.0)
    offsets = at_depth - (base - r + _peak(strength) + 0.5)
    return offsets[:n_x], offsets[n_x:]


def depth_features(depth: np.ndarray | None, gray: np.ndarray, fx: float, fy: float,
                   cfg: DepthQualityConfig) -> DepthFeatures:
    """The depth-quality channels of one frame.

    ``depth``: (H, W) float32 metres aligned to ``gray`` (0 = unknown), or None (monocular: all NaN)."""
    if depth is None:
        return DepthFeatures.absent()
    if depth.shape != gray.shape:
        raise ValueError(f"depth {depth.shape} is not aligned to the gray frame {gray.shape}")
    s = cfg.stride
    w_sub = _inverse_depth(depth[s // 2::s, s // 2::s])
    # Sources write 0 where there is no depth (Frame); counting non-zero pixels is the cheapest full-frame pass.
    holes = 1.0 - cv2.countNonZero(depth) / depth.size
    noise = noise_over_z2(w_sub, cfg.edge_jump)
    along_x, along_y = edge_offsets(depth, gray, w_sub, cfg)
    if along_x.size + along_y.size < cfg.min_edges:
        edge_offset = float("nan")
    else:
        mx = float(np.median(along_x)) / fx if along_x.size else 0.0
        my = float(np.median(along_y)) / fy if along_y.size else 0.0
        edge_offset = float(np.hypot(mx, my))
    return DepthFeatures(holes, noise, edge_offset)
