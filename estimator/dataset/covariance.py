"""The monitor's predicted pose covariance judged as an uncertainty of the label, on a build's runs.

The label of frame j is the norm of the error of the translation from frame j − ``delta_frames`` to j
(:mod:`seesys.core.labels`). Its predicted covariance is that of the pair, from the two frames' logged 6×6 world-axes
covariances (``pose_covariance.csv`` of the device session, :func:`seesys.core.pose_covariance.
relative_translation_covariance`), and its σ the square root of the trace (the expected squared norm of a zero-mean
error of that covariance). **Coverage** is the share of labels within 1σ and 2σ, beside the share a Gaussian of each
frame's own covariance puts there (its norm within 1σ and 2σ, by Monte-Carlo in the covariance's axes).

The bound leaves out the map's own error and ORB-SLAM3's pyramid levels, so it is expected to be too small. A single
**scale** for σ is fitted on a round's training runs only: the quantile of label / σ at the Gaussian's mean 1σ share,
so that on the training runs as many labels lie within the scaled 1σ as a Gaussian would put there. The test sets
(test trajectories, held-out rooms, each held-out camera: :func:`estimator.dataset.splits.set_indices`) are judged
with the bound as computed and with the training runs' scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.build import SESSIONS_DIR
from estimator.dataset.splits import Splits, set_indices
from estimator.dataset.store import FRAMES_CSV, WITH_SAMPLES, DatasetError, list_runs, run_folder
from seesys.core import session_layout
from seesys.core.labels import LabelConfig, LabelStatus
from seesys.core.pose_covariance import pair_covariance
from seesys.io.logfiles import read_csv_table
from seesys.io.rts_log import read_pose_covariance_log
from seesys.io.session_labels import label_session_by_frame
from seesys.io.trajectory_files import read_tum

#: Draws per frame for the share of a Gaussian within 1σ and 2σ; a fixed seed keeps a report reproducible.
GAUSSIAN_DRAWS = 4000
GAUSSIAN_WITHIN = ("gaussian_within_1sigma", "gaussian_within_2sigma")
PAIR_SIGMA = "pair_sigma_m"
LABEL = "label_m"


def gaussian_within(pairs: list[np.ndarray | None]) -> np.ndarray:
    """(N, 2): per frame, the shares of a zero-mean Gaussian of its pair's covariance whose norm lies within 1σ and
    2σ (σ the square root of the trace); NaN where the frame has none."""
    draws = np.random.default_rng(0).standard_normal((GAUSSIAN_DRAWS, 3))
    shares = np.full((len(pairs), 2), np.nan)
    for k, c in enumerate(pairs):
        if c is not None:
            # in the covariance's own axes: a rotation does not change a norm
            norms = np.linalg.norm(draws * np.sqrt(np.clip(np.linalg.eigvalsh(c), 0, None)), axis=1)
            sigma = np.sqrt(np.trace(c))
            shares[k] = np.mean(norms <= sigma), np.mean(norms <= 2 * sigma)
    return shares


def pair_columns(pairs: list[np.ndarray | None]) -> pd.DataFrame:
    """Per frame, the pair's σ and the Gaussian's shares within 1σ and 2σ (NaN where there is no pair)."""
    table = pd.DataFrame(gaussian_within(pairs), columns=list(GAUSSIAN_WITHIN))
    table.insert(0, PAIR_SIGMA, [np.sqrt(np.trace(c)) if c is not None else np.nan for c in pairs])
    return table


def coverage_figures(frames: pd.DataFrame, scale: float = 1.0) -> dict[str, float]:
    """The share of ``frames``' labels within 1σ and 2σ of their pair's σ times ``scale``, what a Gaussian would
    give, and the median label / σ (unscaled), on the frames with both."""
    d = frames.dropna(subset=[PAIR_SIGMA, LABEL])
    ratio = (d[LABEL] / d[PAIR_SIGMA]).to_numpy()
    nan = float("nan")
    return {
        "frames": len(d),
        "within_1sigma": float(np.mean(ratio <= scale)) if len(d) else nan,
        "within_2sigma": float(np.mean(ratio <= 2 * scale)) if len(d) else nan,
        "gaussian_1sigma": float(d[GAUSSIAN_WITHIN[0]].mean()) if len(d) else nan,
        "gaussian_2sigma": float(d[GAUSSIAN_WITHIN[1]].mean()) if len(d) else nan,
        "median_label_over_sigma": float(np.median(ratio)) if len(d) else nan,
    }


def fitted_scale(frames: pd.DataFrame) -> float:
    """The σ scale of the module docstring, fitted on ``frames`` (training runs); NaN without a frame."""
    d = frames.dropna(subset=[PAIR_SIGMA, LABEL])
    if d.empty:
        return float("nan")
    return float(np.quantile(d[LABEL] / d[PAIR_SIGMA], d[GAUSSIAN_WITHIN[0]].mean()))


def _labelled_frame_pairs(session: Path, labels: pd.DataFrame, run: str, delta: int, why: str) -> pd.DataFrame:
    """The labelled frames of ``labels`` (``frame_index``, ``error_m``) of a device session folder with their pair's
    σ and Gaussian shares, named ``run``; :class:`DatasetError` ending in ``why`` when the covariance log is
    missing."""
    logged = read_pose_covariance_log(session)
    if logged is None:
        raise DatasetError(f"{session / session_layout.POSE_COVARIANCE_CSV} is missing: {why}")
    covariances = logged.by_frame()
    positions = logged.positions(read_tum(session / session_layout.TRAJECTORY))
    pairs = [pair_covariance(covariances, positions, int(j), delta) for j in labels.frame_index]
    table = pd.concat([labels[["frame_index"]].reset_index(drop=True), pair_columns(pairs)], axis=1)
    table[LABEL] = labels.error_m.to_numpy(float)
    table.insert(0, "run", run)
    return table


def run_frames(root: Path, run: str, delta: int) -> pd.DataFrame:
    """Every labelled frame of a build's run with its pair's σ and Gaussian shares; raises :class:`DatasetError`
    when the run's device session (kept by ``keep_sessions``) or its covariance log is missing."""
    labels = pd.read_csv(run_folder(root, run) / FRAMES_CSV)
    labels = labels[labels.status == LabelStatus.LABELLED.value]
    why = (
        "the covariance's coverage needs the build's device sessions with their pose covariance (a build of RTS "
        "schema v4 with keep_sessions)"
    )
    return _labelled_frame_pairs(Path(root) / SESSIONS_DIR / run, labels, run, delta, why)


