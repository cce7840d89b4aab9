"""Every trained row of every round on its round's test data, and on out-of-domain sessions.

Runs folder layout (``seesys estimator train-table``): ``RUNS/round_<r>/<row>/`` with ``model.pt`` (DeepSEE, the
ablations, the LSTM) or ``model.pkl`` (random forest). The test runs of a round are judged in two sets, never
mixed: the *test trajectories* in the training environments, and the *held-out environments* (scenes no model
saw); with held-out camera models (leave-one-camera-out splits), each held-out camera is a set of its own,
``held-out camera NAME``, taken out of the other two. Labelled session folders given as out-of-domain data (another
renderer, a real camera) are a third set, judged by every round's model; with more than one session, each is also a
set of its own, ``session NAME`` (its folder's name), so sessions of different cameras are not only seen pooled.

Every set is also judged for the reference rows of :mod:`estimator.deepsee.references` (a constant class, always
the top class, the motion alone; fitted on the round's training windows) and, where a run's sequence or a session's
source was tracked more than once, the ceiling (another trial's true error), on the same windows and bins as the
models. Beside the scores: the median ratio per camera model of each set and row (``cameras``), and the reliability
diagram, Brier score and ECE of each head threshold (``calibration``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.splits import PARTS, Lockbox, Splits, run_table, set_indices
from estimator.dataset.store import DatasetReader
from estimator.deepsee.channels import RawSet, channel_table, choose_features
from estimator.deepsee.config import EstimatorConfig
from estimator.deepsee.data import (
    Windows,
    concat,
    normalised,
    reader_windows,
    session_raw_windows,
    split_readers,
)
from estimator.deepsee.metrics import bootstrap_settings, equation2_head, judged, score
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import (
    CEILING,
    MOTION_ISOTONIC,
    ceiling_estimates,
    fit_references,
    motion_statistic,
    session_ceiling_estimates,
)
from estimator.deepsee.rows import DEEPSEE, RANDOM_FOREST, ROWS
from estimator.deepsee.run_folder import MODEL_PT
from estimator.deepsee.stages import FOREST_PICKLE
from estimator.deepsee.yardsticks import (
    Bootstrap,
    Judged,
    calibration,
    median_ratio,
    paired_differences,
    yardsticks,
)
from seesys.core.equation2 import PulseSettings
from seesys.core.errors import SeesysError
from seesys.core.exceedance import class_boundaries_m
from seesys.core.windows import WindowConfig

OUT_OF_DOMAIN = "out-of-domain sessions"


def round_folder(runs: Path, round_index: int) -> Path:
    return Path(runs) / f"round_{round_index}"


def model_file(folder: Path) -> Path | None:
    for name in (MODEL_PT, FOREST_PICKLE):
        if (folder / name).is_file():
            return folder / name
    return None


@dataclass
class Evaluation:
    scores: pd.DataFrame  # one row per (set, row, round): the Scores fields
    predictions: pd.DataFrame  # one row per window: set, row, round, run, frame_index, timestamp, true_m, estimate_m
    runs: Path
    cameras: pd.DataFrame  # one row per (set, row, round, camera model): windows, median ratio
    calibration: pd.DataFrame  # one row per (set, row, round, head threshold, probability bin): reliability
    channels: pd.DataFrame  # one row per (set, round, channel, window feature): the channel alone (channels.py)
    differences: pd.DataFrame  # one row per (set, round, row, compared row): paired differences (COMPARED)


def session_set(name: str) -> str:
    return f"session {name}"


def session_raw_sets(sessions: list[Path], windows: WindowConfig) -> dict[str, Windows]:
    """The out-of-domain sets of labelled session folders, their RTS raw (:func:`session_raw_windows`): all pooled,
    and each alone when there are several."""
    if not sessions:
        return {}
    names = [Path(s).name for s in sessions]
    if len(set(names)) != len(names):
        raise SeesysError(
            f"two out-of-domain sessions share a folder name ({', '.join(names)}): each is reported "
            "under its folder's name, give folders with distinct names"
        )
    each = [session_raw_windows(s, windows, labelled=True) for s in sessions]
    sets = {OUT_OF_DOMAIN: concat(each)}
    if len(each) > 1:
        sets.update({session_set(name): data for name, data in zip(names, each)})
    return sets


@dataclass
class _Tables:
    """What :func:`judge` collects, row by row."""

    scores: list = field(default_factory=list)
    predictions: list = field(default_factory=list)
    cameras: list = field(default_factory=list)
    calibration: list = field(default_factory=list)
    channels: list = field(default_factory=list)
    differences: list = field(default_factory=list)


def prediction_table(key: dict, data: Windows, estimate_m: np.ndarray) -> pd.DataFrame:
    """One row per window of ``data``: ``key`` (set, row, round), the window's run, frame and time, its true error
    and ``estimate_m``: the rows of ``predictions.csv``."""
    return pd.DataFrame(
        {
            **key,
            "run": data.meta.run.to_numpy(),
            "frame_index": data.meta.frame_index.to_numpy(),
            "timestamp": data.meta.timestamp.to_numpy(),
            "true_m": data.error_m,
            "estimate_m": estimate_m,
        }
    )


def predicted_estimates(predictions: pd.DataFrame, key: dict, data: Windows) -> np.ndarray:
    """The estimates of ``predictions`` (rows of ``predictions.csv``) under ``key`` (set, row, round) for the windows
    of ``data``, in their order: what :func:`prediction_table` wrote, read back. Raises :class:`SeesysError` when a
    window has no estimate there or its true error is not the one written (the predictions are of another build)."""
    chosen = predictions[(predictions[list(key)] == pd.Series(key)).all(axis=1)]
    found = data.meta[["run", "frame_index"]].merge(chosen, on=["run", "frame_index"], how="left")
    if found.estimate_m.isna().any() or not np.allclose(found.true_m, data.error_m):
        described = ", ".join(f"{name} {value}" for name, value in key.items())
        raise SeesysError(f"the predictions of {described} are not of these windows (another build or splits?)")
    return found.estimate_m.to_numpy(float)


def judge(
    tables: _Tables,
    key: dict,
    data: Windows,
    estimate_m: np.ndarray,
    probabilities: np.ndarray | None,
    motion: np.ndarray,
    config: EstimatorConfig,
    pulses: PulseSettings,
) -> None:
    """Score one row's estimates of one set (``key``: set, row, round) into ``tables``."""
    tables.scores.append(
        {**key, **asdict(score(data.meta, estimate_m, data.error_m, config.evaluation, pulses, probabilities, motion))}
    )
    tables.predictions.append(prediction_table(key, data, estimate_m))
    if "camera_model" in data.meta and len(data):
        for camera, rows in data.meta.groupby("camera_model").groups.items():
            rows = np.asarray(rows)
            tables.cameras.append(
                {
                    **key,
                    "camera_model": camera,
                    "windows": len(rows),
                    "median_ratio": median_ratio(estimate_m[rows], data.error_m[rows]),
                }
            )
    if probabilities is not None:
        for k, threshold in enumerate(class_boundaries_m(pulses)):
            fit = calibration(probabilities[:, k], data.error_m, threshold)
            tables.calibration.append(
                pd.DataFrame(
                    {
                        **key,
                        "threshold_m": threshold,
                        "brier": fit.brier,
                        "ece": fit.ece,
                        "confidence": fit.confidence,
                        "observed": fit.observed,
                        "windows": fit.count,
                    }
                )
            )


