"""What the geometry of a tracked frame says about the precision of its pose: pose observability and residuals.

From the frame's matched inlier map points in the camera (``points_c``, metres), the keypoints they matched (pixels,
paired by ``slam_monitor.slam_features``) and, in RGB-D, the depth the camera measured at those keypoints:

- **The pose-only information matrix** H = Σᵢ Jᵢᵀ Σᵢ⁻¹ Jᵢ of the reprojection residuals (and, in RGB-D, of the depth
  residuals), with the pose perturbed as the camera moves: its position by δc in the camera's axes and its rotation
  by δθ, so that a point moves by ∂p/∂(δc, δθ) = [−I | [p]×] in the camera. H⁻¹ is the Cramér–Rao bound of the
  pose fit ORB-SLAM3 does on these points (its pose-only optimisation, before its robust weights).
- **Predicted translation σ** (metres): sqrt of the trace of the translation block of H⁻¹, the camera position's
  standard deviation summed over the three axes.
- **Translation information after the rotation is marginalised out** (the inverse of that block, the Schur
  complement): its smallest eigenvalue (1/m², the weakest direction: a degeneracy, Zhang et al., ICRA 2016) and its
  condition number (largest over smallest: a planar or one-sided point set gives a large one).
- **Coverage**: the share of the cells of a ``coverage_grid`` × ``coverage_grid`` grid over the image that hold an
  inlier keypoint, and the spread of the inliers' depths (the 10–90 % range over the median).
- **Residuals** after the pose: the distances of each matched point's projection to its keypoint (px): median, 90th
  percentile, and the share whose squared distance in units of σ exceeds the χ² gate of two degrees of freedom at 95 %
  (5.991: ORB-SLAM3's own gate for a monocular observation).
- **The residuals' shear** (px): the residual vectors (projection − keypoint) fitted by an affine function of the
  keypoint's position, x and y over the image height; of the fit's 2×2 gradient, the part that no in-plane rotation
  or change of scale makes, √(((g_xx − g_yy)/2)² + ((g_xy + g_yx)/2)²), in pixels across the image height. A pose
  error moves the projections as a rotation about the optical axis, a scale (forward motion) and a shift do near the
  image centre, and the pose fit takes those up; what it cannot take up is a distortion of the image itself. A
  rolling shutter reads the rows at different times, so a camera turning sideways during the readout shears the
  image (x shifted in proportion to the row) and one tilting stretches it: a shear of k px over the height, half of
  it taken up as a rotation, leaves k/2. On a global-shutter camera it is the noise of the fit.

- **The pose covariance** H⁻¹, turned into the world's axes in ROS's order (:func:`pose_covariance_world`): the
  monitor logs it for every tracked frame (``pose_covariance.csv``, exported as ``PoseWithCovarianceStamped``), and
  :func:`seesys.core.pose_covariance.relative_translation_covariance` carries two frames' covariances to the label's
  relative translation.
  It assumes the map points exact: what the pose fit alone contributes, not the map's error or drift.

The monitor computes them on every tracked frame (:func:`frame_geometry`, one information matrix for the channels and
the covariance): the RTS schema's observability and residual channels since its version 4 (the σ in millimetres, the
residuals in the reference camera's pixels; seesys/core/rts_schema.py). In a monocular session the map's scale is
arbitrary, and so are the lengths' and the covariance's unit.

Noise model (:class:`NoiseModel`, ``[observability]`` of monitor.toml): a keypoint's position has standard
deviation ``pixel_sigma_px`` in each axis. ORB-SLAM3 scales it by 1.2 per pyramid level of the keypoint, but
pyorbslam3 does not give the level, so every keypoint gets the level-0 value: H is an upper bound of the
information (σ a lower bound) by up to the level factor of the points. A measured depth has σ_z =
``depth_sigma_at_1m_m`` · z² (stereo and structured-light depth noise grows with the square of the distance).
pyorbslam3 exposes neither ORB-SLAM3's optimisation residuals, its outlier flags, the keypoints' levels nor the map
points' observation counts (their track length and age), so the monitor recomputes the residuals on the current
frame from the pairing and has no track length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slam_monitor.slam_features import SlamFeatures

#: χ² with two degrees of freedom at 95 %: the gate of a monocular reprojection residual (ORB-SLAM3's).
CHI2_GATE_2DOF = 5.991
# Fewer points than this leave the 6-DoF pose unobservable: no channel values.
_MIN_POINTS = 3
# Fewer paired points than this leave the residuals' affine fit (three coefficients per axis) to noise: no shear.
MIN_SHEAR_POINTS = 12


@dataclass(frozen=True)
class NoiseModel:
    """The measurement noise the information matrix assumes (see the module docstring)."""

    pixel_sigma_px: float
    depth_sigma_at_1m_m: float
    coverage_grid: int


@dataclass(frozen=True)
class PoseObservability:
    """The observability and residual channels of one frame (NaN where they cannot be computed)."""

    translation_sigma_m: float
    weakest_information: float
    condition_number: float
    image_coverage: float
    depth_spread: float
    residual_median_px: float
    residual_p90_px: float
    residual_over_gate: float
    residual_shear_px: float

    @classmethod
    def unknown(cls) -> PoseObservability:
        nan = float("nan")
        return cls(nan, nan, nan, nan, nan, nan, nan, nan, nan)


def pose_information(
    points_c: np.ndarray, fx: float, fy: float, noise: NoiseModel, depth_measured: bool = False
) -> np.ndarray:
    """The 6×6 information matrix of the camera pose (position first, then rotation) from points in front of the
    camera (see the module docstring); with ``depth_measured`` each point adds its depth residual."""
    p = np.asarray(points_c, np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    inverse_z = 1.0 / z
    xz, yz = x * inverse_z, y * inverse_z
    # The rows of (projection Jacobian) @ [−I | [p]×], written out: one stacked matrix and one product cost a
    # tenth of the batched products (the monitor computes this on every tracked frame).
    rows = 3 if depth_measured else 2
    jacobian = np.zeros((len(p), rows, 6))
    u, v = jacobian[:, 0], jacobian[:, 1]
    u[:, 0], u[:, 2], u[:, 3], u[:, 4], u[:, 5] = -inverse_z, xz * inverse_z, xz * yz, -(1 + xz * xz), yz
    v[:, 1], v[:, 2], v[:, 3], v[:, 4], v[:, 5] = -inverse_z, yz * inverse_z, 1 + yz * yz, -xz * yz, -xz
    u *= fx / noise.pixel_sigma_px
    v *= fy / noise.pixel_sigma_px
    if depth_measured:
        depth = jacobian[:, 2]  # the depth residual is the point's z: row 3 of [−I | [p]×], per its σ_z
        depth[:, 2], depth[:, 3], depth[:, 4] = -1.0, -y, x
        depth /= (noise.depth_sigma_at_1m_m * z**2)[:, None]
    flat = jacobian.reshape(-1, 6)
    return flat.T @ flat


def coverage(keypoints_px: np.ndarray, width: int, height: int, grid: int) -> float:
    """The share of a ``grid`` × ``grid`` partition of the image that holds at least one of the keypoints."""
    kp = np.asarray(keypoints_px, np.float64).reshape(-1, 2)
    inside = (kp[:, 0] >= 0) & (kp[:, 0] < width) & (kp[:, 1] >= 0) & (kp[:, 1] < height)
    cells = (kp[inside, 1] * grid // height).astype(int) * grid + (kp[inside, 0] * grid // width).astype(int)
    occupied = np.zeros(grid * grid, dtype=bool)
    occupied[cells] = True  # a mark per cell: np.unique sorts the cells, six times the cost
    return np.count_nonzero(occupied) / grid**2


# Fractions, not percents: np.percentile divides by 100, and 10 / 100 is the double nearest 0.1, as is 0.1.
_SPREAD_FRACTIONS = np.array([0.1, 0.5, 0.9])
_RESIDUAL_FRACTIONS = np.array([0.5, 0.9])


def _percentiles(values: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """``np.percentile(values, 100 * fractions)`` of finite ``values`` (one or more), in numpy's own arithmetic (its
    default linear interpolation: the same doubles), without its generic argument handling, which cost more than the
    partition itself on a frame's few hundred values."""
    count = len(values)
    position = (count - 1) * fractions
    below = np.floor(position)
    weight = position - below
    lower = below.astype(np.intp)
    upper = np.minimum(lower + 1, count - 1)
    ordered = np.partition(values, np.concatenate([lower, upper]))
    a, b = ordered[lower], ordered[upper]
    step = b - a
    # numpy's lerp: from the nearer end, so that a weight near 1 gives b exactly.
    return np.where(weight >= 0.5, b - step * (1 - weight), a + step * weight)


