"""Per-participant tracking metrics (paper §7.3): tracking error, tracking completeness, losses, time on task.

- **Tracking error** is the pose-error label's error (``seesys/core/labels.py``, docs/labels.md): evo's relative
  pose error, translation part, over ``delta_frames`` frames, of the SLAM trajectory against the motion-capture
  reference, **per tracked stretch**: the trajectory is cut where tracking was lost (a stretch is a maximal run of
  tracked frames of the session's frame log; without a frame log, of poses less than ``stretch_gap_s`` apart), in
  each stretch every estimated pose is associated with the reference pose nearest in time within
  ``association_max_dt_s``, the stretch is aligned to the reference on its own (SE(3) for metric RGB-D SLAM,
  Sim(3) for monocular) and :func:`seesys.core.labels.stretch_errors` gives its pairs; the pairs of all stretches
  are pooled. So no pair straddles a loss, a participant who loses tracking and continues in a new ORB-SLAM3 map
  (its own origin) is not charged for the reset itself, only for the error within each map, and a pair's error is
  the label of its end frame, monocular included (the advice analysis judges the estimates against these pairs).
  Each stretch is what evo's command line computes on that stretch's poses (``evo_rpe tum REF EST --delta 10
  --delta_unit f --pose_relation trans_part --align [--correct_scale] --t_max_diff 0.01 [--all_pairs]``); a
  trajectory without a loss is one stretch, and its error is evo's on the whole trajectory.
- **Error per metre moved and per radian turned**: the sum of the pairs' errors over the sum of the distance the
  reference moved (and of the angle it turned) over the same pairs. The 10-frame error is an error per third of a
  second, so an operator who only slows down lowers it; per metre moved, slowing down alone changes little.
- **Completeness** is the share of camera frames tracked from the first tracked frame on (initialisation, which
  the operator confirms, is not the participant's doing). With a frame log (a session's ``frames.csv``) it is
  counted on the frames; from two TUM files alone it is the share of time from the first estimated pose to the
  end of the reference covered by estimated poses, a gap longer than ``loss_gap_factor`` median frame intervals
  counting as a loss.
- **Losses and map resets**, apart: the number and total duration of tracking losses after initialisation, and
  how many of them ended in a new map (the frame log shows ``LOST`` or ``NOT_INITIALIZED`` during the loss:
  ORB-SLAM3 starts a new map then; a loss with only ``RECENTLY_LOST`` frames relocalised in the same map).
  Without a frame log the resets are unknown (None).
- **Time on task**: from the first frame to the last (or between the operator's start and end events).

Every metric is over the task's span: when the operator ended the task (``q`` in ``seesys study run``) before the
device stopped, the frames logged after that end are left out (:func:`task_span`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core.errors import SeesysError
from seesys.core.labels import ground_truth_of_frames, stretch_errors, tracked_stretches
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io.logfiles import read_csv_log
from study.config import MetricsConfig


class MetricsError(SeesysError):
    """The trajectories or the frame log cannot give a metric (no overlap, a malformed log)."""


@dataclass(frozen=True)
class TrackingMetrics:
    """One participant's (or any two trajectories') metrics; errors in metres, completeness a fraction 0–1."""

    rpe_mean_m: float
    rpe_rmse_m: float
    rpe_median_m: float
    rpe_max_m: float
    error_per_metre: float  # Σ pair error / Σ distance the reference moved over the pairs (m per m)
    error_per_radian: float  # Σ pair error / Σ angle it turned over them (m per rad)
    pairs: int
    completeness: float
    tracking_losses: int
    loss_duration_s: float
    map_resets: int | None  # losses that ended in a new ORB-SLAM3 map (None: no frame log to tell)
    stretches: int  # tracked stretches the error was computed on
    time_on_task_s: float
    alignment: str
    delta_frames: int
    all_pairs: bool
    association_max_dt_s: float

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RpeResult:
    """evo's RPE over the tracked stretches: the per-pair errors (metres), the timestamps of the pairs' end poses,
    how many stretches had pairs, and how far the reference moved (metres) and turned (radians) over each pair."""

    errors_m: np.ndarray
    timestamps: np.ndarray
    alignment: str
    stretches: int = 0
    moved_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    turned_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))


def reference_motion(reference: Poses, delta_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """How far ``reference`` moved (metres) and turned (radians, the angle of the relative rotation) over every
    pair (k, k + ``delta_frames``)."""
    if len(reference) <= delta_frames:
        return np.zeros(0), np.zeros(0)
    moved = np.linalg.norm(reference.positions[delta_frames:] - reference.positions[:-delta_frames], axis=1)
    rotations = reference.rotations
    turned = (rotations[:-delta_frames].inv() * rotations[delta_frames:]).magnitude()
    return moved, np.asarray(turned, float)


def per_motion(errors_m: np.ndarray, motion: np.ndarray) -> float:
    """The error per unit of motion over the same pairs: Σ error / Σ motion (NaN without motion). A ratio of sums,
    not a mean of ratios: pairs over which the device hardly moved do not blow it up."""
    total = float(np.sum(motion))
    return float(np.sum(errors_m)) / total if total > 0 else float("nan")


@dataclass(frozen=True)
class Stretch:
    """A maximal run of tracked frames, by time (inclusive), and whether it began in a new ORB-SLAM3 map (None:
    unknown)."""

    start_s: float
    end_s: float
    new_map: bool | None


def stretches_from_frames(frames: pd.DataFrame) -> list[Stretch]:
    """The tracked stretches of a session's frame log; a stretch after a loss that passed through ``LOST`` or
    ``NOT_INITIALIZED`` began in a new map."""
    times, states = _frame_states(frames)
    tracked = np.array([s.tracked for s in states], bool)
    stretches = []
    previous_stop = None
    for start, stop in tracked_stretches(tracked):
        new_map: bool | None = (
            None
            if previous_stop is None
            else any(s in (TrackingState.LOST, TrackingState.NOT_INITIALIZED) for s in states[previous_stop:start])
        )
        stretches.append(Stretch(float(times[start]), float(times[stop - 1]), new_map))
        previous_stop = stop
    return stretches


def stretches_from_poses(estimate: Poses, cfg: MetricsConfig) -> list[Stretch]:
    """Without a frame log: runs of estimated poses less than ``stretch_gap_s`` apart (new map unknown)."""
    times = np.unique(estimate.timestamps)
    if len(times) == 0:
        return []
    cuts = np.flatnonzero(np.diff(times) > cfg.stretch_gap_s) + 1
    return [Stretch(float(run[0]), float(run[-1]), None) for run in np.split(times, cuts)]


def relative_pose_error(
    estimate: Poses, reference: Poses, monocular: bool, cfg: MetricsConfig, stretches: list[Stretch] | None = None
) -> RpeResult:
    """The label's error (:func:`seesys.core.labels.stretch_errors`) of ``estimate`` against ``reference``, each
    stretch (default: :func:`stretches_from_poses`) associated and SE(3) / Sim(3)-aligned on its own, the pairs
    pooled; no pairs (empty arrays) when too few poses associate."""
    alignment = "Sim(3)" if monocular else "SE(3)"
    if len(estimate) == 0 or len(reference) == 0:
        return RpeResult(np.zeros(0), np.zeros(0), alignment)
    est, ref = estimate.sorted_unique(), reference.sorted_unique()
    found = []
    for stretch in stretches_from_poses(est, cfg) if stretches is None else stretches:
        inside = (est.timestamps >= stretch.start_s) & (est.timestamps <= stretch.end_s)
        pairs = _stretch_rpe(est.take(inside), ref, monocular, cfg)
        if pairs is not None:
            found.append(pairs)
    if not found:
        return RpeResult(np.zeros(0), np.zeros(0), alignment)
    errors, times, moved, turned = (np.concatenate(column) for column in zip(*found))
    return RpeResult(errors, times, alignment, len(found), moved, turned)


def _stretch_rpe(
    est: Poses, ref: Poses, monocular: bool, cfg: MetricsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The errors, end timestamps and reference motion (:func:`reference_motion`) of one stretch's pairs: the
    label's :func:`stretch_errors` on the stretch's poses that have a reference pose within
    ``association_max_dt_s`` (as evo's association keeps them: a pose without one is dropped, not a cut), or None
    when it has no pair or its Sim(3) fit failed."""
    ref_of_pose = ground_truth_of_frames(est.timestamps, ref, cfg.association_max_dt_s)
    associated = ref_of_pose >= 0
    est, ref = est.take(associated), ref.take(ref_of_pose[associated])
    pairs = stretch_errors(est, ref, monocular, cfg.delta_frames)
    if pairs.errors_m.size == 0:
        return None
    moved, turned = reference_motion(ref, cfg.delta_frames)
    # evo's non-overlapping pairs (0, Δ), (Δ, 2Δ), ... are every Δ-th of all pairs.
    step = 1 if cfg.all_pairs else cfg.delta_frames
    return pairs.errors_m[::step], est.timestamps[cfg.delta_frames :][::step], moved[::step], turned[::step]


