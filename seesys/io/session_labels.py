"""Labels of a recorded device session: its files read, then labelled by :func:`seesys.core.labels.label_frames`
with the settings of ``configs/labels.toml``
(:func:`seesys.io.core_settings.load_label_config`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core import session_layout
from seesys.core.labels import FrameLabels, LabelConfig, LabelError, label_frames
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum


@dataclass(frozen=True)
class SessionTrack:
    """A device session's frames as SLAM tracked them, and the ground truth recorded beside them."""

    estimate: Poses  # one pose per frame of frames.csv (identity where SLAM gave none)
    states: np.ndarray  # tracking state names; a frame without a pose counts as lost
    ground_truth: Poses


def read_session_track(folder: Path) -> SessionTrack:
    """``frames.csv`` (every frame and its state), ``trajectory.tum`` (poses of the tracked frames) and
    ``groundtruth.tum`` of a device session folder (docs/device.md); :class:`LabelError` naming what is missing.

    A frame reported tracked but absent from ``trajectory.tum`` (no valid pose) counts as not tracked.
    """
    try:
        frames = pd.read_csv(folder / session_layout.FRAMES_CSV)
    except (OSError, pd.errors.ParserError) as e:
        raise LabelError(f"cannot read {folder / session_layout.FRAMES_CSV}: {e}") from None
    ground_truth = folder / session_layout.GROUND_TRUTH
    if not ground_truth.is_file():
        raise LabelError(f"{folder} has no {session_layout.GROUND_TRUTH}: the source had no ground truth")
    poses = read_tum(folder / session_layout.TRAJECTORY)
    times = frames["timestamp"].to_numpy(float)
    positions = np.zeros((len(times), 3))
    quaternions = np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1))
    has_pose = np.zeros(len(times), bool)
    if len(poses.timestamps):
        row = np.clip(np.searchsorted(poses.timestamps, times), 0, len(poses.timestamps) - 1)
        has_pose = np.isclose(poses.timestamps[row], times, atol=1e-6, rtol=0.0)
        positions[has_pose] = poses.positions[row[has_pose]]
        quaternions[has_pose] = poses.quaternions_xyzw[row[has_pose]]
    states = np.where(has_pose, frames["state"].to_numpy(object), TrackingState.LOST.name)
    return SessionTrack(Poses(times, positions, quaternions), states, read_tum(ground_truth))


def label_session(folder: Path, monocular: bool, config: LabelConfig) -> FrameLabels:
    """Labels of a device session folder (:func:`read_session_track`)."""
    track = read_session_track(folder)
    return label_frames(track.estimate, track.states, track.ground_truth, monocular, config)


def label_session_by_frame(folder: Path, monocular: bool, config: LabelConfig) -> pd.DataFrame:
    """:func:`label_session` indexed by each frame's index (``frames.csv``): one row per frame, its ``status`` and
    ``error_m`` among the label's columns."""
    labels = label_session(folder, monocular, config).to_frame()
    frames = pd.read_csv(folder / session_layout.FRAMES_CSV, usecols=["frame_index"])
    labels["frame_index"] = frames.frame_index.to_numpy()
    return labels.set_index("frame_index")