def depth_spread(depths_m: np.ndarray) -> float:
    """(p90 − p10) / median of the points' depths: 0 for points at one distance."""
    z = np.asarray(depths_m, np.float64)
    if len(z) < _MIN_POINTS:
        return float("nan")
    p10, p50, p90 = _percentiles(z, _SPREAD_FRACTIONS)
    return float((p90 - p10) / p50)


def _inverse(information: np.ndarray) -> np.ndarray | None:
    """H⁻¹, the pose covariance in the camera's axes; None where H is singular."""
    try:
        return np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return None


def _translation_observability_of(covariance: np.ndarray | None) -> tuple[float, float, float]:
    if covariance is None:
        nan = float("nan")
        return nan, nan, nan
    block = covariance[:3, :3]
    sigma = float(np.sqrt(np.trace(block))) if np.trace(block) > 0 else float("nan")
    eigen = np.linalg.eigvalsh(np.linalg.inv(block))
    weakest = float(eigen[0])
    return sigma, weakest, float(eigen[-1] / weakest) if weakest > 0 else float("inf")


def translation_observability(information: np.ndarray) -> tuple[float, float, float]:
    """(σ of the position in metres, smallest eigenvalue of the marginal translation information, its condition
    number) from a 6×6 pose information matrix; NaN where the pose is not observable (a singular matrix)."""
    return _translation_observability_of(_inverse(information))