@dataclass(frozen=True)
class Completeness:
    """``fraction`` of ``frames`` (camera frames from initialisation on) tracked; the losses among them and how
    many of those ended in a new map (None: unknown)."""

    fraction: float
    frames: int
    losses: int
    loss_duration_s: float
    duration_s: float
    map_resets: int | None = None


def _frame_states(frames: pd.DataFrame) -> tuple[np.ndarray, list[TrackingState]]:
    try:
        return frames["timestamp"].to_numpy(float), [TrackingState[str(s)] for s in frames["state"]]
    except KeyError as e:
        raise MetricsError(f"frame log: unknown tracking state or missing column {e}") from None


def completeness_from_frames(frames: pd.DataFrame) -> Completeness:
    """Completeness, losses, map resets and duration from a session's frame log (``timestamp`` and ``state``
    columns)."""
    times, states = _frame_states(frames)
    tracked = np.array([s.tracked for s in states], bool)
    resets = sum(1 for s in stretches_from_frames(frames) if s.new_map)
    duration = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    if not tracked.any():
        return Completeness(0.0, len(tracked), 0, 0.0, duration)
    first = int(np.argmax(tracked))
    after, t = tracked[first:], times[first:]
    stretches = tracked_stretches(after)
    # A loss runs from its first untracked frame to the next tracked one (or to the last frame).
    losses = [(stop, following) for (_, stop), (following, _) in zip(stretches, stretches[1:])]
    if stretches[-1][1] < len(after):
        losses.append((stretches[-1][1], len(after) - 1))
    lost_s = float(sum(t[end] - t[start] for start, end in losses))
    return Completeness(float(after.mean()), len(after), len(losses), lost_s, duration, resets)


