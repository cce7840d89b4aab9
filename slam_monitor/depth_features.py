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
- ``depth_registration``: how far depth discontinuities sit from the colour edges they coincide with in the
  scene, in focal lengths (pixels / f, i.e. radians), once the camera's motion is accounted for. Where neighbours of
  the subsampled grid differ in depth by more than ``edge_jump`` (relative) and the full-resolution depth row (or
  column) between them makes that change in one sharp step (at least ``edge_sharpness`` of it: noise on a far
  surface spreads its change over several pixels), the jump is placed there and the strongest gray-level step
  within ``search_px`` of it on the gray image (to a sub-pixel by a parabola); each crossing's signed offset is the
  depth edge's position minus the colour edge's. Two things move a depth edge off its colour edge: a
  misregistration (a calibration error, an unregistered depth camera: the same shift on every frame) and depth
  captured at another moment than colour (unsynchronised streams, a rolling colour shutter: a shift along the
  image motion, so it swings with every turn of the camera and cancels a misregistration on some frames). The
  channel separates them with a robust fit over the last ``registration_frames`` frames: offset = m_axis +
  flow · (a + b · row), with flow the crossing's image motion since the previous frame (px/frame, from the
  tracked relative pose and the crossing's depth), a the streams' time offset and b a rolling shutter's readout,
  both in frames; the channel is |m| over the focal lengths. Texture beside an edge scatters both ways and a Huber
  weight (``registration_huber_px``) keeps it from the fit; crossings moving faster than
  ``registration_max_flow_px`` are left out (their depth edge may lie beyond the colour edge search, and blur
  smears the colour edge). NaN until the window holds ``min_registration_crossings`` crossings along each axis
  on tracked frames.

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

from seesys.core.camera import Intrinsics
from slam_monitor.slam_features import project

# median(|x|) = 0.6745 σ for a normal x; a second difference of independent noise of σ has σ·√6.
_SECOND_DIFFERENCE_MAD = 0.6745 * np.sqrt(6.0)
# Added to the fit's time-offset terms (px², i.e. one crossing moving 1 px a frame): it keeps the system solvable
# while the camera holds still (no flow), where the offsets are the misregistration alone; any motion outweighs it.
_TIME_TERM_RIDGE = 1.0


@dataclass(frozen=True)
class DepthQualityConfig:
    """``[depth]`` of ``configs/monitor.toml``."""

    stride: int
    edge_jump: float
    edge_sharpness: float
    search_px: int
    max_edges: int
    registration_frames: int
    registration_huber_px: float
    registration_max_flow_px: float
    min_registration_crossings: int

    def __post_init__(self) -> None:
        if (
            min(self.stride, self.search_px, self.max_edges, self.registration_frames, self.min_registration_crossings)
            < 1
        ):
            raise ValueError(
                "stride, search_px, max_edges, registration_frames and min_registration_crossings must "
                f"be at least 1: {self}"
            )
        if not 0 < self.edge_jump < 1:
            raise ValueError(f"edge_jump is a relative depth jump in (0, 1): {self}")
        if not 0 <= self.edge_sharpness <= 1:
            raise ValueError(f"edge_sharpness is a share of a jump's depth change in [0, 1]: {self}")
        if not (self.registration_huber_px > 0 and self.registration_max_flow_px > 0):
            raise ValueError(f"registration_huber_px and registration_max_flow_px must be positive: {self}")


@dataclass(frozen=True)
class DepthFeatures:
    depth_holes: float
    depth_noise: float
    depth_registration: float

    @classmethod
    def absent(cls) -> DepthFeatures:
        """No depth image (monocular): every channel unknown."""
        nan = float("nan")
        return cls(nan, nan, nan)


@dataclass(frozen=True)
class EdgeCrossings:
    """The depth edges of one frame placed against their colour edges, one entry per crossing.

    ``offset_px``: depth edge minus colour edge along the crossing's axis (x for a crossing found along a row,
    y along a column); ``u``, ``v``: the depth edge's pixel position; ``z``: the nearer side's depth (m), the
    surface whose outline the edge is; ``along_y``: True for crossings found along a column."""

    offset_px: np.ndarray
    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    along_y: np.ndarray

    @classmethod
    def none(cls) -> EdgeCrossings:
        empty = np.zeros(0)
        return cls(empty, empty, empty, empty, np.zeros(0, dtype=bool))


def inverse_depth(depth: np.ndarray) -> np.ndarray:
    """1/z, NaN where there is no depth."""
    with np.errstate(divide="ignore", invalid="ignore"):
        w = 1.0 / depth.astype(np.float32, copy=False)
    w[~np.isfinite(w) | (w <= 0)] = np.nan
    return w


