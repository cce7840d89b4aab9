"""The statistics of ``seesys analyze`` agree with statsmodels, scipy, pingouin and scikit-posthocs called directly
on the same tidy CSV, for a between-subjects and a within-subjects table."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

REPO = Path(__file__).resolve().parent.parent
CONDITIONS = ["none", "rotation", "seesys"]


def made_up_between(path: Path) -> pd.DataFrame:
    """Ten participants per condition, the errors with unequal spreads (as in the paper's means)."""
    rng = np.random.default_rng(3)
    n = 10
    table = pd.DataFrame(
        {
            "participant": [f"P{i + 1:02d}" for i in range(3 * n)],
            "condition": np.repeat(CONDITIONS, n),
            "rpe_mean_m": np.concatenate(
                [rng.normal(0.012, 0.003, n), rng.normal(0.010, 0.002, n), rng.normal(0.009, 0.001, n)]
            ),
            "completeness": np.clip(
                np.concatenate([rng.normal(0.706, 0.12, n), rng.normal(0.873, 0.05, n), rng.normal(0.887, 0.05, n)]),
                0,
                1,
            ),
        }
    )
    table.to_csv(path, index=False)
    return table


def analyze(table_csv: Path, out: Path, design: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "seesys", "analyze", "--table", str(table_csv), "--out", str(out), "--design", design],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )


@pytest.fixture(scope="module")
def between(tmp_path_factory):
    root = tmp_path_factory.mktemp("between")
    made_up_between(root / "participants.csv")
    done = analyze(root / "participants.csv", root / "out", "between")
    assert done.returncode == 0, done.stderr
    data = pd.read_csv(root / "participants.csv")
    data["value"] = data.rpe_mean_m * 100  # the report's unit (cm)
    return root / "out", data


def row(table: pd.DataFrame, **match) -> pd.Series:
    mask = np.ones(len(table), bool)
    for k, v in match.items():
        mask &= table[k] == v
    assert mask.sum() == 1, match
    return table[mask].iloc[0]


@pytest.mark.system
def test_descriptives_and_assumptions(between):
    from statsmodels.stats.weightstats import DescrStatsW

    out, data = between
    desc = pd.read_csv(out / "descriptives.csv")
    checks = pd.read_csv(out / "assumptions.csv")
    for c in CONDITIONS:
        x = data.loc[data.condition == c, "value"].to_numpy()
        r = row(desc, variable="rpe_mean_m", condition=c)
        assert r["mean"] == pytest.approx(x.mean()) and r["sd"] == pytest.approx(x.std(ddof=1))
        assert (r.ci_low, r.ci_high) == pytest.approx(DescrStatsW(x).tconfint_mean(0.05))
        assert row(checks, variable="rpe_mean_m", group=c).p == pytest.approx(stats.shapiro(x).pvalue)
    import pingouin as pg

    levene = pg.homoscedasticity(data, dv="value", group="condition", method="levene")
    assert row(checks, variable="rpe_mean_m", check="Levene (median)").p == pytest.approx(float(levene.pval.iloc[0]))


@pytest.mark.system
def test_omnibus_tests_and_effect_sizes(between):
    import pingouin as pg

    out, data = between
    tests = pd.read_csv(out / "tests.csv")
    groups = [data.loc[data.condition == c, "value"].to_numpy() for c in CONDITIONS]
    anova = row(tests, variable="rpe_mean_m", test="one-way ANOVA", effect="eta^2")
    f = stats.f_oneway(*groups)
    assert (anova.value, anova.p) == pytest.approx((f.statistic, f.pvalue))
    pg_anova = pg.anova(data=data, dv="value", between="condition", detailed=True)
    assert anova.effect_value == pytest.approx(float(pg_anova.np2.iloc[0]))
    assert anova.effect_ci_low < anova.effect_value < anova.effect_ci_high
    welch = row(tests, variable="rpe_mean_m", test="Welch ANOVA")
    pg_welch = pg.welch_anova(data=data, dv="value", between="condition").iloc[0]
    assert (welch.value, welch.df2, welch.p) == pytest.approx((pg_welch.F, pg_welch.ddof2, pg_welch.p_unc))
    kruskal = row(tests, variable="rpe_mean_m", test="Kruskal-Wallis")
    h = stats.kruskal(*groups)
    assert (kruskal.value, kruskal.p) == pytest.approx((h.statistic, h.pvalue))
    assert kruskal.effect_value == pytest.approx(h.statistic / (len(data) - 1))


