"""The RTS schema's geometry channels (its version 4's observability, residual and second-opinion channels, and the
pose covariance) against the label, on sequences with ground truth: the check a channel passed before it joined the
schema, kept to judge them, and the covariance, on new sequences.

``seesys dataset candidates SOURCE... --out DIR``: each source (``KIND:PATH`` with ground truth, e.g. a rendered
TUM folder) is tracked once by ORB-SLAM3 (RGB-D, in this process, unpaced), and for every tracked frame the candidate
channels are computed from what the monitor is handed: the pose observability and residual channels
(``slam_monitor.observability``: predicted translation σ, weakest translation information, its condition number,
image coverage, depth spread, residual median, p90 and share over the χ² gate) and the second opinion's disagreement
with ORB-SLAM3 over the label's frames (``slam_monitor.second_opinion``). Every frame gets its label
(``seesys.core.labels``). A per-frame channel is averaged over the label's ``delta_frames`` frames (the pair the
label measures; the disagreement already spans them), sources are named by kind and folder name, and the motion
statistic is the motion yardstick's (``seesys.core.motion``: the spread of the relative
translation, m/frame, over the model window's ``rts_length`` frames).

The predicted pose covariance the monitor logs (``slam_monitor.observability``) is judged as an uncertainty: each
labelled frame gets the predicted σ of its pair's relative translation (``pair_sigma_m``, the square root of the
trace of :func:`seesys.core.pose_covariance.relative_translation_covariance` of the two frames' covariances), a
channel like the others, and the coverage table gives the share of labels within 1σ and 2σ of it beside the share a
Gaussian of that covariance would put there (computed per frame from its 3×3 covariance), and the median of label / σ.

The report: per source and pooled, per channel, the frames it has a value on, its Spearman ρ with the label and its
partial Spearman ρ given the motion statistic (how much of its ranking is not the motion's), and the motion
statistic's own ρ. The dataset report gives the same figures for every channel of a whole build.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.covariance import (
    GAUSSIAN_WITHIN,
    LABEL,
    PAIR_SIGMA,
    coverage_figures,
    pair_columns,
)
from estimator.deepsee.yardsticks import partial_spearman
from seesys.core.errors import SeesysError
from seesys.core.labels import LabelConfig, label_frames
from seesys.core.motion import translation_spread
from seesys.core.pose_covariance import pair_covariance
from seesys.core.trajectory import Poses
from slam_monitor.monitor import MonitorInput, input_slam_features
from slam_monitor.monitor_config import MonitorConfig
from slam_monitor.observability import PoseObservability, frame_geometry
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.replay import record_inputs
from slam_monitor.second_opinion import SecondOpinion
from slam_monitor.slam_features import RelativeMotion, relative_motion
from slam_monitor.sources import load_camera_config, open_source, parse_source_spec

#: The candidate channels, as the report names them: the per-frame ones, and the second opinion's over the label's span.
PER_FRAME = tuple(PoseObservability.__dataclass_fields__)
CHANNELS = (*PER_FRAME, "disagreement_m", PAIR_SIGMA)
MOTION = "motion"
POOLED = "pooled"


def _ground_truth(source: str) -> Poses:
    with open_source(parse_source_spec(source), load_camera_config(), with_depth=True) as opened:
        truth = opened.ground_truth()
    if truth is None:
        raise SeesysError(f"{source} has no ground truth: the candidate channels are judged against the label")
    return truth


def _frame_row(
    item: MonitorInput, opinion: SecondOpinion, recent: deque, config: MonitorConfig
) -> tuple[dict, np.ndarray | None]:
    """One frame's candidate channels and motion statistic (NaN where it has none), and its world-axes pose
    covariance (None where it has none)."""
    frame = item.frame
    if frame.depth is None:
        raise SeesysError(f"frame {frame.index} has no depth: the second opinion is RGB-D's")
    k = frame.intrinsics.matrix()
    disagreement = opinion.update(frame.index, frame.gray, frame.depth, item.keypoints, k, item.pose_wc)
    row: dict = {"frame_index": frame.index, "timestamp": frame.timestamp, "disagreement_m": disagreement}
    if item.pose_wc is None or item.pose_cw is None:
        recent.clear()
        return row, None
    previous = item.prev_pose_wc
    motion = relative_motion(previous, item.pose_wc) if previous is not None else RelativeMotion.still()
    recent.append(motion.translation)
    slam = input_slam_features(item, motion, np.zeros((0, 3)), config)
    seen, covariance = frame_geometry(
        slam, k, frame.intrinsics.width, frame.intrinsics.height, True, config.observability, item.pose_wc[:3, :3]
    )
    row.update(asdict(seen))
    row[MOTION] = float(translation_spread(np.array(recent))) if len(recent) > 2 else None
    return row, covariance


def candidate_frames(source: str, config: MonitorConfig, labels: LabelConfig) -> pd.DataFrame:
    """Every frame of ``source``: its candidate channels averaged over the label's frames, the motion statistic and
    the label (see the module docstring). Raises SeesysError for a source without ground truth or a failed run."""
    truth = _ground_truth(source)
    inputs = record_inputs(source, SlamMode.RGBD)
    opinion = SecondOpinion(config.second_opinion)
    recent: deque = deque(maxlen=config.windows.rts_length)
    framed = [_frame_row(item, opinion, recent, config) for item in inputs]
    if not framed:
        raise SeesysError(f"{source} gave no frames")
    columns = ["frame_index", "timestamp", *CHANNELS, MOTION]
    table = pd.DataFrame([row for row, _ in framed]).reindex(columns=columns).astype(dict.fromkeys(columns[2:], float))
    tracked = [item.pose_wc is not None for item in inputs]
    # A frame without a pose gets the identity in its place, and no label (below).
    poses = [i.pose_wc if i.pose_wc is not None else np.eye(4) for i in inputs]
    estimate = Poses.from_matrices(table.timestamp.to_numpy(float), np.array(poses))
    states = np.array([i.state.name for i in inputs])
    table[LABEL] = label_frames(estimate, states, truth, False, labels).error_m
    table.loc[~np.array(tracked), LABEL] = np.nan
    covariances = {j: covariance for j, (_, covariance) in enumerate(framed) if covariance is not None}
    positions = {j: pose[:3, 3] for j, pose in enumerate(poses)}
    pairs = [pair_covariance(covariances, positions, j, labels.delta_frames) for j in range(len(inputs))]
    table[[PAIR_SIGMA, *GAUSSIAN_WITHIN]] = pair_columns(pairs).to_numpy()
    # A frame's channels over the label's pair; the disagreement already spans it.
    for channel in PER_FRAME:
        table[channel] = table[channel].rolling(labels.delta_frames, min_periods=1).mean()
    spec = parse_source_spec(source)
    table.insert(0, "source", f"{spec.kind}:{Path(spec.path).name}")
    return table


def _per_source(frames: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """Each source's frames, then all of them (:data:`POOLED`)."""
    return [(str(name), group) for name, group in frames.groupby("source", sort=False)] + [(POOLED, frames)]