def completeness_from_poses(estimate: Poses, reference: Poses, cfg: MetricsConfig) -> Completeness:
    """Completeness from two TUM trajectories alone (see the module docstring)."""
    times = np.unique(estimate.timestamps)
    if len(times) < 2:
        return Completeness(0.0, 0, 0, 0.0, 0.0)
    step = float(np.median(np.diff(times)))
    end = max(float(times[-1]), float(reference.timestamps.max()) if len(reference) else float(times[-1]))
    span = end - float(times[0]) + step
    gaps = np.append(np.diff(times), end - times[-1] + step)  # the time after the last pose may be a loss too
    lost = gaps[gaps > cfg.loss_gap_factor * step] - step
    fraction = float(np.clip(1.0 - lost.sum() / span, 0.0, 1.0))
    return Completeness(fraction, int(round(span / step)), int(len(lost)), float(lost.sum()), float(end - times[0]))


def task_span(estimate: Poses, frames: pd.DataFrame | None, end_s: float) -> tuple[Poses, pd.DataFrame | None]:
    """The poses and frames of a recording up to the end of the task (``end_s``, the timestamp of its last frame:
    frames after the operator ended the task are kept in the session but are not the participant's task)."""
    estimate = estimate.take(estimate.timestamps <= end_s)
    if frames is not None:
        frames = frames[frames["timestamp"].to_numpy(float) <= end_s]
    return estimate, frames


def measure(
    estimate: Poses,
    reference: Poses,
    monocular: bool,
    cfg: MetricsConfig,
    frames: pd.DataFrame | None = None,
    task_end_s: float | None = None,
) -> tuple[RpeResult, Completeness]:
    """The error pairs and the completeness of one recording, over the task's span only when it ended at
    ``task_end_s`` (:func:`task_span`); with its frame log (``frames``) the stretches and the completeness come from
    the tracking states, without it from the poses."""
    if task_end_s is not None:
        estimate, frames = task_span(estimate, frames, task_end_s)
    if frames is not None and len(frames):
        return (
            relative_pose_error(estimate, reference, monocular, cfg, stretches_from_frames(frames)),
            completeness_from_frames(frames),
        )
    return relative_pose_error(estimate, reference, monocular, cfg), completeness_from_poses(estimate, reference, cfg)


