"""The pose-error label of a frame: the one definition used by the dataset builder and the label report.

Definition (docs/labels.md explains the choices and how they differ from the authors' code):

- **Error.** evo's relative pose error (RPE), ``PoseRelation.translation_part``, over ``delta_frames`` frames
  (10, ≈ 0.33 s at 30 Hz): for the pair (i, j = i + Δ), ``E = (G_i⁻¹ G_j)⁻¹ (P_i⁻¹ P_j)`` with G the ground truth
  and P the estimate, and the label is ‖translation(E)‖ in metres. It is assigned to the *end* frame j, the frame
  whose RTS window ends the pair.
- **Pairs only inside a tracked stretch.** A stretch is a maximal run of consecutive frames that SLAM reports
  as tracked (``TrackingState.tracked``) and that have a ground-truth pose within ``association_max_dt_s``.
  A pair whose frames are not both in one stretch gets no label.
- **Alignment, per tracked stretch.** Each stretch is aligned to the ground truth on its own, as evo's
  ``--align`` (RGB-D: SE(3)) and ``--align --correct_scale`` (monocular: Sim(3)) do on a whole trajectory. A rigid
  change of the world frame leaves every relative pose unchanged, so only the monocular scale matters: the
  estimate is multiplied by the Sim(3) scale fitted (Umeyama) on all the stretch's poses. Scale drift within a
  stretch therefore stays in the label, as it stays in what an AR user sees (content placed at the wrong size).
  The fitted scale is kept per frame (``scale``). :func:`stretch_errors` is this error of one stretch; the study's
  tracking error and its judgement of the advice use it too, so a monocular label and a study pair are one number.
- **No cleaning.** No clipping, no dropping of large errors, no smoothing, no ground-truth substitution when an
  alignment fails (the frame is flagged instead).
- **Frames around tracking loss are flagged, not labelled:** every frame gets a :class:`LabelStatus`; only
  ``labelled`` frames carry an error and belong to the regression target.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import SupportsInt

import numpy as np
import pandas as pd

from seesys.core.errors import SeesysError
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses, sim3_scale


@dataclass(frozen=True)
class LabelConfig:
    delta_frames: int
    association_max_dt_s: float


# The name of the monocular label's alignment (one Sim(3) per tracked stretch), recorded with every model trained on
# monocular sessions: a model made under another definition is refused by it (estimator/artefact/compatibility.py).
MONO_ALIGNMENT = "sim3-per-stretch"
# The alignment of monocular labels whose record names none (a model's, a dataset's): they were made before the name
# was recorded, on the label that fitted each pair's scale on a sliding window.
BEFORE_MONO_ALIGNMENT = "sim3-sliding-window"


class LabelStatus(str, Enum):
    """Why a frame has, or has no, label."""

    LABELLED = "labelled"
    NOT_TRACKED = "not_tracked"  # SLAM did not report the frame as tracked (initialising, lost, relocalising)
    WARMUP = "warmup"  # tracked, but fewer than delta frames into its tracked stretch
    NO_GROUND_TRUTH = "no_ground_truth"  # no ground-truth pose within the association tolerance
    UNALIGNED = "unaligned"  # monocular: degenerate motion (all poses on a line) leaves the stretch's scale unfitted


class LabelError(SeesysError):
    """Inputs to the labeller are inconsistent (lengths, order, too little ground truth)."""


@dataclass(frozen=True)
class FrameLabels:
    """Per SLAM frame: the label (metres, NaN unless ``labelled``), its status and the fitted scale."""

    timestamps: np.ndarray
    error_m: np.ndarray
    status: np.ndarray  # LabelStatus values (str)
    scale: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame(
            {"timestamp": self.timestamps, "error_m": self.error_m, "status": self.status, "scale": self.scale}
        )

    @property
    def labelled(self) -> np.ndarray:
        return self.status == LabelStatus.LABELLED.value


def _state(value: str | SupportsInt) -> TrackingState:
    """A tracking state given as its number or its name (session logs write names)."""
    try:
        return TrackingState[value] if isinstance(value, str) else TrackingState(int(value))
    except (KeyError, ValueError):
        raise LabelError(f"unknown tracking state {value!r}") from None


def tracked_stretches(tracked: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs [start, stop) of True in ``tracked``."""
    padded = np.concatenate([[False], tracked.astype(bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def ground_truth_of_frames(timestamps: np.ndarray, ground_truth: Poses, max_dt_s: float) -> np.ndarray:
    """For each frame time, the index of its ground-truth pose (evo's association: nearest in time, within
    ``max_dt_s``), or -1."""
    from evo.core import sync

    est_idx, gt_idx = sync.matching_time_indices(timestamps, ground_truth.timestamps, max_diff=max_dt_s)
    gt_of_frame = np.full(len(timestamps), -1)
    gt_of_frame[np.asarray(est_idx, int)] = np.asarray(gt_idx, int)
    return gt_of_frame


def tracked_states(states: np.ndarray) -> np.ndarray:
    """Whether SLAM reported each frame tracked (``states``: tracking states by number or name)."""
    return np.array([_state(s).tracked for s in states], bool)


def label_frames(
    estimate: Poses, states: np.ndarray, ground_truth: Poses, monocular: bool, config: LabelConfig
) -> FrameLabels:
    """Label every frame of one SLAM run (``estimate`` has one pose per frame, ``states`` its tracking states)."""
    n = len(estimate.timestamps)
    if len(states) != n:
        raise LabelError(f"{len(states)} tracking states for {n} frames")
    if n and np.any(np.diff(estimate.timestamps) <= 0):
        raise LabelError("frame timestamps must increase strictly")
    gt_of_frame = ground_truth_of_frames(estimate.timestamps, ground_truth, config.association_max_dt_s)

    tracked = tracked_states(states)
    status = np.where(tracked, LabelStatus.WARMUP.value, LabelStatus.NOT_TRACKED.value).astype(object)
    status[tracked & (gt_of_frame < 0)] = LabelStatus.NO_GROUND_TRUTH.value
    error = np.full(n, np.nan)
    scale = np.full(n, np.nan)
    delta = config.delta_frames
    for start, stop in tracked_stretches(tracked & (gt_of_frame >= 0)):
        if stop - start <= delta:
            continue
        frames = np.arange(start, stop)
        ends = frames[delta:]
        pairs = stretch_errors(estimate.take(frames), ground_truth.take(gt_of_frame[frames]), monocular, delta)
        scale[ends] = pairs.scale
        if np.isfinite(pairs.scale):
            error[ends] = pairs.errors_m
            status[ends] = LabelStatus.LABELLED.value
        else:
            status[ends] = LabelStatus.UNALIGNED.value
    return FrameLabels(estimate.timestamps.copy(), error, status.astype(str), scale)


@dataclass(frozen=True)
class StretchErrors:
    """The error of every pair (k, k + Δ) of one tracked stretch, in pair order (metres; none when the stretch has
    no pair), and the scale the estimate was multiplied by (1 for RGB-D; the stretch's Sim(3) scale for
    monocular; NaN when that fit failed or the stretch has no pair, and then no errors)."""

    errors_m: np.ndarray
    scale: float


def stretch_errors(estimate: Poses, ground_truth: Poses, monocular: bool, delta_frames: int) -> StretchErrors:
    """The pose error of one tracked stretch: ``estimate`` and ``ground_truth`` associated pose for pose, every
    pair (k, k + ``delta_frames``); raises :class:`LabelError` when their lengths differ.

    This is evo's RPE (translation part, all pairs) after evo's alignment of the whole stretch: SE(3) for RGB-D
    (which leaves every relative pose as it is, so none is applied) and Sim(3) for monocular, of which only the
    scale changes a relative pose (the Umeyama fit over all the stretch's poses, ``sim3_scale``).
    """
    from evo.core import metrics
    from evo.core.trajectory import PosePath3D

    n = len(estimate)
    if len(ground_truth) != n:
        raise LabelError(f"{len(ground_truth)} ground-truth poses for {n} estimated poses of a stretch")
    if n <= delta_frames:
        return StretchErrors(np.zeros(0), float("nan") if monocular else 1.0)
    scale = sim3_scale(estimate.positions, ground_truth.positions) if monocular else 1.0
    if not np.isfinite(scale):
        return StretchErrors(np.zeros(0), scale)
    scaled = PosePath3D(
        positions_xyz=estimate.positions * scale, orientations_quat_wxyz=estimate.quaternions_xyzw[:, [3, 0, 1, 2]]
    )
    rpe = metrics.RPE(
        metrics.PoseRelation.translation_part, delta=delta_frames, delta_unit=metrics.Unit.frames, all_pairs=True
    )
    rpe.process_data((ground_truth.to_evo(), scaled))
    return StretchErrors(np.asarray(rpe.error, float), scale)


@dataclass(frozen=True)
class LabelSummary:
    """Distribution of labels (metres) over labelled frames, and the share of frames tracked."""

    frames: int
    labelled: int
    tracked_fraction: float
    median_m: float
    p90_m: float
    p99_m: float
    max_m: float
    fraction_above: dict[float, float]

    @classmethod
    def of(cls, labels: pd.DataFrame, thresholds_m: tuple[float, ...]) -> LabelSummary:
        """Summary of a label table (``to_frame`` rows of one or many runs)."""
        errors = labels.loc[labels.status == LabelStatus.LABELLED.value, "error_m"].to_numpy()
        tracked = (labels.status != LabelStatus.NOT_TRACKED.value).mean() if len(labels) else float("nan")
        if len(errors) == 0:
            nan = float("nan")
            return cls(len(labels), 0, float(tracked), nan, nan, nan, nan, dict.fromkeys(thresholds_m, nan))
        p50, p90, p99 = np.percentile(errors, [50, 90, 99])
        return cls(
            len(labels),
            len(errors),
            float(tracked),
            float(p50),
            float(p90),
            float(p99),
            float(errors.max()),
            {t: float((errors > t).mean()) for t in thresholds_m},
        )
