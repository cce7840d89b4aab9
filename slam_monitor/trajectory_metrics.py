"""Session summaries and absolute trajectory error (ATE) with evo.

ATE is the RMSE of the translation differences after Umeyama alignment of the estimate to the ground truth:
SE(3) for RGB-D, whose scale is metric, and Sim(3) for monocular, whose scale is arbitrary.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from seesys.errors import SeesysError
from slam_monitor import session
from slam_monitor.orbslam_settings import SlamMode
from seesys.protocol.tracking_state import TrackingState

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
    from evo.tools import file_interface

    if _pose_rows(estimate) < 3:
        return None
    try:
        reference = file_interface.read_tum_trajectory_file(str(ground_truth))
        estimated = file_interface.read_tum_trajectory_file(str(estimate))
    except Exception as e:  # evo raises its own FileInterfaceException and numpy errors on bad files
        raise SeesysError(f"cannot read trajectories {ground_truth} / {estimate}: {e}") from None
    reference, estimated = sync.associate_trajectories(reference, estimated, max_diff=ASSOCIATION_MAX_DT_S)
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
    return AteResult(float(ape.get_statistic(metrics.StatisticsType.rmse)), aligned.num_poses,
                     "Sim(3)" if with_scale else "SE(3)", float(scale))


def _pose_rows(path: Path) -> int:
    """Data rows of a TUM file (evo rejects a file with none)."""
    try:
        with path.open() as lines:
            return sum(1 for line in lines if line.strip() and not line.startswith("#"))
    except OSError as e:
        raise SeesysError(f"cannot read trajectory {path}: {e.strerror}") from None


def summarize_session(folder: Path, mode: SlamMode) -> SessionSummary:
    """Frames, tracked frames and, when the folder has ``groundtruth.tum``, the ATE of ``trajectory.tum``."""
    frames = pd.read_csv(folder / session.FRAMES_CSV)
    tracked = int(frames["state"].isin([TrackingState.OK.name, TrackingState.OK_KLT.name]).sum())
    ground_truth = folder / session.GROUND_TRUTH
    ate = absolute_trajectory_error(ground_truth, folder / session.TRAJECTORY, mode) if ground_truth.exists() else None
    return SessionSummary(len(frames), tracked, ate)
