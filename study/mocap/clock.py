"""The clock offset between SLAM (camera clock) and motion capture, from their angular speeds.

A rigid body's angular speed is the same in any frame attached to it, so the camera's (from SLAM) and the
marker body's (from motion capture) are one signal on two clocks. Both speeds are computed on their own
timestamps, low-pass filtered alike (a moving average over ``speed_smoothing_s``, so that 30 Hz and 100 Hz
samples carry the same band), resampled on a grid of ``offset_grid_s``, and cross-correlated over
±``max_offset_s``; the peak is then refined by minimising the squared difference of the speeds over a
continuous offset (bounded to ±1 grid step around the peak). Convention: ``t_camera = t_mocap + offset``.

The residual report gives the correlation at the peak (near 1 for a good recording; a low value means too
little rotation or the wrong body), the RMS speed difference after alignment and the number of samples compared.
Fails when the trajectories overlap too little or do not rotate.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import optimize, signal
from scipy.ndimage import uniform_filter1d
from scipy.spatial.transform import Slerp

from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from study.config import CalibrationConfig


class CalibrationError(SeesysError):
    """The recordings cannot be calibrated (too short, no overlap, no rotation)."""


@dataclass(frozen=True)
class ClockOffset:
    offset_s: float
    peak_correlation: float
    residual_rms_deg_s: float
    samples: int
    searched_from_s: float = 0.0  # the centre of the ±max_offset_s search

    def as_dict(self) -> dict:
        return asdict(self)


def interpolate_poses(poses: Poses, times: np.ndarray) -> Poses:
    """Poses at ``times`` (inside the span of ``poses``): positions linearly, rotations by slerp."""
    positions = np.column_stack([np.interp(times, poses.timestamps, poses.positions[:, k]) for k in range(3)])
    rotations = Slerp(poses.timestamps, poses.rotations)(times)
    return Poses.from_rotations(times, positions, rotations)


def angular_speed(poses: Poses) -> tuple[np.ndarray, np.ndarray]:
    """(midpoint times, angular speed in rad/s) between consecutive poses."""
    poses = poses.sorted_unique()
    if len(poses) < 3:
        raise CalibrationError(f"too few poses ({len(poses)}) for an angular speed")
    relative = poses.rotations[:-1].inv() * poses.rotations[1:]
    dt = np.diff(poses.timestamps)
    return (poses.timestamps[:-1] + poses.timestamps[1:]) / 2, relative.magnitude() / dt


def _smoothed_on_grid(times: np.ndarray, speed: np.ndarray, grid: np.ndarray, width: int) -> np.ndarray:
    return uniform_filter1d(np.interp(grid, times, speed), size=max(width, 1), mode="nearest")


def estimate_clock_offset(camera: Poses, mocap: Poses, cfg: CalibrationConfig) -> ClockOffset:
    """The offset with ``t_camera = t_mocap + offset`` (see the module docstring)."""
    t_cam, w_cam = angular_speed(camera)
    t_moc, w_moc = angular_speed(mocap)
    step = cfg.offset_grid_s
    width = int(round(cfg.speed_smoothing_s / step))
    cam_grid = np.arange(t_cam[0], t_cam[-1], step)
    moc_grid = np.arange(t_moc[0], t_moc[-1], step)
    if len(cam_grid) < 2 * width + 3 or len(moc_grid) < 2 * width + 3:
        raise CalibrationError("the recordings are too short to find a clock offset")
    cam = _smoothed_on_grid(t_cam, w_cam, cam_grid, width)
    moc = _smoothed_on_grid(t_moc, w_moc, moc_grid, width)
    if np.std(cam) == 0 or np.std(moc) == 0:
        raise CalibrationError("a trajectory does not rotate: no clock offset can be found")
    # Normalised cross-correlation: lag k means cam[n] ~ moc[n - k] on the shared grid step.
    corr = signal.correlate(cam - cam.mean(), moc - moc.mean(), mode="full")
    overlap = signal.correlate(np.ones_like(cam), np.ones_like(moc), mode="full")
    lags = signal.correlation_lags(len(cam), len(moc), mode="full")
    offsets = cam_grid[0] - moc_grid[0] + lags * step
    # Only offsets within range and with at least a quarter of the shorter recording overlapping count.
    usable = (np.abs(offsets) <= cfg.max_offset_s) & (overlap >= min(len(cam), len(moc)) / 4)
    if not usable.any():
        raise CalibrationError(f"the recordings do not overlap within ±{cfg.max_offset_s} s")
    score = np.where(usable, corr / overlap, -np.inf)
    coarse = float(offsets[int(np.argmax(score))])

    def mismatch(offset: float) -> float:
        grid = cam_grid[(cam_grid - offset >= moc_grid[0]) & (cam_grid - offset <= moc_grid[-1])]
        return float(np.mean((np.interp(grid, cam_grid, cam) - np.interp(grid - offset, moc_grid, moc)) ** 2))

    fine = optimize.minimize_scalar(
        mismatch, bounds=(coarse - step, coarse + step), method="bounded", options={"xatol": step * 1e-3}
    )
    offset = float(fine.x)
    grid = cam_grid[(cam_grid - offset >= moc_grid[0]) & (cam_grid - offset <= moc_grid[-1])]
    a, b = np.interp(grid, cam_grid, cam), np.interp(grid - offset, moc_grid, moc)
    return ClockOffset(
        offset, float(np.corrcoef(a, b)[0, 1]), float(np.degrees(np.sqrt(np.mean((a - b) ** 2)))), len(grid)
    )


def shift(poses: Poses, offset_s: float) -> Poses:
    """The same poses with ``offset_s`` added to every timestamp."""
    return Poses(poses.timestamps + offset_s, poses.positions, poses.quaternions_xyzw)