def correlations(frames: pd.DataFrame) -> pd.DataFrame:
    """Per source and pooled, per channel: n, ρ with the label, partial ρ given the motion statistic, and the motion
    statistic's own ρ on the same frames."""
    rows = []
    for name, group in _per_source(frames):
        for channel in CHANNELS:
            d = group.dropna(subset=[channel, LABEL, MOTION])
            rows.append(
                {
                    "source": name,
                    "channel": channel,
                    "n": len(d),
                    "rho": float(d[[channel, LABEL]].corr("spearman").iloc[0, 1]) if len(d) > 3 else np.nan,
                    "partial_rho_given_motion": partial_spearman(
                        d[channel].to_numpy(), d[LABEL].to_numpy(), d[MOTION].to_numpy()
                    ),
                    "motion_rho": float(d[[MOTION, LABEL]].corr("spearman").iloc[0, 1]) if len(d) > 3 else np.nan,
                }
            )
    return pd.DataFrame(rows)


def coverage(frames: pd.DataFrame) -> pd.DataFrame:
    """Per source and pooled: how often the label lies within 1σ and 2σ of its pair's predicted σ, what a Gaussian of
    the predicted covariance would give (the mean over the frames), and the median of label / σ."""
    return pd.DataFrame([{"source": name, **coverage_figures(group)} for name, group in _per_source(frames)])


def write_candidates_report(frames: pd.DataFrame, table: pd.DataFrame, out: Path) -> list[Path]:
    """``frames.csv``, ``correlations.csv``, ``coverage.csv`` and ``correlations.md`` (both tables) in ``out``
    (created)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "frames.csv", out / "correlations.csv", out / "coverage.csv", out / "correlations.md"]
    frames.to_csv(paths[0], index=False)
    table.to_csv(paths[1], index=False)
    covered = coverage(frames)
    covered.to_csv(paths[2], index=False)
    shown = table.assign(**{c: table[c].round(3) for c in ("rho", "partial_rho_given_motion", "motion_rho")})
    paths[3].write_text(
        "# Candidate channels against the label\n\n"
        "Spearman ρ of each channel (averaged over the label's frames) with the label, and partial ρ given the motion "
        "statistic; per source and pooled.\n\n" + shown.to_markdown(index=False) + "\n\n"
        "## The predicted covariance as an uncertainty\n\n"
        "Share of labels within 1σ and 2σ of the pair's predicted σ (`pair_sigma_m`), beside the share a Gaussian of "
        "the predicted covariance puts there, and the median label / σ.\n\n"
        + covered.round(3).to_markdown(index=False)
        + "\n"
    )
    return paths