@dataclass(frozen=True)
class _Judging:
    """What judging one round's sets needs besides the sets."""

    roots: list[Path]
    config: EstimatorConfig
    pulses: PulseSettings
    windows: WindowConfig
    device: torch.device


def _judge_round(
    tables: _Tables,
    r: int,
    sets: dict[str, Windows],
    ceilings: dict[str, np.ndarray],
    train: Windows,
    models: list[tuple[str, Path]],
    how: _Judging,
) -> None:
    """The reference rows (fitted on ``train``), the ceiling (``ceilings``: per set, each window's estimate by the
    other trials, NaN where there is none; a set without an entry has no ceiling row) and every model of ``models``
    ((row name, model file)) on every set of round ``r``."""
    config, pulses = how.config, how.pulses
    transform = LabelTransform(config.label_transform.k)
    motion = {name: motion_statistic(data.rts) for name, data in sets.items()}
    references = fit_references(train, pulses)
    # Every row's estimates by set, for the paired comparisons once all are made.
    estimated: dict[str, dict[str, np.ndarray]] = {}
    for name, data in sets.items():
        estimated[name] = references.estimates(data)
        for row_name, estimate in estimated[name].items():
            judge(
                tables, {"set": name, "row": row_name, "round": r}, data, estimate, None, motion[name], config, pulses
            )
        if name in ceilings:
            ceiling = ceilings[name]
            kept = np.flatnonzero(np.isfinite(ceiling))
            if len(kept):
                judge(
                    tables,
                    {"set": name, "row": CEILING, "round": r},
                    data.subset(kept),
                    ceiling[kept],
                    None,
                    motion[name][kept],
                    config,
                    pulses,
                )
    for row_name, path in models:
        predictor = load_predictor(path, transform, config.evaluation.batch_size, how.device, how.windows)
        for name, data in sets.items():
            estimates = predictor.estimates(data)
            estimated[name][row_name] = estimates.metres
            head = equation2_head(estimates.probabilities, predictor.thresholds_m, pulses)
            judge(
                tables,
                {"set": name, "row": row_name, "round": r},
                data,
                estimates.metres,
                head,
                motion[name],
                config,
                pulses,
            )
    for name, data in sets.items():
        _compare(
            tables, {"set": name, "round": r}, data, estimated[name], [row for row, _ in models], motion[name], how
        )