def session_frames(folder: Path, delta: int, monocular: bool, config: LabelConfig) -> pd.DataFrame:
    """Every labelled frame of a device session folder (labelled as :func:`seesys.io.session_labels.label_session`
    labels it; ``run``: the folder's name) with its pair's σ and Gaussian shares; raises :class:`DatasetError` when
    its monitor logged no pose covariance."""
    labels = label_session_by_frame(folder, monocular, config).reset_index()
    labels = labels[labels.status == LabelStatus.LABELLED.value]
    why = "its monitor logged no pose covariance (RTS schema v4 or later logs it)"
    return _labelled_frame_pairs(Path(folder), labels, Path(folder).name, delta, why)


def build_frames(roots: list[Path], delta: int) -> pd.DataFrame:
    """:func:`run_frames` of every run with samples of the build folders, with the run's room and camera model."""
    tables = []
    for root in roots:
        for info in list_runs(root):
            if info.status in WITH_SAMPLES:
                table = run_frames(root, info.run, delta)
                tables.append(table.assign(environment=info.environment, camera_model=info.camera_model))
    if not tables:
        raise DatasetError(f"no run with samples in {', '.join(str(r) for r in roots)}")
    return pd.concat(tables, ignore_index=True)


def coverage_by_set(frames: pd.DataFrame, splits: Splits, rounds: list[int]) -> pd.DataFrame:
    """Per round and test set: the coverage of the bound as computed and scaled by the round's training runs'
    :func:`fitted_scale` (columns ``*_scaled``), and per camera model of the set."""
    rows = []
    for r in rounds:
        split_round = splits.rounds[r]
        scale = fitted_scale(frames[frames.run.isin(split_round.train)])
        test = frames[frames.run.isin(split_round.test)].reset_index(drop=True)
        environments, cameras = splits.heldout(r)
        for name, index in set_indices(test, environments, cameras).items():
            part = test.iloc[index]
            groups = [("all", part)] + [(str(c), g) for c, g in part.groupby("camera_model")]
            for camera, group in groups:
                raw, scaled = coverage_figures(group), coverage_figures(group, scale)
                rows.append(
                    {
                        "round": r,
                        "set": name,
                        "camera_model": camera,
                        "runs": group.run.nunique(),
                        **raw,
                        "scale": scale,
                        "within_1sigma_scaled": scaled["within_1sigma"],
                        "within_2sigma_scaled": scaled["within_2sigma"],
                    }
                )
    return pd.DataFrame(rows)


