"""The geometry channels judged alone (estimator/deepsee/channels.py), on windows with known answers."""

from __future__ import annotations

import numpy as np

from estimator.deepsee.channels import RawSet, channel_table, choose_features, judged_channels
from estimator.deepsee.yardsticks import Bootstrap
from seesys.core import rts_schema

WINDOW = 30


def _windows(seed: int, runs: int = 8, per_run: int = 60) -> RawSet:
    """Windows whose label is half motion, half something only ``flow_disagreement``'s window end sees; the
    predicted σ follows the motion alone, and the residual median is noise."""
    rng = np.random.default_rng(seed)
    n = runs * per_run
    rts = np.full((n, WINDOW, rts_schema.NUM_CHANNELS), np.nan, np.float32)
    speed = rng.uniform(0.001, 0.01, n)
    # The motion statistic (the spread of the relative translation over the window) is the speed exactly.
    rts[:, :, [rts_schema.index_of(name) for name in rts_schema.TRANSLATION_CHANNELS]] = 0.0
    rts[:, :, rts_schema.index_of("rel_tx")] = speed[:, None] * np.resize([1.0, -1.0], WINDOW)
    hidden = rng.uniform(0.0, 0.01, n)
    error = speed + hidden
    flow = rng.uniform(0.0, 0.01, (n, WINDOW))
    flow[:, -1] = hidden + 0.0005 * rng.standard_normal(n)
    rts[:, :, rts_schema.index_of("flow_disagreement")] = flow
    rts[:, :, rts_schema.index_of("translation_sigma")] = speed[:, None] * (1 + 0.01 * rng.standard_normal((n, WINDOW)))
    rts[:, :, rts_schema.index_of("residual_median")] = rng.uniform(0.5, 2.0, (n, WINDOW))
    return RawSet(rts, error, np.repeat([f"run{k}" for k in range(runs)], per_run))


def test_a_channel_that_sees_what_the_motion_does_not_is_chosen_by_its_feature_and_judged_with_an_interval():
    chosen = choose_features(_windows(0))
    assert chosen["flow_disagreement"] == "flow_disagreement_end"
    table = channel_table(_windows(1), chosen, Bootstrap(100, 0.95, 0))
    assert set(table.channel) == set(judged_channels()) and set(table.feature) == {"mean", "min", "max", "std", "end"}
    # One chosen feature per channel with a value; the channels that are NaN throughout have none.
    picked = table[table.chosen].set_index("channel")
    assert set(picked.index) == {"flow_disagreement", "translation_sigma", "residual_median"}
    flow = picked.loc["flow_disagreement"]
    assert flow.partial_spearman > 0.6 and flow.partial_spearman_low > 0.3
    assert flow.partial_spearman_low <= flow.partial_spearman <= flow.partial_spearman_high and flow.runs == 8
    # The σ ranks the error as the motion does (ρ high) and adds nothing given it; the noise channel nothing.
    sigma = picked.loc["translation_sigma"]
    assert sigma.spearman > 0.4 and abs(sigma.partial_spearman) < 0.2 < sigma.spearman - 0.3
    assert abs(picked.loc["residual_median"].partial_spearman) < 0.2
    # Only the chosen features get intervals.
    assert table[~table.chosen].partial_spearman_low.isna().all()
    assert table[table.channel == "depth_spread"].windows.eq(0).all()
