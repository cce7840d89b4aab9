"""``seesys dataset candidates``: the next schema's candidate channels judged against the label on the sample, and a
source without ground truth refused in one line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from testkit.sample import SAMPLE, copy_tum_subset, run_seesys

from estimator.dataset.candidates import CHANNELS, POOLED


@pytest.mark.slam
@pytest.mark.system
def test_the_candidate_channels_are_reported_against_the_label_with_and_without_the_motion(tmp_path):
    result = run_seesys("dataset", "candidates", f"tum:{SAMPLE}", "--out", str(tmp_path / "report"))
    assert result.returncode == 0, result.stderr
    frames = pd.read_csv(tmp_path / "report" / "frames.csv")
    table = pd.read_csv(tmp_path / "report" / "correlations.csv")
    assert len(frames) == 150 and frames.label_m.notna().sum() > 120
    assert set(table.channel) == set(CHANNELS) and set(table.source) == {"tum:sample", POOLED}
    pooled = table[table.source == POOLED].set_index("channel")
    assert (pooled.n > 100).all()
    assert np.isfinite(pooled.rho).all() and (pooled.rho.abs() <= 1).all()
    assert np.isfinite(pooled.partial_rho_given_motion).all() and (pooled.partial_rho_given_motion.abs() <= 1).all()
    # The predicted σ of the sample's frames: between 10 µm and 2 cm.
    assert frames.translation_sigma_m.dropna().between(1e-5, 0.02).all()
    # The pair's predicted σ, judged as an uncertainty: shares are shares, a Gaussian's within the χ bounds of 3-D.
    covered = pd.read_csv(tmp_path / "report" / "coverage.csv").set_index("source")
    assert covered.loc[POOLED, "frames"] > 100 and 0 <= covered.loc[POOLED, "within_1sigma"] <= 1
    assert 0.5 < covered.loc[POOLED, "gaussian_1sigma"] < 0.75 and covered.loc[POOLED, "gaussian_2sigma"] > 0.95
    assert covered.loc[POOLED, "median_label_over_sigma"] > 0


@pytest.mark.system
def test_a_source_without_ground_truth_is_refused_by_name(tmp_path):
    folder = copy_tum_subset(SAMPLE, tmp_path / "no-truth", 20)
    (folder / "groundtruth.txt").unlink()
    result = run_seesys("dataset", "candidates", f"tum:{folder}", "--out", str(tmp_path / "report"))
    assert result.returncode == 2 and "has no ground truth" in result.stderr
    assert not (tmp_path / "report").exists()