#: The rows every trained row is compared with, run by run: the motion alone and the forest.
COMPARED = (MOTION_ISOTONIC, RANDOM_FOREST)
#: The yardsticks of a paired comparison.
DIFFERENCES = ("kappa", "aurg", "aurg_capped", "spearman", "partial_spearman")


def _difference_columns() -> list[str]:
    return [f"{name}{suffix}" for name in DIFFERENCES for suffix in ("", "_low", "_high")]


def paired_difference_values(
    a: Judged, b: Judged, classes: int, large_error_m: float, settings: Bootstrap
) -> dict[str, float]:
    """:data:`DIFFERENCES` of row ``a`` minus row ``b`` on the same windows and bins, each with its interval over
    runs (``<name>_low``, ``<name>_high``; :func:`estimator.deepsee.yardsticks.paired_differences`): one row of the
    differences table."""

    def statistic(j: Judged) -> dict[str, float]:
        return yardsticks(j, classes, large_error_m)

    points, intervals = paired_differences(a, b, statistic, DIFFERENCES, settings)
    values = {}
    for name in DIFFERENCES:
        values[name] = points[name]
        values[f"{name}_low"], values[f"{name}_high"] = intervals[name]
    return values


def _compare(
    tables: _Tables,
    key: dict,
    data: Windows,
    estimated: dict[str, np.ndarray],
    trained: list[str],
    motion: np.ndarray,
    how: _Judging,
) -> None:
    """Each trained row minus each row of :data:`COMPARED` on the same windows, with the interval of the difference
    over runs (:func:`paired_difference_values`)."""
    if not len(data):
        return
    evaluation, pulses = how.config.evaluation, how.pulses
    # Each row's windows and bins once, however many comparisons it is in.
    rows = {
        row: judged(data.meta, estimated[row], data.error_m, motion, pulses)
        for row in (*trained, *COMPARED)
        if row in estimated
    }
    for row in trained:
        for against in COMPARED:
            if row == against or against not in rows:
                continue
            values = paired_difference_values(
                rows[row],
                rows[against],
                pulses.max_pulses + 1,
                evaluation.large_error_m,
                bootstrap_settings(evaluation),
            )
            tables.differences.append({**key, "row": row, "against": against, **values})