def tracking_metrics(
    estimate: Poses,
    reference: Poses,
    monocular: bool,
    cfg: MetricsConfig,
    frames: pd.DataFrame | None = None,
    time_on_task_s: float | None = None,
) -> TrackingMetrics:
    """All metrics of one trajectory; ``frames`` (a session's frame log) makes completeness exact, and
    ``time_on_task_s`` (from the operator's events) replaces the first-to-last-frame duration."""
    rpe, done = measure(estimate, reference, monocular, cfg, frames)
    return combine([rpe], [done], cfg, rpe.alignment, done.duration_s if time_on_task_s is None else time_on_task_s)


def combine(
    rpes: list[RpeResult], parts: list[Completeness], cfg: MetricsConfig, alignment: str, time_on_task_s: float
) -> TrackingMetrics:
    """The metrics of several recordings of one participant's task (a session resumed after a crash): the
    errors of all pairs pooled, completeness weighted by frames, losses and durations summed."""
    errors = np.concatenate([r.errors_m for r in rpes]) if rpes else np.zeros(0)
    moved = np.concatenate([r.moved_m for r in rpes]) if rpes else np.zeros(0)
    turned = np.concatenate([r.turned_rad for r in rpes]) if rpes else np.zeros(0)
    frames = sum(p.frames for p in parts)
    nan = float("nan")
    return TrackingMetrics(
        rpe_mean_m=float(errors.mean()) if errors.size else nan,
        rpe_rmse_m=float(np.sqrt(np.mean(errors**2))) if errors.size else nan,
        rpe_median_m=float(np.median(errors)) if errors.size else nan,
        rpe_max_m=float(errors.max()) if errors.size else nan,
        error_per_metre=per_motion(errors, moved),
        error_per_radian=per_motion(errors, turned),
        pairs=int(errors.size),
        completeness=float(sum(p.fraction * p.frames for p in parts) / frames) if frames else nan,
        tracking_losses=sum(p.losses for p in parts),
        loss_duration_s=float(sum(p.loss_duration_s for p in parts)),
        map_resets=None if any(p.map_resets is None for p in parts) else sum(p.map_resets or 0 for p in parts),
        stretches=sum(r.stretches for r in rpes),
        time_on_task_s=float(time_on_task_s),
        alignment=alignment,
        delta_frames=cfg.delta_frames,
        all_pairs=cfg.all_pairs,
        association_max_dt_s=cfg.association_max_dt_s,
    )


def read_frame_log(path: Path) -> pd.DataFrame:
    """A session's ``frames.csv``; a row cut short by a crash is dropped."""
    try:
        frames = read_csv_log(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise MetricsError(f"cannot read the frame log {path}: {e}") from None
    return frames.dropna(subset=["timestamp", "state"])


def format_metrics(m: TrackingMetrics) -> str:
    """The metrics as the lines ``seesys study metrics`` prints."""
    return "\n".join(
        [
            f"tracking error (RPE, translation, delta {m.delta_frames} frames, {m.alignment}, "
            f"{'all pairs' if m.all_pairs else 'non-overlapping pairs'}, "
            f"association <= {m.association_max_dt_s * 1e3:g} ms):",
            f"  mean {m.rpe_mean_m * 100:.3f} cm, RMSE {m.rpe_rmse_m * 100:.3f} cm, "
            f"median {m.rpe_median_m * 100:.3f} cm, max {m.rpe_max_m * 100:.3f} cm over {m.pairs} pairs",
            f"tracking completeness: {m.completeness * 100:.1f} % ({m.tracking_losses} losses, "
            f"{m.loss_duration_s:.2f} s lost; map resets {'unknown' if m.map_resets is None else m.map_resets})",
            f"  the error is over {m.stretches} tracked stretch(es), each aligned on its own",
            f"  per motion: {m.error_per_metre * 1000:.2f} mm per metre moved, "
            f"{m.error_per_radian * 1000:.2f} mm per radian turned",
            f"time on task: {m.time_on_task_s:.1f} s",
        ]
    )