def _turned(covariance: np.ndarray, rotation_wc: np.ndarray) -> np.ndarray:
    turn = np.zeros((6, 6))
    turn[:3, :3] = turn[3:, 3:] = rotation_wc
    return turn @ covariance @ turn.T


def pose_covariance_world(information: np.ndarray, rotation_wc: np.ndarray) -> np.ndarray | None:
    """The 6×6 covariance of the pose in the world's axes, ROS's order (position x, y, z, then rotation about the
    fixed x, y, z axes): H⁻¹, whose perturbations are in the camera's axes, turned by R_wc (both blocks); None
    where H is singular."""
    covariance = _inverse(information)
    return _turned(covariance, rotation_wc) if covariance is not None else None


def residual_channels(distances_px: np.ndarray, pixel_sigma_px: float) -> tuple[float, float, float]:
    """(median, 90th percentile, share beyond the χ² gate) of the matched points' reprojection distances."""
    d = np.asarray(distances_px, np.float64)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        nan = float("nan")
        return nan, nan, nan
    median, p90 = _percentiles(d, _RESIDUAL_FRACTIONS)
    return float(median), float(p90), float(np.mean((d / pixel_sigma_px) ** 2 > CHI2_GATE_2DOF))


def residual_shear(keypoints_px: np.ndarray, residuals_px: np.ndarray, width: int, height: int) -> float:
    """The residuals' shear (module docstring), in pixels across the image height: the residual vectors
    (projection − keypoint, N×2) fitted by least squares as a + G·((u − W/2)/H, (v − H/2)/H). NaN with fewer than
    :data:`MIN_SHEAR_POINTS` points or keypoints that do not span the image in both axes (a singular fit)."""
    kp = np.asarray(keypoints_px, np.float64).reshape(-1, 2)
    if len(kp) < MIN_SHEAR_POINTS:
        return float("nan")
    design = np.ones((len(kp), 3))
    design[:, 1] = (kp[:, 0] - width / 2) / height
    design[:, 2] = (kp[:, 1] - height / 2) / height
    # The 3×3 normal equations: lstsq's SVD costs several times as much on a frame's few hundred points.
    try:
        coefficients = np.linalg.solve(design.T @ design, design.T @ np.asarray(residuals_px, np.float64))
    except np.linalg.LinAlgError:
        return float("nan")
    (gxx, gyx), (gxy, gyy) = coefficients[1], coefficients[2]  # row: ∂/∂u, ∂/∂v; column: residual x, y
    return float(np.hypot((gxx - gyy) / 2, (gxy + gyx) / 2))