@pytest.mark.system
def test_post_hoc_tests(between):
    import pingouin as pg
    import scikit_posthocs as sp

    out, data = between
    posthoc = pd.read_csv(out / "posthoc.csv")
    groups = {c: data.loc[data.condition == c, "value"].to_numpy() for c in CONDITIONS}
    tukey = stats.tukey_hsd(*groups.values())
    games = pg.pairwise_gameshowell(data=data, dv="value", between="condition")
    dunn = sp.posthoc_dunn(data, val_col="value", group_col="condition", p_adjust="holm")
    for i, a in enumerate(CONDITIONS):
        for j, b in enumerate(CONDITIONS[i + 1 :], start=i + 1):
            assert row(posthoc, variable="rpe_mean_m", method="Tukey HSD", a=a, b=b).p_adj == pytest.approx(
                tukey.pvalue[i, j], abs=1e-3
            )  # statsmodels' and scipy's studentized range tables
            gh = games[(a == games.A) & (b == games.B)].iloc[0]
            r = row(posthoc, variable="rpe_mean_m", method="Games-Howell", a=a, b=b)
            assert r.p_adj == pytest.approx(gh.pval)
            assert r.hedges_g == pytest.approx(gh.hedges)
            assert r.mean_diff == pytest.approx(groups[a].mean() - groups[b].mean())
            assert row(posthoc, variable="rpe_mean_m", method="Dunn (Holm)", a=a, b=b).p_adj == pytest.approx(
                dunn.loc[a, b]
            )


@pytest.mark.system
def test_power_note_matches_pingouin(between):
    import pingouin as pg

    out, data = between
    eta2 = row(pd.read_csv(out / "tests.csv"), variable="rpe_mean_m", test="one-way ANOVA", effect="eta^2").effect_value
    per_group = math.ceil(pg.power_anova(eta_squared=eta2, k=3, n=None, power=0.8, alpha=0.05))
    report = (out / "report.md").read_text()
    assert f"needs {per_group} participants per condition (" in report
    assert (out / "report.html").read_text().count("<table>") >= 3
    assert (out / "figures" / "box_rpe_mean_m.png").stat().st_size > 1000


@pytest.mark.system
def test_within_subjects_agrees_with_statsmodels_anovarm(tmp_path):
    import pingouin as pg
    from statsmodels.stats.anova import AnovaRM

    rng = np.random.default_rng(5)
    people = [f"P{i + 1:02d}" for i in range(12)]
    base = rng.normal(0.011, 0.002, len(people))
    table = pd.DataFrame(
        [
            {
                "participant": p,
                "condition": c,
                "position": k + 1,
                "rpe_mean_m": b * (1 - 0.1 * k) + rng.normal(0, 0.0008),
            }
            for p, b in zip(people, base)
            for k, c in enumerate(CONDITIONS)
        ]
    )
    table.to_csv(tmp_path / "within.csv", index=False)
    done = analyze(tmp_path / "within.csv", tmp_path / "out", "within")
    assert done.returncode == 0, done.stderr
    tests = pd.read_csv(tmp_path / "out" / "tests.csv")
    table["value"] = table.rpe_mean_m * 100
    reference = AnovaRM(table, "value", "participant", within=["condition"]).fit().anova_table.iloc[0]
    rm = row(tests, variable="rpe_mean_m", test="repeated-measures ANOVA")
    assert (rm.value, rm.p) == pytest.approx((reference["F Value"], reference["Pr > F"]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fried = stats.friedmanchisquare(
            *[table.loc[table.condition == c].sort_values("participant").value for c in CONDITIONS]
        )
    r = row(tests, variable="rpe_mean_m", test="Friedman")
    assert (r.value, r.p) == pytest.approx((fried.statistic, fried.pvalue))
    import statsmodels.formula.api as smf

    mixed = smf.mixedlm("value ~ C(condition)", table, groups=table["participant"]).fit(reml=True)
    wald = mixed.wald_test_terms(scalar=True).table.loc["C(condition)"]
    r = row(tests, variable="rpe_mean_m", test="mixed model (random intercept)")
    assert (r.value, r.p) == pytest.approx((wald.statistic, wald.pvalue))
    paired = pg.pairwise_tests(data=table, dv="value", within="condition", subject="participant", padjust="holm")
    posthoc = pd.read_csv(tmp_path / "out" / "posthoc.csv")
    for pr in paired.itertuples():
        assert row(posthoc, method="paired t (Holm)", a=pr.A, b=pr.B).p_adj == pytest.approx(pr.p_corr)


def test_the_share_of_the_oracles_gain_is_the_gap_seesys_closes_with_a_paired_interval():
    from analysis.config import load_analysis_config
    from analysis.stats import oracle_share

    cfg = load_analysis_config()
    variable = next(v for v in cfg.variables if v.column == "error_per_metre")
    rng = np.random.default_rng(5)
    n = 10
    base = rng.normal(0.010, 0.002, n)  # participants differ; within a participant the arms differ by a fixed gap
    rows = []
    for arm, gain in (("yoked", 0.0), ("seesys", 0.001), ("oracle", 0.002), ("none", -0.0005)):
        rows += [
            {"participant": f"P{i:02d}", "condition": arm, "position": 1, "error_per_metre": base[i] - gain}
            for i in range(n)
        ]
    table = pd.DataFrame(rows)
    share = oracle_share(table, variable, "within", cfg)
    assert share["share_of_oracle_gain"] == pytest.approx(0.5) and share["n"] == n
    assert share["ci_low"] == pytest.approx(0.5) and share["ci_high"] == pytest.approx(0.5)  # exact gaps: no spread
    expected = (base.mean() - 0.002) / base.mean() - 1  # the oracle's own change against yoked
    assert share["oracle_vs_yoked"] == pytest.approx(expected) and share["oracle_ci_high"] < 0
    assert oracle_share(table[table.condition != "oracle"], variable, "within", cfg) is None
