"""The camera's metric scale against ground truth: an error no input to the model shows.

An RGB-D camera whose depth reads z·(1+s) makes ORB-SLAM3 build a world, and a trajectory, scaled by 1+s: the
tracker, its features and every RTS channel are self-consistent in that world, so no estimator sees the error,
yet every translation is off by s (a 7 % depth scale error doubles the 10-frame error on our renders). Ground truth
measures it: the Sim(3) alignment (Umeyama, via evo) of the SLAM trajectory onto the ground truth has scale
c = 1/(1+s). The scale is fitted on windows of tracked frames, so that a window's own drift and a relocalisation
between stretches do not enter one fit, and its spread over windows says how well it is known.

Monocular SLAM has no metric scale (its scale is its initialisation's): the check is for RGB-D sessions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seesys.core.errors import SeesysError
from seesys.core.labels import ground_truth_of_frames, tracked_stretches
from seesys.core.trajectory import Poses, sim3_scale


class ScaleCheckError(SeesysError):
    """The scale cannot be measured from the session(s): too little tracked motion with ground truth."""


def depth_scale_error(correction: float) -> float:
    """The depth scale error s (the camera reads z·(1+s)) that the depth correction (or the Sim(3) scale) c
    undoes: 1/c − 1; positive when the depth reads long."""
    return 1.0 / correction - 1.0


@dataclass(frozen=True)
class ScaleSettings:
    """``[scale]`` of ``configs/camera.toml``."""

    depth_correction: float  # every depth value is multiplied by this before tracking (1: as the camera reports it)
    warn_above: float  # a recorded scale error above this (a fraction) is a warning when the app starts
    window_frames: int  # tracked frames per fitted window
    step_frames: int  # a window starts every this many frames
    min_path_m: float  # a window whose ground-truth path is shorter than this is not fitted (its scale is ill-posed)

    def __post_init__(self) -> None:
        if not 0.5 < self.depth_correction < 2.0:
            raise ValueError(f"depth_correction must lie in (0.5, 2), got {self.depth_correction}")
        if self.window_frames < 3 or self.step_frames < 1 or self.min_path_m <= 0 or self.warn_above <= 0:
            raise ValueError(f"window_frames >= 3, step_frames >= 1, min_path_m > 0 and warn_above > 0: {self}")

    @property
    def recorded_error(self) -> float:
        """The depth scale error s the configured correction compensates (the camera reads z·(1+s))."""
        return depth_scale_error(self.depth_correction)

    def warning(self) -> str | None:
        """What the app says when it starts, if the recorded scale error is above ``warn_above``; else None."""
        if abs(self.recorded_error) <= self.warn_above:
            return None
        return (
            f"this camera's depth reads {abs(self.recorded_error):.1%} {_long_or_short(self.recorded_error)} "
            f"(camera.toml [scale] depth_correction = {self.depth_correction:g}, applied to every frame): "
            "recalibrate it if you can; a model not fine-tuned on this camera has not seen its faults"
        )


@dataclass(frozen=True)
class ScaleFit:
    """Sim(3) scales c (ground truth ≈ c·R·estimate + t) of the fitted windows, and what they say."""

    scales: np.ndarray

    @property
    def windows(self) -> int:
        return len(self.scales)

    @property
    def scale(self) -> float:
        """The median window scale c."""
        return float(np.median(self.scales))

    @property
    def spread(self) -> tuple[float, float]:
        """The 10th and 90th percentiles of the window scales."""
        low, high = np.percentile(self.scales, [10, 90])
        return float(low), float(high)

    @property
    def depth_scale_error(self) -> float:
        """The camera's depth scale error s, the depth reading z·(1+s): 1/c − 1 (positive: depth reads long)."""
        return depth_scale_error(self.scale)

    def correction(self, applied: float = 1.0) -> float:
        """The ``depth_correction`` that would have made the trajectory metric, given the one ``applied`` while
        recording."""
        return applied * self.scale

    def depth_factor(self, depth_factor: float) -> float:
        """What a calibration's ``depth_factor`` (depth PNG value per metre) should say instead."""
        return depth_factor / self.scale

    @classmethod
    def pooled(cls, fits: list[ScaleFit]) -> ScaleFit:
        """The windows of several sessions of one camera together."""
        return cls(np.concatenate([f.scales for f in fits]) if fits else np.zeros(0))


def _long_or_short(error: float) -> str:
    return "long" if error > 0 else "short"


def describe(fit: ScaleFit) -> str:
    """One line: the fitted scale, its spread, the windows and the depth scale error it means."""
    low, high = fit.spread
    return (
        f"scale {fit.scale:.4f} (10-90 % of windows {low:.4f}-{high:.4f}, {fit.windows} windows): the depth "
        f"reads {abs(fit.depth_scale_error):.1%} {_long_or_short(fit.depth_scale_error)}"
    )


def _stretches(usable: np.ndarray, timestamps: np.ndarray, max_gap_s: float | None) -> list[tuple[int, int]]:
    """Runs [start, stop) of usable frames, split where consecutive frames are more than ``max_gap_s`` apart."""
    cuts = np.flatnonzero(np.diff(timestamps) > max_gap_s) + 1 if max_gap_s is not None else np.zeros(0, int)
    runs = []
    for start, stop in tracked_stretches(usable):
        bounds = [start, *cuts[(cuts > start) & (cuts < stop)].tolist(), stop]
        runs += list(zip(bounds[:-1], bounds[1:]))
    return runs


def window_scales(
    estimate: Poses,
    tracked: np.ndarray,
    ground_truth: Poses,
    association_max_dt_s: float,
    settings: ScaleSettings,
    max_gap_s: float | None = None,
) -> ScaleFit:
    """The Sim(3) scale of every window of ``settings.window_frames`` frames, inside one stretch of frames tracked
    with a ground-truth pose, whose ground-truth path is at least ``settings.min_path_m`` long.

    ``estimate`` has one pose per frame (any pose where not ``tracked``); with ``max_gap_s``, frames further apart
    in time also end a stretch (a trajectory file that holds only the tracked poses). Raises
    :class:`ScaleCheckError` when no window qualifies."""
    if len(tracked) != len(estimate):
        raise ScaleCheckError(f"{len(tracked)} tracking flags for {len(estimate)} frames")
    gt_of_frame = ground_truth_of_frames(estimate.timestamps, ground_truth, association_max_dt_s)
    n, step = settings.window_frames, settings.step_frames
    usable = np.asarray(tracked, bool) & (gt_of_frame >= 0)
    scales = []
    for start, stop in _stretches(usable, estimate.timestamps, max_gap_s):
        for lo in range(start, stop - n + 1, step):
            gt_xyz = ground_truth.positions[gt_of_frame[lo : lo + n]]
            if np.linalg.norm(np.diff(gt_xyz, axis=0), axis=1).sum() < settings.min_path_m:
                continue
            scales.append(sim3_scale(estimate.positions[lo : lo + n], gt_xyz))
    fitted = np.array([c for c in scales if np.isfinite(c)])
    if not len(fitted):
        raise ScaleCheckError(
            f"no stretch of {n} tracked frames with ground truth moves {settings.min_path_m} m: "
            "the scale cannot be measured"
        )
    return ScaleFit(fitted)
