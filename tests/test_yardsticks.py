"""The yardsticks that do not reward the base rate (estimator/deepsee/yardsticks.py) and the reference rows
(estimator/deepsee/references.py), each against a hand computation on a few windows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import Windows
from estimator.deepsee.evaluate import predicted_estimates, prediction_table
from estimator.deepsee.metrics import advisory_bins, score
from estimator.deepsee.references import (
    ALWAYS_TOP,
    CONSTANT,
    MOTION_ISOTONIC,
    fit_references,
    motion_statistic,
)
from estimator.deepsee.yardsticks import (
    Bootstrap,
    Judged,
    bootstrap_over_runs,
    calibration,
    capped_aurg,
    paired_differences,
    partial_spearman,
    quadratic_kappa,
    sparsification,
    yardsticks,
)
from seesys.core import rts_schema
from seesys.core.errors import SeesysError
from seesys.io.core_settings import load_pulse_settings

PULSES = load_pulse_settings()
EVALUATION = load_estimator_config().evaluation


def test_quadratic_kappa_by_hand():
    truth = np.array([0, 1, 2, 3])
    assert quadratic_kappa(truth, truth, 4) == 1.0
    # Every constant class is chance: κ 0, whatever its agreement.
    for c in range(4):
        assert quadratic_kappa(np.array([0, 3, 3, 3]), np.full(4, c), 4) == pytest.approx(0.0)
    # truth 0,0,1,1 against 0,1,1,1 (2 classes, weights (i − j)²): observed disagreement 1/4; the marginals
    # (1/2, 1/2) and (1/4, 3/4) expect 1/2 · 3/4 + 1/2 · 1/4 = 1/2; κ = 1 − (1/4) / (1/2) = 1/2.
    assert quadratic_kappa(np.array([0, 0, 1, 1]), np.array([0, 1, 1, 1]), 2) == pytest.approx(0.5)
    # Off by two classes costs four times off by one.
    near = quadratic_kappa(np.array([0, 1, 2, 3]), np.array([1, 1, 2, 3]), 4)
    far = quadratic_kappa(np.array([0, 1, 2, 3]), np.array([2, 1, 2, 3]), 4)
    assert far < near < 1
    assert np.isnan(quadratic_kappa(np.zeros(3, int), np.zeros(3, int), 4))


def test_quadratic_kappa_is_scikit_learns():
    from sklearn.metrics import cohen_kappa_score

    rng = np.random.default_rng(2)
    for n in (2, 5, 60, 1000):
        for _ in range(30):
            truth = rng.integers(0, 5, size=n)
            estimate = np.clip(truth + rng.integers(-2, 3, size=n), 0, 6)  # classes 5 and 6 are outside the 5 asked
            inside = estimate < 5
            if len(set(truth[inside]) | set(estimate[inside])) < 2:
                continue  # 0 / 0: NaN here, scikit-learn's warning
            reference = cohen_kappa_score(truth, estimate, labels=list(range(5)), weights="quadratic")
            assert quadratic_kappa(truth, estimate, 5) == pytest.approx(reference, abs=1e-12)


def test_sparsification_by_hand():
    truth = np.arange(1.0, 101.0)
    # A perfect order (any increasing function of the truth): AUSE 0; it removes the largest errors first.
    ause, aurg = sparsification(np.log(truth), truth)
    assert ause == pytest.approx(0.0, abs=1e-12) and aurg > 0.4
    # A constant: every window is one tie, the curve stays at 1: AURG exactly 0.
    ause, aurg = sparsification(np.ones(100), truth)
    assert aurg == pytest.approx(0.0, abs=1e-12) and ause > 0.4
    # The reversed order is worse than random.
    assert sparsification(-truth, truth)[1] < 0
    # Four windows, truth 1, 2, 3, 6 (mean 3), with S = 100 removed fractions: the oracle keeps all 4 for the
    # first 25 fractions (mean 3), 3 windows (1, 2, 3: mean 2), then 2 (1.5), then 1 (1); normalised by 3 its mean
    # is (3 + 2 + 1.5 + 1) / 4 / 3 = 0.625. An estimate that swaps the two largest keeps 1, 2, 6 (mean 3) after the
    # first removal, so its curve is (3 + 3 + 1.5 + 1) / 4 / 3 and AUSE = (3 − 2) / 4 / 3 = 1/12.
    truth = np.array([1.0, 2.0, 3.0, 6.0])
    ause, aurg = sparsification(np.array([1.0, 2.0, 6.0, 3.0]), truth)
    assert ause == pytest.approx(1 / 12) and aurg == pytest.approx(1 - 8.5 / 12)


def test_aurg_to_the_top_class_is_not_decided_by_one_map_jump():
    """99 windows of 1-11 mm and one of 4 m (a map jump). A row that finds only the jump wins AURG, since the jump
    holds most of the summed error; a row that ranks the 99 right but the jump last loses it. Capped at the top
    class (12 mm) the jump counts as 12 mm, and the row that ranks what the advisory tells apart wins."""
    truth = np.append(np.linspace(0.001, 0.011, 99), 4.0)
    finds_the_jump = np.append(np.zeros(99), 1.0)
    ranks_the_rest = np.append(np.linspace(0.001, 0.011, 99), 0.0)
    assert sparsification(finds_the_jump, truth)[1] > 0.8 > 0.0 > sparsification(ranks_the_rest, truth)[1]
    assert capped_aurg(ranks_the_rest, truth, 0.012) > 0.2 > 0.02 > capped_aurg(finds_the_jump, truth, 0.012)
    assert capped_aurg(ranks_the_rest, truth, 0.012) == sparsification(ranks_the_rest, np.minimum(truth, 0.012))[1]
    empty = np.zeros(0)
    judged = Judged(
        np.zeros(100), truth, ranks_the_rest, truth, empty, empty, empty, empty.astype(int), empty.astype(int)
    )
    figures = yardsticks(judged, 4, 0.012)
    assert figures["aurg_capped"] == capped_aurg(ranks_the_rest, truth, 0.012) and figures["aurg"] < 0.0


def test_partial_spearman_removes_what_the_motion_explains():
    rng = np.random.default_rng(0)
    motion = rng.normal(size=2000)
    truth = motion + 0.1 * rng.normal(size=2000)
    copies_motion = motion + 0.01 * rng.normal(size=2000)
    sees_the_rest = truth - motion
    assert partial_spearman(copies_motion, truth, motion) < 0.15  # what it knows is the motion
    assert partial_spearman(sees_the_rest, truth, motion) > 0.5


def test_partial_spearman_is_pingouins_where_the_rank_correlations_are_invertible_and_defined_where_not():
    import pingouin  # the reference: the same partial correlation from its inverse correlation matrix

    rng = np.random.default_rng(1)
    compared = 0
    for n in (6, 40, 500):
        for _ in range(20):
            motion = rng.normal(size=n)
            truth = motion + rng.normal(size=n)
            estimate = np.round(truth + rng.normal(size=n), 1)  # with ties
            table = pd.DataFrame({"e": estimate, "t": truth, "m": motion})
            if np.linalg.det(table.rank().corr().to_numpy()) < 1e-6:
                continue  # singular: pingouin's pseudo-inverse is no reference there (below)
            reference = pingouin.partial_corr(table, x="e", y="t", covar="m", method="spearman")["r"].iloc[0]
            assert partial_spearman(estimate, truth, motion) == pytest.approx(reference, abs=1e-12)
            compared += 1
    assert compared >= 50
    truth, motion = rng.normal(size=100), rng.normal(size=100)
    assert partial_spearman(truth, truth, motion) == 1.0  # a perfect estimate
    assert partial_spearman(-truth, truth, motion) == -1.0
    assert np.isnan(partial_spearman(np.exp(motion), truth, motion))  # ranked as the motion: nothing left
    # Ranks 1..4 of the estimate, truth and motion with correlations -0.8, 0 and 0.6: a singular matrix whose partial
    # correlation is (-0.8 - 0 * 0.6) / sqrt(1 * (1 - 0.36)) = -1 exactly.
    estimate, truth, motion = np.array([1.0, 2, 3, 4]), np.array([4.0, 2, 3, 1]), np.array([3.0, 1, 4, 2])
    assert partial_spearman(estimate, truth, motion) == pytest.approx(-1.0)


def test_calibration_by_hand():
    # Two windows at p = 0.2 (one above the threshold) and two at p = 0.9 (both above): bins 0.2 → observed 0.5,
    # 0.9 → observed 1.0; ECE = 1/2 · |0.5 − 0.2| + 1/2 · |1.0 − 0.9| = 0.2;
    # Brier = (0.04 + 0.64 + 0.01 + 0.01) / 4.
    fit = calibration(np.array([0.2, 0.2, 0.9, 0.9]), np.array([0.001, 0.01, 0.02, 0.03]), 0.004)
    assert fit.ece == pytest.approx(0.2) and fit.brier == pytest.approx(0.7 / 4)
    np.testing.assert_allclose(fit.observed, [0.5, 1.0])
    np.testing.assert_allclose(fit.confidence, [0.2, 0.9])
    assert list(fit.count) == [2, 2]


def _meta(runs: int, windows_per_run: int) -> pd.DataFrame:
    """Windows 0.1 s apart in each run."""
    return pd.DataFrame(
        {
            "run": np.repeat([f"r{k}" for k in range(runs)], windows_per_run),
            "timestamp": np.tile(np.arange(windows_per_run) * 0.1, runs),
        }
    )


@pytest.mark.system
def test_score_of_a_perfect_and_of_a_constant_estimator():
    rng = np.random.default_rng(1)
    meta = _meta(6, 60)
    truth = rng.lognormal(np.log(0.008), 0.8, 6 * 60)
    motion = rng.normal(size=len(truth))
    perfect = score(meta, truth, truth, EVALUATION, PULSES, motion=motion)
    assert perfect.kappa == 1.0 and perfect.agreement == 1.0 and perfect.ause == pytest.approx(0.0, abs=1e-12)
    assert perfect.aurg > 0 and perfect.runs == 6
    assert perfect.kappa_low == perfect.kappa_high == 1.0  # every resample is perfect too
    constant = score(meta, np.full(len(truth), 0.009), truth, EVALUATION, PULSES, motion=motion)
    assert constant.kappa == pytest.approx(0.0) and constant.aurg == pytest.approx(0.0, abs=1e-12)
    bins = advisory_bins(meta, truth, truth, PULSES.window_s)
    assert constant.agreement == pytest.approx(np.mean([PULSES.pulses(t) == 2 for t in bins.truth]))
    assert constant.agreement_low <= constant.agreement <= constant.agreement_high


def test_bootstrap_over_runs_resamples_whole_runs():
    # Two runs: all of run a right, all of run b wrong. A resample of runs draws a, b or both: agreement 0, 1/2 or
    # 1 in whole runs' steps, never between (as a resample of bins would).
    judged = Judged(
        np.array(["a", "a", "b", "b"]),
        np.ones(4),
        np.ones(4),
        np.zeros(4),
        np.array(["a", "b"]),
        np.ones(2),
        np.ones(2),
        np.array([1, 1]),
        np.array([1, 0]),
    )
    seen = set()

    def statistic(j: Judged) -> dict[str, float]:
        value = float(np.mean(j.bin_true_class == j.bin_estimate_class))
        seen.add(value)
        return {"agreement": value}

    intervals, n = bootstrap_over_runs(judged, statistic, ("agreement",), Bootstrap(200, 0.95, 0))
    assert n == 2 and seen == {0.0, 0.5, 1.0} and intervals["agreement"] == (0.0, 1.0)
    single = dataclasses.replace(judged, window_run=np.array(["a"] * 4), bin_run=np.array(["a", "a"]))
    intervals, n = bootstrap_over_runs(single, statistic, ("agreement",), Bootstrap(200, 0.95, 0))
    assert n == 1 and all(np.isnan(intervals["agreement"]))


def test_a_paired_difference_resamples_the_same_runs_for_both_rows():
    # Three runs; estimator a right in runs a and b, wrong in c; estimator b wrong in a, right in b and c. Drawn
    # together, the difference of agreement is (right_a − right_b) / 3 over the drawn runs, from −1 (only c drawn)
    # to +1 (only a); drawn apart (two intervals side by side) the spread would come from both draws.
    runs = np.array(["a", "b", "c"])
    truth_class = np.array([1, 1, 1])
    a = Judged(
        runs, np.ones(3), np.ones(3), np.zeros(3), runs, np.ones(3), np.ones(3), truth_class, np.array([1, 1, 0])
    )
    b = dataclasses.replace(a, bin_estimate_class=np.array([0, 1, 1]))

    def statistic(j: Judged) -> dict[str, float]:
        return {"agreement": float(np.mean(j.bin_true_class == j.bin_estimate_class))}

    points, intervals = paired_differences(a, b, statistic, ("agreement",), Bootstrap(400, 0.95, 0))
    assert points["agreement"] == pytest.approx(0.0)
    low, high = intervals["agreement"]
    assert -1.0 <= low < 0 < high <= 1.0
    # The same estimates: every draw differs by exactly 0.
    points, intervals = paired_differences(a, a, statistic, ("agreement",), Bootstrap(50, 0.95, 0))
    assert points["agreement"] == 0 and intervals["agreement"] == (0.0, 0.0)
    # A row right everywhere against one wrong everywhere: the interval excludes 0.
    right = dataclasses.replace(a, bin_estimate_class=truth_class)
    wrong = dataclasses.replace(a, bin_estimate_class=np.zeros(3, int))
    _, intervals = paired_differences(right, wrong, statistic, ("agreement",), Bootstrap(50, 0.95, 0))
    assert intervals["agreement"] == (1.0, 1.0)


def _windows(motion_per_run: list[float], truth_per_run: list[float], windows_per_run: int = 30) -> Windows:
    """Windows whose relative translation alternates ±m along y (std m per frame) and whose truth is constant
    per run."""
    runs = len(motion_per_run)
    rts = np.zeros((runs * windows_per_run, 30, rts_schema.NUM_CHANNELS), np.float32)
    sign = np.where(np.arange(30) % 2 == 0, 1.0, -1.0)
    scale = rts_schema.CHANNELS[rts_schema.index_of("rel_ty")].scale
    for k, m in enumerate(motion_per_run):
        rts[k * windows_per_run : (k + 1) * windows_per_run, :, rts_schema.index_of("rel_ty")] = m * sign / scale
    truth = np.repeat(truth_per_run, windows_per_run).astype(float)
    return Windows(rts, None, truth, _meta(runs, windows_per_run))


def test_reference_rows_are_fitted_on_training_windows():
    train = _windows([0.001, 0.002, 0.004, 0.008], [0.003, 0.005, 0.009, 0.02])
    np.testing.assert_allclose(motion_statistic(train.rts)[::30], [0.001, 0.002, 0.004, 0.008], rtol=1e-5)
    refs = fit_references(train, PULSES)
    # Training bins' classes: 0, 1, 2, 3, one run each, ten bins each: a tie, the first (class 0) wins; its estimate
    # is the median of those bins' means.
    assert refs.constant_class == 0 and refs.constant_m == pytest.approx(0.003)
    test = _windows([0.0015, 0.008, 0.02], [0.004, 0.02, 0.05])
    estimates = refs.estimates(test)
    assert set(estimates) == {CONSTANT, ALWAYS_TOP, MOTION_ISOTONIC}
    np.testing.assert_allclose(estimates[ALWAYS_TOP], 0.012)
    # Isotonic: between the training points it interpolates (0.0015 → 0.004), beyond them it clips (0.02 → 0.02).
    np.testing.assert_allclose(estimates[MOTION_ISOTONIC][::30], [0.004, 0.02, 0.02], rtol=1e-6)
    top = yardsticks(
        Judged(
            np.zeros(1),
            np.zeros(1),
            np.zeros(1),
            np.zeros(1),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0, int),
            np.zeros(0, int),
        ),
        4,
        0.012,
    )
    assert np.isnan(top["agreement"]) and np.isnan(top["kappa"])


def test_the_ceiling_is_the_other_trials_truth_at_the_same_frame(tmp_path):
    """Two trials of one render (the same frames, different errors) and a third render tracked once."""
    from testkit.deepsee import write_session

    from estimator.dataset.build import label_run
    from estimator.dataset.store import COMPLETED, DatasetReader, RunInfo, write_run
    from estimator.deepsee.data import reader_windows
    from estimator.deepsee.references import ceiling_estimates
    from seesys.core import camera_normalisation
    from seesys.io.core_settings import load_label_config, load_window_config
    from slam_monitor.orbslam_settings import SlamMode

    root = tmp_path / "dataset"
    windows = dataclasses.replace(load_window_config(), end_stride=1)
    for name, seed in (("lab__traj__s0__rgbd__t0", 0), ("lab__traj__s0__rgbd__t1", 1), ("lab__once__s0__rgbd__t0", 2)):
        folder = write_session(tmp_path / "sessions" / name, seed=seed, frames=120)
        arrays = label_run(folder, SlamMode.RGBD, load_label_config(), windows)
        sequence, _, trial = name.rsplit("__", 2)
        write_run(
            root,
            RunInfo(
                name,
                sequence,
                "lab",
                "patrol",
                sequence.split("__")[1],
                "rgbd",
                int(trial[1:]),
                COMPLETED,
                frames=120,
                frames_tracked=120,
                samples=len(arrays.samples),
                camera_normalisation=camera_normalisation.VERSION,
            ),
            arrays,
        )
    data = reader_windows(
        DatasetReader([root], runs=["lab__traj__s0__rgbd__t0", "lab__once__s0__rgbd__t0"], usable_only=True)
    )
    ceiling = ceiling_estimates([root], data)
    other = DatasetReader([root], runs=["lab__traj__s0__rgbd__t1"]).frame_labels().set_index("frame_index").error_m
    twice = (data.meta.run == "lab__traj__s0__rgbd__t0").to_numpy()
    np.testing.assert_allclose(ceiling[twice], other.reindex(data.meta.frame_index[twice]).to_numpy())
    assert np.isfinite(ceiling[twice]).all() and np.isnan(ceiling[~twice]).all()  # tracked once: no ceiling
    assert not np.allclose(ceiling[twice], data.error_m[twice])  # another trial, not its own truth


def test_the_ceiling_of_sessions_is_the_other_sessions_of_the_same_source_and_mode(tmp_path):
    """Two sessions of one recording (different errors), one of another recording, one of the first recording in
    the other mode and one that names no source: only the first two are each other's trials."""
    from testkit.deepsee import write_session

    from estimator.deepsee.data import concat, session_frame_labels, session_windows
    from estimator.deepsee.references import other_session_trials, session_ceiling_estimates
    from seesys.io import session_files
    from seesys.io.core_settings import load_window_config

    folders = {}
    for name, seed, source, mode in (
        ("first", 0, "tum:recording", "rgbd"),
        ("second", 1, "tum:recording", "rgbd"),
        ("elsewhere", 2, "tum:another", "rgbd"),
        ("mono", 3, "tum:recording", "mono"),
        ("unnamed", 4, None, "rgbd"),
        ("unnamed_too", 5, None, "rgbd"),
    ):
        folders[name] = write_session(tmp_path / name, seed=seed, frames=120)
        if source is not None:
            session_files.update_manifest(folders[name], source=source, mode=mode)
    sessions = list(folders.values())
    assert other_session_trials(sessions) == {
        "first": ["second"],
        "second": ["first"],
        "elsewhere": [],
        "mono": [],
        "unnamed": [],
        "unnamed_too": [],
    }

    windows = load_window_config()
    data = concat([session_windows(folders[name], windows, labelled=True) for name in ("first", "elsewhere")])
    ceiling = session_ceiling_estimates(sessions, data)
    first = (data.meta.run == "first").to_numpy()
    assert first.sum() > 5 and (~first).sum() > 5
    other = session_frame_labels(folders["second"]).error_m
    np.testing.assert_allclose(ceiling[first], other.reindex(data.meta.frame_index[first]).to_numpy())
    assert np.isfinite(ceiling[first]).all() and np.isnan(ceiling[~first]).all()  # no other trial: no ceiling
    assert not np.allclose(ceiling[first], data.error_m[first])  # another trial, not its own truth