#: An evaluation's predictions.csv columns the model-scaled coverage reads.
PREDICTION_COLUMNS = ("set", "row", "round", "run", "frame_index", "true_m", "estimate_m")


def read_predictions(path: Path) -> pd.DataFrame:
    """An evaluation's ``predictions.csv``; raises :class:`seesys.core.errors.SeesysError` for a file that is
    missing, unreadable or without one of :data:`PREDICTION_COLUMNS`."""
    return read_csv_table(path, PREDICTION_COLUMNS)


def model_scaled_coverage(frames: pd.DataFrame, predictions: pd.DataFrame) -> pd.DataFrame:
    """Per round, set and row of ``predictions`` (an evaluation's predictions.csv: each window's estimate) and per
    camera model of the set, the coverage of the pose covariance scaled to the row's estimate
    (:func:`seesys.core.pose_covariance.scaled_to_error`): the share of labels within its 1σ and 2σ, that is at most
    the estimate and twice it, on the windows whose end frame's pair has a covariance; beside them the share a
    Gaussian of each pair's covariance puts there (a scale does not change it) and the median label / estimate."""
    paired = frames.dropna(subset=[PAIR_SIGMA])[["run", "frame_index", *GAUSSIAN_WITHIN, "camera_model"]]
    joined = predictions.merge(paired, on=["run", "frame_index"], how="inner", validate="many_to_one")
    joined = joined[np.isfinite(joined.estimate_m) & (joined.estimate_m > 0)]
    rows = []
    for (r, name, row), part in joined.groupby(["round", "set", "row"], sort=False):
        for camera, group in [("all", part)] + [(str(c), g) for c, g in part.groupby("camera_model")]:
            ratio = (group.true_m / group.estimate_m).to_numpy(float)
            rows.append(
                {
                    "round": r,
                    "set": name,
                    "row": row,
                    "camera_model": camera,
                    "runs": group.run.nunique(),
                    "windows": len(group),
                    "within_1sigma": float(np.mean(ratio <= 1)),
                    "within_2sigma": float(np.mean(ratio <= 2)),
                    "gaussian_1sigma": float(group[GAUSSIAN_WITHIN[0]].mean()),
                    "gaussian_2sigma": float(group[GAUSSIAN_WITHIN[1]].mean()),
                    "median_label_over_estimate": float(np.median(ratio)),
                }
            )
    return pd.DataFrame(rows)


COVERAGE_CSV = "covariance_coverage.csv"
COVERAGE_MD = "covariance_coverage.md"
MODEL_SCALED_CSV = "model_scaled_coverage.csv"


def _shown(table: pd.DataFrame) -> str:
    return table.assign(**{c: table[c].round(3) for c in table.columns if table[c].dtype.kind == "f"}).to_markdown(
        index=False
    )


def write_coverage_report(
    table: pd.DataFrame, out: Path, notes: list[str], model_scaled: pd.DataFrame | None = None
) -> Path:
    """``covariance_coverage.csv`` and ``covariance_coverage.md`` (the table, each set pooled over its camera
    models first) in ``out`` (created); with ``model_scaled`` (:func:`model_scaled_coverage`) also
    ``model_scaled_coverage.csv`` and its table in the report."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / COVERAGE_CSV, index=False)
    text = (
        "# The predicted pose covariance as an uncertainty of the label\n\n"
        + "".join(f"- {n}\n" for n in notes)
        + "- Per round and test set (and per camera model of it): the share of labels within 1σ and 2σ of the pair's "
        "predicted σ as the monitor computes it, the share a Gaussian of each frame's covariance puts there, the "
        "median label / σ, and the shares with σ times the scale fitted on the round's training runs (`scale`).\n\n"
        + _shown(table)
        + "\n"
    )
    if model_scaled is not None:
        model_scaled.to_csv(out / MODEL_SCALED_CSV, index=False)
        text += (
            "\n## Scaled to each row's estimate\n\n"
            "The covariance scaled so that the pair's σ is the row's estimate of the window ending at the frame: the "
            "share of labels within 1σ and 2σ (at most the estimate, twice it), a Gaussian's share, and the median "
            "label / estimate.\n\n" + _shown(model_scaled) + "\n"
        )
    path = out / COVERAGE_MD
    path.write_text(text)
    return path
