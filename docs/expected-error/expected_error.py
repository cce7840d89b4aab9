"""How well one ORB-SLAM3 trial's error can be known from the render at all, against the motion row.

Every sequence of BUILD was tracked n ≥ 3 times (`seesys dataset build --trials n`). For each run, the estimate
"k other trials" is the mean true error of k of the other trials of the same render at the same window end (the
dataset's ceiling row takes all of them, :func:`estimator.deepsee.references.ceiling_estimates`); the k trials are
the next k in a fixed cyclic order of the sequence's runs, so every trial is used as often. As k grows this
estimate tends to the error the render and trajectory lead ORB-SLAM3 to on average: what knowing the scene, the
motion and SLAM's behaviour perfectly tells, short of this trial's own chance (which a model reading the trial's own
tracking may still see).

Beside it, on the same windows (those where every other trial labelled the window's end frame) and the same 1/3 s
bins:
- the motion row, fitted per room on the build's other rooms (leave one room out, as on a held-out room);
- the served model (``data/models/forest.onnx`` or MODEL), which was trained on other trajectories of these rooms.
A constant's κ and AURG are 0 by definition and are not printed. First, each render's labels per trial (median,
p99 and largest 10-frame error), which show how far the trials' tails part.

κ, AURG, Spearman ρ and partial ρ given motion, with bootstrap intervals over runs, and each row's paired difference
from the motion row (the same resampled runs for both), as `seesys estimator evaluate` computes them.

    .venv/bin/python docs/expected-error/expected_error.py BUILD --scores scores.csv [--model MODEL]

``--scores`` also writes every figure printed (set, row, yardstick, its interval, and each row's paired difference
from the motion row) to a CSV file.
"""

import argparse
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.store import WITH_SAMPLES, DatasetReader, list_runs
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import Windows, reader_windows
from estimator.deepsee.metrics import bootstrap_settings, judged
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import MOTION_ISOTONIC, fit_references, motion_statistic, other_trials
from estimator.deepsee.yardsticks import Bootstrap, Judged, bootstrap_over_runs, paired_differences, yardsticks
from seesys.core.labels import LabelStatus
from seesys.io.core_settings import load_pulse_settings

NAMES = ("kappa", "aurg", "partial_spearman")
DIFFERENCES = ("kappa", "aurg")
SERVED = "served_model"


def judge_rows(
    rows: dict[str, Judged], settings: Bootstrap, classes: int, large_error_m: float, where: dict[str, str]
) -> list[dict[str, object]]:
    """Print each row's yardsticks, with their intervals over runs, and each other row's paired difference from the
    motion row's; return them as records (``where`` says the set) for the scores file."""

    def score(j: Judged) -> dict[str, float]:
        return yardsticks(j, classes, large_error_m)

    records: list[dict[str, object]] = []
    print(f"  {'row':20s} {'κ':>22s} {'AURG':>22s} {'partial ρ':>22s} {'ρ':>6s} agreement median ratio")
    for name, j in rows.items():
        point = score(j)
        interval, runs = bootstrap_over_runs(j, score, NAMES, settings)
        cells = [f"{point[n]:6.3f} [{interval[n][0]:6.3f}, {interval[n][1]:6.3f}]" for n in NAMES]
        print(
            f"  {name:20s} {' '.join(cells)} {point['spearman']:6.3f} {point['agreement']:9.3f}"
            f" {point['median_ratio']:12.3f}"
        )
        record: dict[str, object] = {**where, "row": name, "compared_with": "", "runs": runs, "windows": len(j.truth_m)}
        record.update(point)
        for n in NAMES:
            record[f"{n}_low"], record[f"{n}_high"] = interval[n]
        records.append(record)
    print("  minus the motion row, paired over runs:")
    for name, j in rows.items():
        if name == MOTION_ISOTONIC:
            continue
        point, interval = paired_differences(j, rows[MOTION_ISOTONIC], score, DIFFERENCES, settings)
        print(
            f"  {name:20s} Δκ {point['kappa']:+.3f} [{interval['kappa'][0]:+.3f}, {interval['kappa'][1]:+.3f}]"
            f"  ΔAURG {point['aurg']:+.3f} [{interval['aurg'][0]:+.3f}, {interval['aurg'][1]:+.3f}]"
        )
        record = {**where, "row": name, "compared_with": MOTION_ISOTONIC, "runs": len(set(j.window_run))}
        for n in DIFFERENCES:
            record[n], (record[f"{n}_low"], record[f"{n}_high"]) = point[n], interval[n]
        records.append(record)
    return records


def arguments(description: str) -> argparse.Namespace:
    """BUILD, --scores and --model, the same for every script of this folder."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("build", type=Path, help="a dataset build whose renders were tracked three or more times")
    parser.add_argument("--scores", type=Path, required=True, help="CSV file for every figure printed")
    parser.add_argument("--model", type=Path, default=Path("data/models/forest.onnx"), help="the served model")
    return parser.parse_args()


def run_table(build: Path) -> pd.DataFrame:
    """Each run with samples: its rendered sequence, room and camera model (indexed by run)."""
    infos = [info for info in list_runs(build) if info.status in WITH_SAMPLES]
    what = [(i.sequence, i.environment, i.camera_model) for i in infos]
    return pd.DataFrame(what, index=[i.run for i in infos], columns=["sequence", "room", "camera"])


def held_out_sets(
    windows: Windows, what: pd.DataFrame, ceiling: np.ndarray
) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """Each room of ``windows``, then each camera model (``what``: :func:`run_table`): the set's name ("held-out room
    lab"), the indices of the other rooms' (cameras') windows to train on, and of this one's windows where ``ceiling``
    has a value to judge on; prints the set's sizes."""
    runs = windows.meta.run
    for kind in ("room", "camera"):
        of_window = runs.map(what[kind]).to_numpy()
        for value in sorted(set(of_window)):
            train = np.flatnonzero(of_window != value)
            test = np.flatnonzero((of_window == value) & np.isfinite(ceiling))
            name = f"held-out {kind} {value}"
            print(
                f"\n{name}: trained on {runs.iloc[train].nunique()} runs, judged on {runs.iloc[test].nunique()} runs, "
                f"{len(test)} windows"
            )
            yield name, train, test