def _observability(
    covariance: np.ndarray | None,
    points_c: np.ndarray,
    keypoints_px: np.ndarray,
    distances_px: np.ndarray,
    residuals_px: np.ndarray,
    width: int,
    height: int,
    noise: NoiseModel,
) -> PoseObservability:
    """The channels from H⁻¹ (``covariance``, camera axes; None for a singular H) and the pairing."""
    sigma, weakest, condition = _translation_observability_of(covariance)
    median, p90, over = residual_channels(distances_px, noise.pixel_sigma_px)
    return PoseObservability(
        sigma,
        weakest,
        condition,
        coverage(keypoints_px, width, height, noise.coverage_grid),
        depth_spread(points_c[:, 2]),
        median,
        p90,
        over,
        residual_shear(keypoints_px, residuals_px, width, height),
    )


def pose_observability(
    points_c: np.ndarray,
    keypoints_px: np.ndarray,
    residuals_px: np.ndarray,
    camera_matrix: np.ndarray,
    width: int,
    height: int,
    noise: NoiseModel,
    depth_measured: bool,
) -> PoseObservability:
    """Every channel of one frame: ``points_c`` the matched inlier points in the camera (in front of it),
    ``keypoints_px`` the keypoints they matched and ``residuals_px`` each point's projection less its keypoint."""
    p = np.asarray(points_c, np.float64).reshape(-1, 3)
    if len(p) < _MIN_POINTS:
        return PoseObservability.unknown()
    residuals = np.asarray(residuals_px, np.float64).reshape(-1, 2)
    distances = np.hypot(residuals[:, 0], residuals[:, 1])
    information = pose_information(p, camera_matrix[0, 0], camera_matrix[1, 1], noise, depth_measured)
    return _observability(_inverse(information), p, keypoints_px, distances, residuals, width, height, noise)


def frame_geometry(
    slam: SlamFeatures,
    camera_matrix: np.ndarray,
    width: int,
    height: int,
    depth_measured: bool,
    noise: NoiseModel,
    rotation_wc: np.ndarray,
) -> tuple[PoseObservability, np.ndarray | None]:
    """A tracked frame's observability and residual channels from its SLAM-side features' pairing
    (``slam_monitor.slam_features``), and its world-axes 6×6 pose covariance (:func:`pose_covariance_world`), from
    one information matrix and its one inverse; unknown channels and None with fewer than three paired points, None
    for a singular (or numerically useless) information matrix."""
    points = np.asarray(slam.paired_points_c, np.float64).reshape(-1, 3)
    if len(points) < _MIN_POINTS:
        return PoseObservability.unknown(), None
    # One inverse for both: the channels read H⁻¹ in the camera's axes, the log and the stream in the world's.
    inverse = _inverse(pose_information(points, camera_matrix[0, 0], camera_matrix[1, 1], noise, depth_measured))
    seen = _observability(
        inverse,
        points,
        slam.paired_keypoints_px,
        slam.paired_distances_px,
        slam.paired_residuals_px,
        width,
        height,
        noise,
    )
    covariance = _turned(inverse, rotation_wc) if inverse is not None else None
    return seen, covariance if covariance is not None and np.isfinite(covariance).all() else None