def raw_set(reader: DatasetReader) -> RawSet:
    """A reader's usable windows as the channel table reads them (raw RTS), in the order of
    :func:`estimator.deepsee.data.reader_windows`'s windows of the same reader."""
    return RawSet(
        reader.rts_windows(), reader.index.error_m.to_numpy(np.float64), reader.index.run.to_numpy().astype(str)
    )


def _judge_channels(tables: _Tables, r: int, sets: dict[str, RawSet], train: RawSet, how: _Judging) -> None:
    """The geometry channels alone on every set of round ``r`` (``sets``: raw RTS), each by its window feature
    chosen on the round's training windows ``train``."""
    chosen = choose_features(train)
    for name, data in sets.items():
        if len(data.error_m):
            table = channel_table(data, chosen, bootstrap_settings(how.config.evaluation))
            tables.channels.append(table.assign(set=name, round=r))


def _evaluation(tables: _Tables, runs: Path) -> Evaluation:
    calibrated = (
        pd.concat(tables.calibration, ignore_index=True)
        if tables.calibration
        else pd.DataFrame(
            columns=["set", "row", "round", "threshold_m", "brier", "ece", "confidence", "observed", "windows"]
        )
    )
    return Evaluation(
        pd.DataFrame(tables.scores),
        pd.concat(tables.predictions, ignore_index=True),
        Path(runs),
        pd.DataFrame(tables.cameras, columns=["set", "row", "round", "camera_model", "windows", "median_ratio"]),
        calibrated,
        pd.concat(tables.channels, ignore_index=True) if tables.channels else pd.DataFrame(columns=["set", "round"]),
        pd.DataFrame(tables.differences, columns=["set", "round", "row", "against", *_difference_columns()]),
    )


def evaluate(
    roots: list[Path],
    splits: Splits,
    runs: Path,
    rounds: list[int],
    sessions: list[Path],
    config: EstimatorConfig,
    pulses: PulseSettings,
    windows: WindowConfig,
    device: torch.device,
) -> Evaluation:
    other_raw = session_raw_sets(sessions, windows)
    other = {name: normalised(raw) for name, raw in other_raw.items()}
    other_channels = {
        name: RawSet(raw.rts, raw.error_m, raw.meta.run.to_numpy().astype(str)) for name, raw in other_raw.items()
    }
    # The sessions' ceilings do not depend on the round: the same windows, the same other trials.
    session_ceilings = {name: session_ceiling_estimates(sessions, data) for name, data in other.items()}
    tables = _Tables()
    how = _Judging([Path(r) for r in roots], config, pulses, windows, device)
    for r in rounds:
        folder = round_folder(runs, r)
        trained = [(row.name, path) for row in ROWS if (path := model_file(folder / row.name)) is not None]
        if not trained:
            raise SeesysError(f"no trained model under {folder} (train the round with `seesys estimator train-table`)")
        readers = split_readers(roots, splits, r, ("train", "test"))
        parts = {part: reader_windows(reader) for part, reader in readers.items()}
        environments, cameras = splits.heldout(r)
        index = set_indices(parts["test"].meta, environments, cameras)
        sets = {name: parts["test"].subset(rows) for name, rows in index.items()}
        ceilings = {name: ceiling_estimates(how.roots, data) for name, data in sets.items()} | session_ceilings
        sets.update(other)
        _judge_round(tables, r, sets, ceilings, parts["train"], trained, how)
        test = raw_set(readers["test"])
        raw_sets = {name: test.subset(rows) for name, rows in index.items()} | other_channels
        _judge_channels(tables, r, raw_sets, raw_set(readers["train"]), how)
    return _evaluation(tables, runs)