def other_trial_labels(build: Path) -> tuple[pd.Series, dict[str, list[str]]]:
    """Labelled frames (run, frame_index → error_m) and each run's other trials in cyclic order after it."""
    cyclic = {}
    for run, others in other_trials([build]).items():
        runs = sorted([run, *others])
        i = runs.index(run)
        cyclic[run] = runs[i + 1 :] + runs[:i]
    labels = DatasetReader([build]).frame_labels()
    labels = labels[labels.status == LabelStatus.LABELLED.value].set_index(["run", "frame_index"]).error_m
    return labels, cyclic


def print_trial_tails(labels: pd.Series, what: pd.DataFrame) -> None:
    """Each render's labels, trial by trial: median, p99 and largest, in mm."""
    per_run = labels.groupby(level="run")
    figures = {"median": per_run.median(), "p99": per_run.quantile(0.99), "largest": per_run.max()}
    print("labels per render, trial by trial (mm):")
    for sequence, runs in what.groupby("sequence").groups.items():
        runs = sorted(runs)
        cells = [" ".join(f"{1000 * figures[f].get(r, np.nan):7.1f}" for r in runs) for f in figures]
        print(f"  {sequence:26s} ({what.camera[runs[0]]:9s}) " + " | ".join(f"{f} {c}" for f, c in zip(figures, cells)))


def main() -> None:
    args = arguments("The mean error of other SLAM trials of the same render against the motion row")
    build, model = args.build, args.model
    config, pulses = load_estimator_config(), load_pulse_settings()
    settings = bootstrap_settings(config.evaluation)
    labels, cyclic = other_trial_labels(build)
    what = run_table(build)
    trials = 1 + min(len(others) for others in cyclic.values())
    if trials < 3:
        raise SystemExit(f"{build}: every sequence needs 3 or more trials, the fewest here is {trials}")

    windows = reader_windows(DatasetReader([build], usable_only=True))
    meta = windows.meta
    frames = meta.frame_index.to_numpy()
    other = np.full((trials - 1, len(windows)), np.nan)
    for run, rows in meta.groupby("run", sort=False).groups.items():
        rows = np.asarray(rows)
        for k, o in enumerate(cyclic[run][: trials - 1]):
            if o in labels.index.get_level_values(0):
                other[k, rows] = labels.loc[o].reindex(frames[rows]).to_numpy()
    keep = np.isfinite(other).all(axis=0)

    estimates = {MOTION_ISOTONIC: np.full(len(windows), np.nan)}
    window_room = meta.run.map(what.room).to_numpy()
    for environment in sorted(set(window_room)):
        held = window_room == environment
        references = fit_references(windows.subset(np.flatnonzero(~held)), pulses)
        estimates[MOTION_ISOTONIC][held] = references.estimates(windows.subset(np.flatnonzero(held)))[MOTION_ISOTONIC]
    predictor = load_predictor(model, LabelTransform(config.label_transform.k), config.evaluation.batch_size)
    estimates[SERVED] = predictor.metres(windows)
    for k in range(1, trials):
        estimates[f"{k} other trial{'s' if k > 1 else ''}"] = other[:k].mean(axis=0)

    print_trial_tails(labels, what)
    index = np.flatnonzero(keep)
    kept = meta.iloc[index].reset_index(drop=True)
    truth, motion = windows.error_m[index], motion_statistic(windows.rts[index])
    print(
        f"{build}: {kept.run.nunique()} runs of {kept.run.map(what.sequence).nunique()} renders, "
        f"{trials} trials each; {len(index)} of {len(windows)} windows have every other trial's label; "
        f"rooms {', '.join(sorted(set(window_room)))}; served model {model}"
    )

    sets = {"all runs": np.ones(len(kept), bool)}
    for kind in ("room", "camera"):
        of_window = kept.run.map(what[kind]).to_numpy()
        sets.update({f"{kind} {v}": of_window == v for v in sorted(set(of_window))})
    kept_estimates = {name: values[index] for name, values in estimates.items()}
    records = []
    for label, mask in sets.items():
        chosen = np.flatnonzero(mask)
        part = {
            name: judged(kept.iloc[chosen], values[chosen], truth[chosen], motion[chosen], pulses)
            for name, values in kept_estimates.items()
        }
        print(f"\n{label} ({kept.run.iloc[chosen].nunique()} runs, {len(chosen)} windows)")
        records += judge_rows(part, settings, pulses.max_pulses + 1, config.evaluation.large_error_m, {"set": label})
    pd.DataFrame(records).to_csv(args.scores, index=False)


if __name__ == "__main__":
    main()