def hole_share(depth: np.ndarray) -> float:
    """``depth_holes``: the share of the pixels of a float32 depth image that are 0 (no depth)."""
    # Sources write 0 where there is no depth (Frame); counting non-zero pixels is the cheapest full-frame pass,
    # and counting them on the float32 image's bits (+0.0 is all zero bits) is 2-4 times faster than on floats.
    return 1.0 - cv2.countNonZero(depth.view(np.int32)) / depth.size


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
    # np.minimum / np.maximum: np.clip checks its bounds' types on every call, several times their cost here.
    a = np.where(inner, values[rows, np.maximum(k - 1, 0)], 0.0)
    b = values[rows, k]
    c = np.where(inner, values[rows, np.minimum(k + 1, values.shape[1] - 1)], 0.0)
    denominator = a - 2.0 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(inner & (denominator < 0), 0.5 * (a - c) / denominator, 0.0)
    return k + np.minimum(np.maximum(delta, -0.5), 0.5)


def _evenly(index: tuple[np.ndarray, ...], most: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``most`` of the (row, column) pairs, evenly over the image: the same ones for the same frame."""
    rows, cols = index
    if rows.size > most:
        keep = np.linspace(0, rows.size - 1, most).astype(np.intp)
        return rows[keep], cols[keep]
    return rows, cols


def edge_crossings(depth: np.ndarray, gray: np.ndarray, w_sub: np.ndarray, cfg: DepthQualityConfig) -> EdgeCrossings:
    """Each sharp depth jump between horizontal neighbours of ``w_sub`` (the inverse depth subsampled by
    ``cfg.stride``), placed along its full-resolution row, and each between vertical neighbours, along its column,
    with the strongest gray step near it.

    Each jump is a short line through the full-resolution images, handled in one pass through flat indices: the
    largest depth step between the two subsampled pixels is the depth edge, at its middle, kept only where it makes
    ``cfg.edge_sharpness`` of the line's whole change; the largest gray-level step within ``search_px`` of it is the
    colour edge."""
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
        return EdgeCrossings.none()
    # Per line: where the subsampled pair starts along it, its flat offset across, one pixel's flat step, its length.
    start = first + np.concatenate([cols_x, rows_y]) * s
    fixed = np.concatenate([first + rows_x * s, first + cols_y * s])  # the row (column) the line runs along
    across = np.concatenate([fixed[:n_x] * width, fixed[n_x:]])
    step = np.concatenate([np.ones(n_x, np.intp), np.full(rows_y.size, width, np.intp)])[:, None]
    last = np.concatenate([np.full(n_x, width - 1), np.full(rows_y.size, height - 1)])[:, None]
    flat_depth, flat_gray = depth.ravel(), gray.ravel()
    segment = flat_depth[across[:, None] + np.minimum(start[:, None] + np.arange(s + 1), last) * step]
    steps = np.abs(np.diff(segment, axis=1))
    steps[(segment[:, :-1] <= 0) | (segment[:, 1:] <= 0)] = 0.0  # a hole is not an edge position
    k = np.argmax(steps, axis=1)
    jump = steps[np.arange(k.size), k]
    # Only sharp jumps go on to the colour search.
    sharp = np.flatnonzero((jump > 0) & (jump >= cfg.edge_sharpness * np.abs(segment[:, -1] - segment[:, 0])))
    k, start, across, fixed, step, last = k[sharp], start[sharp], across[sharp], fixed[sharp], step[sharp], last[sharp]
    near = np.minimum(segment[sharp, k], segment[sharp, k + 1])
    at_depth = start + k + 0.5
    base = np.floor(at_depth).astype(np.intp)
    around = base[:, None] + np.arange(-r, r + 1)
    inside = (around >= 0) & (around < last)
    index = across[:, None] + np.minimum(np.maximum(around, 0), last - 1) * step
    strength = np.where(inside, np.abs(flat_gray[index + step].astype(np.float32) - flat_gray[index]), 0.0)
    offsets = at_depth - (base - r + _peak(strength) + 0.5)
    along_y = sharp >= n_x
    u = np.where(along_y, fixed, at_depth)
    v = np.where(along_y, at_depth, fixed)
    return EdgeCrossings(offsets, u, v, near.astype(np.float64), along_y)


def image_motion_px(crossings: EdgeCrossings, intrinsics: Intrinsics, previous_from_current: np.ndarray) -> np.ndarray:
    """Each crossing's image motion since the previous frame along its axis (px/frame): its point (pixel and
    depth) moved into the previous camera by ``previous_from_current`` (4×4, T_prev_cur = T_w_prev⁻¹ · T_w_cur)
    and projected there."""
    k = intrinsics
    points = np.stack(
        [(crossings.u - k.cx) / k.fx * crossings.z, (crossings.v - k.cy) / k.fy * crossings.z, crossings.z]
    )
    before = (previous_from_current[:3, :3] @ points + previous_from_current[:3, 3:4]).T
    with np.errstate(divide="ignore", invalid="ignore"):  # a point behind the previous camera: NaN below
        uv_before = project(before, k.matrix())
    motion = np.where(crossings.along_y, crossings.v - uv_before[:, 1], crossings.u - uv_before[:, 0])
    return np.where(before[:, 2] > 0, motion, np.nan)


class RegistrationFit:
    """The robust fit behind ``depth_registration`` over the last ``registration_frames`` frames (see the module
    docstring): offset = m_x · [along x] + m_y · [along y] + flow · (a + b · (row / height − ½)).

    Each frame adds its crossings' normal equations, weighted by a Huber weight of their residuals to the fit so
    far, so a frame costs one pass over its own crossings, a sum of the window's 4×4 matrices and a 4×4 solve."""

    def __init__(self, cfg: DepthQualityConfig) -> None:
        self._cfg = cfg
        # Per frame of the window (a ring, slot = frame count mod window): its normal equations and its crossings
        # along x and along y.
        self._normal = np.zeros((cfg.registration_frames, 4, 4))
        self._rhs = np.zeros((cfg.registration_frames, 4))
        self._counts = np.zeros((cfg.registration_frames, 2), dtype=np.int64)
        self._slot = 0
        self._params = np.zeros(4)

    def update(self, crossings: EdgeCrossings, motion_px: np.ndarray | None, height: int) -> tuple[float, float]:
        """Add one frame (``motion_px`` None: no tracked pose, the frame adds nothing but still counts in the
        window) and return the misregistration (m_x, m_y) in pixels, NaN while the window holds too few crossings
        along either axis."""
        slot = self._slot
        self._slot = (slot + 1) % self._cfg.registration_frames
        self._normal[slot], self._rhs[slot], self._counts[slot] = 0.0, 0.0, 0
        if motion_px is not None and crossings.offset_px.size:
            # A crossing moving fast may have its colour edge outside the search (and blurred): left out.
            known = np.abs(motion_px) <= self._cfg.registration_max_flow_px
            along_y, flow = crossings.along_y[known], motion_px[known]
            design = np.empty((flow.size, 4))
            design[:, 0], design[:, 1], design[:, 2] = ~along_y, along_y, flow
            np.multiply(flow, crossings.v[known] / height - 0.5, out=design[:, 3])
            offsets = crossings.offset_px[known]
            # Huber: weight 1 within registration_huber_px of the fit so far, falling as 1/residual beyond.
            huber = self._cfg.registration_huber_px
            weighted = design.T * (huber / np.maximum(np.abs(offsets - design @ self._params), huber))
            self._normal[slot], self._rhs[slot] = weighted @ design, weighted @ offsets
            along = int(np.count_nonzero(along_y))
            self._counts[slot] = (along_y.size - along, along)
        if (self._counts.sum(axis=0) < self._cfg.min_registration_crossings).any():
            return float("nan"), float("nan")
        normal = self._normal.sum(axis=0)
        normal[2:, 2:] += _TIME_TERM_RIDGE * np.eye(2)
        self._params = np.linalg.solve(normal, self._rhs.sum(axis=0))
        return float(self._params[0]), float(self._params[1])