LOCKBOX = "lockbox"


def _fresh_lockbox(splits: Splits, fresh: list[Path]) -> Lockbox:
    """The lockbox of ``splits`` holding the runs of the ``fresh`` folders instead of its own. Raises
    :class:`SeesysError` when the splits define no lockbox, or a fresh run is of another room and camera (it would
    not be a lockbox run) or is already a run of the splits (it is not new)."""
    box = splits.lockbox
    if box is None:
        raise SeesysError("these splits define no lockbox (made before the lockbox): a fresh one cannot be judged")
    runs = run_table(fresh)
    outside = runs.run[(runs.environment != box.environment) & (runs.camera_model != box.camera_model)]
    if len(outside):
        raise SeesysError(
            f"fresh run {outside.iloc[0]} is neither in the lockbox's room {box.environment} nor through its camera "
            f"{box.camera_model}: it is not a lockbox run"
        )
    known = set(box.runs).union(*(getattr(r, part) for r in splits.rounds for part in (*PARTS, "excluded")))
    seen = sorted(known.intersection(runs.run))
    if seen:
        raise SeesysError(f"fresh run {seen[0]} is a run of the splits already: a fresh lockbox holds new renders only")
    return Lockbox(box.environment, box.camera_model, box.sha256, sorted(runs.run))


def evaluate_lockbox(
    roots: list[Path],
    splits: Splits,
    model: Path,
    round_index: int,
    config: EstimatorConfig,
    pulses: PulseSettings,
    windows: WindowConfig,
    device: torch.device,
    row: str = DEEPSEE,
    fresh: list[Path] | None = None,
) -> Evaluation:
    """``model`` (a shipped model, trained on round ``round_index`` of ``splits``; named ``row`` in the tables) on
    the lockbox's runs: all of them, those of its room and those through its camera, beside the reference rows
    fitted on that round's training windows and the ceiling.

    With ``fresh`` (dataset folders of new renders), the lockbox judged is their runs instead of the splits' own:
    a fresh lockbox, for when the build's lockbox runs have been judged once already. Raises :class:`SeesysError`
    when there is no lockbox run to judge, and when a fresh run is outside the lockbox's room and camera or is a
    run of the splits."""
    box = splits.lockbox
    if fresh:
        box = _fresh_lockbox(splits, fresh)
    if box is None or not box.runs:
        raise SeesysError(
            "these splits hold no lockbox runs (made before the lockbox, or the build has none of its "
            "room and camera): there is nothing to judge"
        )
    reader = DatasetReader(list(fresh) if fresh else roots, runs=box.runs, usable_only=True)
    data = reader_windows(reader)
    index = {
        LOCKBOX: np.arange(len(data)),
        f"{LOCKBOX} room {box.environment}": np.flatnonzero((data.meta.environment == box.environment).to_numpy()),
        f"{LOCKBOX} camera {box.camera_model}": np.flatnonzero((data.meta.camera_model == box.camera_model).to_numpy()),
    }
    index = {name: rows for name, rows in index.items() if len(rows)}
    sets = {name: data.subset(rows) for name, rows in index.items()}
    train_reader = split_readers(roots, splits, round_index, ("train",))["train"]
    tables = _Tables()
    how = _Judging([Path(r) for r in [*roots, *(fresh or [])]], config, pulses, windows, device)
    ceilings = {name: ceiling_estimates(how.roots, data) for name, data in sets.items()}
    _judge_round(tables, round_index, sets, ceilings, reader_windows(train_reader), [(row, Path(model))], how)
    raw = raw_set(reader)
    raw_sets = {name: raw.subset(rows) for name, rows in index.items()}
    _judge_channels(tables, round_index, raw_sets, raw_set(train_reader), how)
    return _evaluation(tables, Path(model).parent)