def test_predicted_estimates_read_back_what_the_prediction_table_wrote_and_refuse_other_windows():
    data = _windows([0.001, 0.002, 0.004], [0.003, 0.005, 0.009], windows_per_run=4)
    data.meta["frame_index"] = np.tile(np.arange(4) * 10, 3)
    key = {"set": "held-out environments", "row": "random_forest", "round": 1}
    estimate = np.linspace(0.001, 0.012, len(data))
    written = pd.concat(
        [
            prediction_table(key, data, estimate),
            prediction_table({**key, "round": 0}, data, estimate * 2),  # another round: not read
            prediction_table({**key, "row": "deepsee"}, data, estimate * 3),  # another row: not read
        ]
    ).sample(frac=1.0, random_state=0)  # the file's order is not the windows'
    np.testing.assert_array_equal(predicted_estimates(written, key, data), estimate)
    # Windows in another order are answered in theirs.
    reordered = data.subset(np.arange(len(data))[::-1])
    np.testing.assert_array_equal(predicted_estimates(written, key, reordered), estimate[::-1])
    with pytest.raises(SeesysError, match="not of these windows"):  # a window the predictions do not hold
        predicted_estimates(written[written.frame_index != 30], key, data)
    relabelled = dataclasses.replace(data, error_m=data.error_m * 2)
    with pytest.raises(SeesysError, match="held-out environments"):  # the same names, another build's truth
        predicted_estimates(written, key, relabelled)
