"""Session summaries and absolute trajectory error (ATE) with evo.

ATE is the RMSE of the translation differences after Umeyama alignment of the estimate to the ground truth:
SE(3) for RGB-D, whose scale is metric, and Sim(3) for monocular, whose scale is arbitrary.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from seesys.core import session_layout
from seesys.core.tracking_state import TrackingState
from seesys.io.trajectory_files import read_tum
from slam_monitor.orbslam_settings import SlamMode

# Estimated and true poses are paired when their timestamps differ by at most this (seconds).
ASSOCIATION_MAX_DT_S = 0.01


@dataclass(frozen=True)
class AteResult:
    rmse_m: float
    pairs: int
    alignment: str
    scale: float


@dataclass(frozen=True)
class SessionSummary:
    frames: int
    frames_tracked: int
    ate: AteResult | None

    @property
    def tracked_percent(self) -> float:
        return 100.0 * self.frames_tracked / self.frames if self.frames else 0.0


def absolute_trajectory_error(ground_truth: Path, estimate: Path, mode: SlamMode) -> AteResult | None:
    """ATE of ``estimate`` against ``ground_truth`` (TUM files), or ``None`` when it cannot be aligned: fewer than
    3 pairs (none at all when ORB-SLAM3 never initialised), or positions on a line (a short straight path), for
    which Umeyama's alignment is undetermined."""
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException

    estimated_poses, reference_poses = read_tum(estimate), read_tum(ground_truth)
    if len(estimated_poses) < 3 or len(reference_poses) < 3:
        return None
    reference, estimated = sync.associate_trajectories(
        reference_poses.to_evo(), estimated_poses.to_evo(), max_diff=ASSOCIATION_MAX_DT_S
    )
    if estimated.num_poses < 3:
        return None
    aligned = copy.deepcopy(estimated)
    with_scale = mode is SlamMode.MONO
    try:
        _, _, scale = aligned.align(reference, correct_scale=with_scale)
    except GeometryException:
        return None
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, aligned))
    return AteResult(
        float(ape.get_statistic(metrics.StatisticsType.rmse)),
        aligned.num_poses,
        "Sim(3)" if with_scale else "SE(3)",
        float(scale),
    )


def summarize_session(folder: Path, mode: SlamMode) -> SessionSummary:
    """Frames, tracked frames and, when the folder has ``groundtruth.tum``, the ATE of ``trajectory.tum``."""
    frames = pd.read_csv(folder / session_layout.FRAMES_CSV)
    tracked = int(frames["state"].isin([TrackingState.OK.name, TrackingState.OK_KLT.name]).sum())
    ground_truth = folder / session_layout.GROUND_TRUTH
    trajectory = folder / session_layout.TRAJECTORY
    ate = absolute_trajectory_error(ground_truth, trajectory, mode) if ground_truth.exists() else None
    return SessionSummary(len(frames), tracked, ate)