class DepthQuality:
    """The depth-quality channels of one session's frames, in frame order (``depth_registration`` fits over the
    recent frames: one instance per session)."""

    def __init__(self, cfg: DepthQualityConfig) -> None:
        self._cfg = cfg
        self._registration = RegistrationFit(cfg)

    def frame(
        self,
        depth: np.ndarray | None,
        gray: np.ndarray,
        intrinsics: Intrinsics,
        previous_from_current: np.ndarray | None,
    ) -> DepthFeatures:
        """The channels of one frame.

        ``depth``: (H, W) float32 metres aligned to ``gray`` (0 = unknown), or None (monocular: all NaN);
        ``previous_from_current``: the tracked motion since the previous frame (4×4 T_prev_cur), None when either
        frame has no tracked pose. Raises ValueError when ``depth`` is not the shape of ``gray``."""
        if depth is None:
            return DepthFeatures.absent()
        if depth.shape != gray.shape:
            raise ValueError(f"depth {depth.shape} is not aligned to the gray frame {gray.shape}")
        s = self._cfg.stride
        w_sub = inverse_depth(depth[s // 2 :: s, s // 2 :: s])
        holes = hole_share(depth)
        noise = noise_over_z2(w_sub, self._cfg.edge_jump)
        crossings = edge_crossings(depth, gray, w_sub, self._cfg)
        motion = (
            image_motion_px(crossings, intrinsics, previous_from_current) if previous_from_current is not None else None
        )
        m_x, m_y = self._registration.update(crossings, motion, depth.shape[0])
        return DepthFeatures(holes, noise, float(np.hypot(m_x / intrinsics.fx, m_y / intrinsics.fy)))
