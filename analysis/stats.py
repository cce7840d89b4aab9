"""Per-condition statistics of one dependent variable (paper Table 5 and what it left out).

Between-subjects (the paper's design): descriptives (mean, SD, t-based CI of the mean), assumption checks
(Shapiro–Wilk per condition and on the ANOVA residuals, Levene's test centred on the median, i.e.
Brown–Forsythe), the classic one-way ANOVA (statsmodels ``anova_lm``) with η² and ω², Welch's ANOVA
(statsmodels ``anova_oneway``) and Kruskal–Wallis (scipy) with ε², post hoc Tukey HSD (statsmodels),
Games–Howell (pingouin) and Dunn with Holm correction (scikit-posthocs), each pair with Hedges' g and its CI
(pingouin). The CIs of η² and ε² are percentile bootstraps (scipy.stats.bootstrap, groups resampled
separately). Which test to read is chosen from the checks: normal residuals and equal variances → ANOVA and
Tukey; normal but unequal variances → Welch and Games–Howell; not normal → Kruskal–Wallis and Dunn. The power
note gives the participants per group that the observed effect (Cohen's f from η²) needs for the configured
power (statsmodels ``FTestAnovaPower``).

Within-subjects: repeated-measures ANOVA with Mauchly's sphericity test and the Greenhouse–Geisser correction
(pingouin ``rm_anova``), Friedman's test with Kendall's W (pingouin), a linear mixed model with a random
intercept per participant (statsmodels ``mixedlm``, which also uses participants missing a condition), paired
post hoc t tests or Wilcoxon tests with Holm correction (pingouin ``pairwise_tests``), and a power note from
pingouin's ``power_rm_anova``. Only participants with a value in every condition enter, except in the mixed
model.

Values are in the variable's reported unit (``scale`` applied) everywhere.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from analysis.config import AnalysisConfig, Variable

# The smallest design the power note considers: an effect that already has the wanted power with this many
# participants per group needs no more (the solvers find no root below it).
MIN_PER_GROUP = 2


@dataclass
class Comparison:
    """Everything reported for one variable: tidy tables and the reading of them."""

    variable: Variable
    design: str
    descriptives: pd.DataFrame
    assumptions: pd.DataFrame = field(default_factory=pd.DataFrame)
    tests: pd.DataFrame = field(default_factory=pd.DataFrame)
    posthoc: pd.DataFrame = field(default_factory=pd.DataFrame)
    recommended_test: str = ""
    recommended_posthoc: str = ""
    power_note: str = ""
    notes: list[str] = field(default_factory=list)


def values_of(table: pd.DataFrame, variable: Variable) -> pd.DataFrame:
    """``participant``, ``condition``, ``position`` and ``value`` (scaled) of the rows with a value."""
    data = table[["participant", "condition", "position", variable.column]].dropna(subset=[variable.column]).copy()
    data["value"] = data.pop(variable.column).astype(float) * variable.scale
    return data.reset_index(drop=True)


def paired_values(data: pd.DataFrame, conditions: list[str]) -> pd.DataFrame:
    """One row per participant with a value in every one of ``conditions``, a column each (no rows when a
    condition has no value at all)."""
    wide = data.pivot_table(index="participant", columns="condition", values="value")
    return wide.reindex(columns=conditions).dropna()


def descriptives(data: pd.DataFrame, conditions: list[str], confidence: float) -> pd.DataFrame:
    rows = []
    for c in conditions:
        x = data.loc[data.condition == c, "value"].to_numpy()
        n = len(x)
        mean = float(x.mean()) if n else math.nan
        sd = float(x.std(ddof=1)) if n > 1 else math.nan
        low, high = (
            stats.t.interval(confidence, n - 1, loc=mean, scale=sd / math.sqrt(n))
            if n > 1 and sd > 0
            else (mean, mean)
            if n > 1
            else (math.nan, math.nan)
        )
        rows.append({"condition": c, "n": n, "mean": mean, "sd": sd, "ci_low": float(low), "ci_high": float(high)})
    return pd.DataFrame(rows)


def _shapiro(x: np.ndarray) -> tuple[float, float]:
    if len(x) < 3 or np.ptp(x) == 0:
        return math.nan, math.nan
    result = stats.shapiro(x)
    return float(result.statistic), float(result.pvalue)


def _bootstrap_ci(
    samples: list[np.ndarray], statistic, cfg: AnalysisConfig, paired: bool = False
) -> tuple[float, float]:
    """The percentile bootstrap CI of ``statistic`` (vectorised): groups resampled separately, or, ``paired``,
    the rows of all samples together (participants with their pairs)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degenerate resamples (a constant group) give NaN and a warning
        result = stats.bootstrap(
            samples,
            statistic,
            paired=paired,
            n_resamples=cfg.bootstrap_resamples,
            confidence_level=cfg.confidence,
            method="percentile",
            vectorized=True,
            random_state=np.random.default_rng(cfg.bootstrap_seed),
        )
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def eta_squared(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    """η² = SS_between / SS_total, from scipy's F (vectorised over resamples)."""
    k = len(samples)
    n = sum(s.shape[axis] for s in samples)
    f = stats.f_oneway(*samples, axis=axis).statistic
    return f * (k - 1) / (f * (k - 1) + (n - k))


def epsilon_squared(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    """ε² = H / (n − 1) of the Kruskal–Wallis H (vectorised over resamples)."""
    n = sum(s.shape[axis] for s in samples)
    return stats.kruskal(*samples, axis=axis).statistic / (n - 1)


def _pair_effects(groups: dict[str, np.ndarray], a: str, b: str, confidence: float, paired: bool = False) -> dict:
    import pingouin as pg

    x, y = groups[a], groups[b]
    g = float(pg.compute_effsize(x, y, paired=paired, eftype="hedges"))
    low, high = pg.compute_esci(g, len(x), len(y), paired=paired, eftype="cohen", confidence=confidence, decimals=6)
    return {"hedges_g": g, "g_ci_low": float(low), "g_ci_high": float(high)}


def compare_between(table: pd.DataFrame, variable: Variable, conditions: list[str], cfg: AnalysisConfig) -> Comparison:
    """The between-subjects analysis of one variable (see the module docstring)."""
    import pingouin as pg
    import scikit_posthocs as sp
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm
    from statsmodels.stats.multicomp import pairwise_tukeyhsd
    from statsmodels.stats.oneway import anova_oneway
    from statsmodels.stats.power import FTestAnovaPower

    data = values_of(table, variable)
    result = Comparison(variable, "between", descriptives(data, conditions, cfg.confidence))
    present = [c for c in conditions if (data.condition == c).sum() >= 2]
    data = data[data.condition.isin(present)]
    if len(present) < 2:
        result.notes.append(f"fewer than two conditions with two or more participants: no tests for {variable.label}")
        return result
    if data.value.std() == 0 or all(np.ptp(data.loc[data.condition == c, "value"]) == 0 for c in present):
        result.notes.append(f"{variable.label} does not vary within conditions: no tests")
        return result
    groups = {c: data.loc[data.condition == c, "value"].to_numpy() for c in present}
    samples = list(groups.values())
    k, n = len(present), len(data)

    model = smf.ols("value ~ C(condition)", data=data).fit()
    rows = [
        {"check": "Shapiro-Wilk", "group": c, "statistic": s, "p": p} for c in present for s, p in [_shapiro(groups[c])]
    ]
    statistic, p = _shapiro(model.resid.to_numpy())
    rows.append({"check": "Shapiro-Wilk", "group": "residuals", "statistic": statistic, "p": p})
    levene = stats.levene(*samples, center="median")
    rows.append(
        {"check": "Levene (median)", "group": "all", "statistic": float(levene.statistic), "p": float(levene.pvalue)}
    )
    result.assumptions = pd.DataFrame(rows)
    result.assumptions["passed"] = ~(result.assumptions.p < cfg.alpha)  # an unchecked (NaN) p does not fail

    anova = anova_lm(model, typ=2)
    ss_b, ss_w = anova.loc["C(condition)", "sum_sq"], anova.loc["Residual", "sum_sq"]
    df_b, df_w = anova.loc["C(condition)", "df"], anova.loc["Residual", "df"]
    ms_w = ss_w / df_w
    eta2 = ss_b / (ss_b + ss_w)
    omega2 = (ss_b - df_b * ms_w) / (ss_b + ss_w + ms_w)
    eta_ci = _bootstrap_ci(samples, eta_squared, cfg)
    welch = anova_oneway(data.value, data.condition, use_var="unequal", welch_correction=True)
    kruskal = stats.kruskal(*samples)
    eps2 = float(kruskal.statistic) / (n - 1)
    eps_ci = _bootstrap_ci(samples, epsilon_squared, cfg)
    result.tests = pd.DataFrame(
        [
            {
                "test": "one-way ANOVA",
                "statistic": "F",
                "value": float(anova.loc["C(condition)", "F"]),
                "df1": df_b,
                "df2": df_w,
                "p": float(anova.loc["C(condition)", "PR(>F)"]),
                "effect": "eta^2",
                "effect_value": eta2,
                "effect_ci_low": eta_ci[0],
                "effect_ci_high": eta_ci[1],
            },
            {
                "test": "one-way ANOVA",
                "statistic": "F",
                "value": float(anova.loc["C(condition)", "F"]),
                "df1": df_b,
                "df2": df_w,
                "p": float(anova.loc["C(condition)", "PR(>F)"]),
                "effect": "omega^2",
                "effect_value": omega2,
                "effect_ci_low": math.nan,
                "effect_ci_high": math.nan,
            },
            {
                "test": "Welch ANOVA",
                "statistic": "F",
                "value": float(welch.statistic),
                "df1": float(welch.df_num),
                "df2": float(welch.df_denom),
                "p": float(welch.pvalue),
                "effect": "",
                "effect_value": math.nan,
                "effect_ci_low": math.nan,
                "effect_ci_high": math.nan,
            },
            {
                "test": "Kruskal-Wallis",
                "statistic": "H",
                "value": float(kruskal.statistic),
                "df1": k - 1,
                "df2": math.nan,
                "p": float(kruskal.pvalue),
                "effect": "epsilon^2",
                "effect_value": eps2,
                "effect_ci_low": eps_ci[0],
                "effect_ci_high": eps_ci[1],
            },
        ]
    )

    pairs = [(a, b) for i, a in enumerate(present) for b in present[i + 1 :]]
    effects = {(a, b): _pair_effects(groups, a, b, cfg.confidence) for a, b in pairs}
    tukey = pairwise_tukeyhsd(data.value, data.condition, alpha=cfg.alpha)
    tukey_p = {tuple(sorted((str(r[0]), str(r[1])))): float(r[3]) for r in tukey.summary().data[1:]}
    games = pg.pairwise_gameshowell(data=data, dv="value", between="condition")
    games_p = {tuple(sorted((r.A, r.B))): float(r.pval) for r in games.itertuples()}
    dunn = sp.posthoc_dunn(data, val_col="value", group_col="condition", p_adjust="holm")
    rows = []
    for method, p_of in (
        ("Tukey HSD", tukey_p),
        ("Games-Howell", games_p),
        ("Dunn (Holm)", {tuple(sorted((a, b))): float(dunn.loc[a, b]) for a, b in pairs}),
    ):
        for a, b in pairs:
            rows.append(
                {
                    "method": method,
                    "a": a,
                    "b": b,
                    "mean_diff": groups[a].mean() - groups[b].mean(),
                    "p_adj": p_of[tuple(sorted((a, b)))],
                    **effects[(a, b)],
                }
            )
    result.posthoc = pd.DataFrame(rows)

    normal = bool(result.assumptions.loc[result.assumptions.check == "Shapiro-Wilk", "passed"].all())
    equal_var = bool(result.assumptions.loc[result.assumptions.check == "Levene (median)", "passed"].all())
    result.recommended_test, result.recommended_posthoc = (
        ("one-way ANOVA", "Tukey HSD")
        if normal and equal_var
        else ("Welch ANOVA", "Games-Howell")
        if normal
        else ("Kruskal-Wallis", "Dunn (Holm)")
    )
    result.notes.append(
        f"assumptions: {'normal' if normal else 'not normal'} (Shapiro-Wilk), "
        f"{'equal' if equal_var else 'unequal'} variances (Levene): read the "
        f"{result.recommended_test} and {result.recommended_posthoc}"
    )
    cohen_f = math.sqrt(eta2 / (1 - eta2)) if 0 < eta2 < 1 else math.nan
    if math.isfinite(cohen_f) and cohen_f > 0:
        power = FTestAnovaPower()
        smallest = power.power(effect_size=cohen_f, nobs=MIN_PER_GROUP * k, alpha=cfg.alpha, k_groups=k)
        total = (
            math.nan
            if smallest >= cfg.target_power
            else power.solve_power(effect_size=cohen_f, nobs=None, alpha=cfg.alpha, power=cfg.target_power, k_groups=k)
        )
        needed = (
            f"{math.ceil(total / k)} participants per condition ({math.ceil(total / k) * k} in all"
            if math.isfinite(total)
            else f"no more than {MIN_PER_GROUP} participants per condition (the smallest design already has that power"
        )
        result.power_note = (
            f"observed effect Cohen's f = {cohen_f:.2f} (from eta^2 = {eta2:.3f}); detecting it "
            f"with power {cfg.target_power:.0%} at alpha = {cfg.alpha} in a one-way ANOVA needs "
            f"{needed}; this study has {n})"
        )
    else:
        result.power_note = "no effect observed (eta^2 = 0): no sample size can be given"
    return result


def compare_within(table: pd.DataFrame, variable: Variable, conditions: list[str], cfg: AnalysisConfig) -> Comparison:
    """The within-subjects analysis of one variable (see the module docstring)."""
    import pingouin as pg

    data = values_of(table, variable)
    everyone = data[data.condition.isin(conditions)]
    counts = data.groupby("participant").condition.nunique()
    complete = counts.index[counts == len(conditions)]
    data = data[data.participant.isin(complete) & data.condition.isin(conditions)]
    result = Comparison(variable, "within", descriptives(data, conditions, cfg.confidence))
    if len(complete) < everyone.participant.nunique():
        result.notes.append(
            f"{everyone.participant.nunique() - len(complete)} participant(s) without every "
            f"condition: left out of all but the mixed model"
        )
    if len(complete) < 3 or data.value.std() == 0:
        result.notes.append(
            f"fewer than three participants with every condition, or no variation: no tests for {variable.label}"
        )
        return result
    groups = {c: data.loc[data.condition == c].sort_values("participant").value.to_numpy() for c in conditions}
    rows = [
        {"check": "Shapiro-Wilk", "group": c, "statistic": s, "p": p}
        for c in conditions
        for s, p in [_shapiro(groups[c])]
    ]
    sphericity = pg.sphericity(data, dv="value", within="condition", subject="participant")
    # With two conditions sphericity holds by definition, and pingouin says so with a plain tuple (True, nan, ...).
    w, p = (float(sphericity.W), float(sphericity.pval)) if hasattr(sphericity, "W") else (1.0, math.nan)
    rows.append({"check": "Mauchly sphericity", "group": "all", "statistic": w, "p": p})
    result.assumptions = pd.DataFrame(rows)
    result.assumptions["passed"] = ~(result.assumptions.p < cfg.alpha)

    rm = pg.rm_anova(
        data=data, dv="value", within="condition", subject="participant", correction=True, effsize="np2"
    ).iloc[0]
    friedman = pg.friedman(data=data, dv="value", within="condition", subject="participant").iloc[0]
    p_gg = float(rm.get("p_GG_corr", rm.get("p-GG-corr", math.nan)))
    result.tests = pd.DataFrame(
        [
            {
                "test": "repeated-measures ANOVA",
                "statistic": "F",
                "value": float(rm.F),
                "df1": float(rm.ddof1),
                "df2": float(rm.ddof2),
                "p": float(rm.get("p_unc", rm.get("p-unc"))),
                "effect": "partial eta^2",
                "effect_value": float(rm.np2),
                "effect_ci_low": math.nan,
                "effect_ci_high": math.nan,
            },
            {
                "test": "repeated-measures ANOVA (Greenhouse-Geisser)",
                "statistic": "F",
                "value": float(rm.F),
                "df1": float(rm.ddof1) * float(rm.eps),
                "df2": float(rm.ddof2) * float(rm.eps),
                "p": p_gg,
                "effect": "partial eta^2",
                "effect_value": float(rm.np2),
                "effect_ci_low": math.nan,
                "effect_ci_high": math.nan,
            },
            {
                "test": "Friedman",
                "statistic": "Q",
                "value": float(friedman.Q),
                "df1": float(friedman.ddof1),
                "df2": math.nan,
                "p": float(friedman.get("p_unc", friedman.get("p-unc"))),
                "effect": "Kendall W",
                "effect_value": float(friedman.W),
                "effect_ci_low": math.nan,
                "effect_ci_high": math.nan,
            },
            _mixed_model(everyone),
        ]
    )
    rows = []
    for parametric, method in ((True, "paired t (Holm)"), (False, "Wilcoxon (Holm)")):
        table_ = pg.pairwise_tests(
            data=data, dv="value", within="condition", subject="participant", parametric=parametric, padjust="holm"
        )
        # One pair needs no correction: pingouin then gives only the uncorrected p.
        p_col = next(c for c in ("p_corr", "p-corr", "p_unc", "p-unc") if c in table_)
        for r in table_.to_dict("records"):
            a, b = r["A"], r["B"]
            rows.append(
                {
                    "method": method,
                    "a": a,
                    "b": b,
                    "mean_diff": groups[a].mean() - groups[b].mean(),
                    "p_adj": float(r[p_col]),
                    **_pair_effects(groups, a, b, cfg.confidence, paired=True),
                }
            )
    result.posthoc = pd.DataFrame(rows)
    normal = bool(result.assumptions.loc[result.assumptions.check == "Shapiro-Wilk", "passed"].all())
    spherical = bool(result.assumptions.loc[result.assumptions.check == "Mauchly sphericity", "passed"].all())
    result.recommended_test = (
        "repeated-measures ANOVA"
        if normal and spherical
        else "repeated-measures ANOVA (Greenhouse-Geisser)"
        if normal
        else "Friedman"
    )
    result.recommended_posthoc = "paired t (Holm)" if normal else "Wilcoxon (Holm)"
    result.notes.append(
        f"assumptions: {'normal' if normal else 'not normal'} (Shapiro-Wilk), sphericity "
        f"{'holds' if spherical else 'violated'} (Mauchly): read the {result.recommended_test} "
        f"and {result.recommended_posthoc}"
    )
    wide = data.pivot(index="participant", columns="condition", values="value")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a condition whose values do not vary has no correlation (NaN)
        corr = float(np.nanmean(wide.corr().to_numpy()[np.triu_indices(len(conditions), 1)]))
    if not math.isfinite(corr):
        result.power_note = "no power note: a condition's values do not vary, so conditions have no correlation"
    elif 0 < float(rm.np2) < 1:
        needed = pg.power_rm_anova(
            eta_squared=float(rm.np2),
            m=len(conditions),
            n=None,
            power=cfg.target_power,
            alpha=cfg.alpha,
            corr=max(min(corr, 0.99), -0.49),
            epsilon=float(rm.eps),
        )
        count = (
            f"{math.ceil(needed)} participants"
            if math.isfinite(needed)
            else f"no more than {MIN_PER_GROUP} participants (the smallest design already has that power)"
        )
        result.power_note = (
            f"observed partial eta^2 = {float(rm.np2):.3f} (mean correlation between conditions "
            f"{corr:.2f}); power {cfg.target_power:.0%} at alpha = {cfg.alpha} needs "
            f"{count}; this study has {len(complete)}"
        )
    else:
        result.power_note = "no effect observed: no sample size can be given"
    return result


def _mixed_model(data: pd.DataFrame) -> dict:
    """Linear mixed model ``value ~ condition`` with a random intercept per participant (statsmodels, REML) and
    the Wald chi-square test of the condition terms: unlike the repeated-measures ANOVA it keeps participants
    who miss a condition (a crashed session)."""
    import statsmodels.formula.api as smf

    row = {
        "test": "mixed model (random intercept)",
        "statistic": "chi2",
        "value": math.nan,
        "df1": math.nan,
        "df2": math.nan,
        "p": math.nan,
        "effect": "",
        "effect_value": math.nan,
        "effect_ci_low": math.nan,
        "effect_ci_high": math.nan,
    }
    try:
        fit = smf.mixedlm("value ~ C(condition)", data, groups=data["participant"]).fit(reml=True)
        wald = fit.wald_test_terms(scalar=True).table.loc["C(condition)"]
    except (ValueError, np.linalg.LinAlgError):  # a singular fit (e.g. no variation between participants)
        return row
    return {**row, "value": float(wald.statistic), "df1": float(wald.df_constraint), "p": float(wald.pvalue)}


def _ratio_minus_one(b: np.ndarray, a: np.ndarray, axis: int = -1) -> np.ndarray:
    """mean(b) / mean(a) − 1; NaN where mean(a) is 0 (no relative change from nothing)."""
    reference = np.mean(a, axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(reference == 0, np.nan, np.mean(b, axis=axis) / reference - 1.0)


def relative_changes(
    table: pd.DataFrame, variable: Variable, conditions: list[str], design: str, of: list[str], cfg: AnalysisConfig
) -> pd.DataFrame:
    """The change of each condition in ``of`` against every other condition, relative to the other's mean
    (mean_b / mean_a − 1: −0.25 is the paper's "25 % lower"), with a percentile bootstrap CI: groups resampled
    separately between subjects; participants resampled with their pairs within subjects (only participants with
    both conditions)."""
    data = values_of(table, variable)
    rows = []
    for b in [c for c in of if c in conditions]:
        for a in [c for c in conditions if c != b]:
            if design == "between":
                x = data.loc[data.condition == a, "value"].to_numpy()
                y = data.loc[data.condition == b, "value"].to_numpy()
                paired = False
            else:
                wide = paired_values(data, [a, b])
                x, y, paired = wide[a].to_numpy(), wide[b].to_numpy(), True
            change, low, high = math.nan, math.nan, math.nan
            if len(x) and len(y):
                change = float(_ratio_minus_one(y, x))
            if len(x) > 1 and len(y) > 1 and math.isfinite(change):
                low, high = _bootstrap_ci([y, x], _ratio_minus_one, cfg, paired)
            rows.append(
                {
                    "variable": variable.column,
                    "condition": b,
                    "against": a,
                    "n_condition": len(y),
                    "n_against": len(x),
                    "relative_change": change,
                    "ci_low": low,
                    "ci_high": high,
                }
            )
    return pd.DataFrame(rows)


def compare(
    table: pd.DataFrame, variable: Variable, conditions: list[str], design: str, cfg: AnalysisConfig
) -> Comparison:
    return (compare_between if design == "between" else compare_within)(table, variable, conditions, cfg)


#: The arms of the oracle-share question: sound without information, the advisory judged, the true error.
SOUND_ONLY, JUDGED, ORACLE = "yoked", "seesys", "oracle"


def _gain_share(yoked: np.ndarray, judged: np.ndarray, oracle: np.ndarray, axis: int = -1) -> np.ndarray:
    """(mean yoked − mean judged) / (mean yoked − mean oracle); NaN where the oracle gains nothing."""
    gain = np.mean(yoked, axis=axis) - np.mean(oracle, axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(gain == 0, np.nan, (np.mean(yoked, axis=axis) - np.mean(judged, axis=axis)) / gain)


def oracle_share(table: pd.DataFrame, variable: Variable, design: str, cfg: AnalysisConfig) -> dict | None:
    """The share of the oracle's gain over the yoked arm that SEESys reaches, (yoked − seesys) / (yoked − oracle),
    on ``variable`` (lower is better), with a percentile bootstrap CI: participants resampled with all three arms
    within subjects, groups separately between. None when the study lacks one of the three arms.

    Beside it, the oracle's own change against yoked (mean oracle / mean yoked − 1, with its CI): the share means
    something only where the oracle gains, i.e. where that interval lies below 0."""
    data = values_of(table, variable)
    arms = (SOUND_ONLY, JUDGED, ORACLE)
    if not set(arms) <= set(data.condition):
        return None
    if design == "between":
        samples = [data.loc[data.condition == arm, "value"].to_numpy() for arm in arms]
        paired = False
    else:
        wide = paired_values(data, list(arms))
        samples, paired = [wide[arm].to_numpy() for arm in arms], True
    share, low, high = math.nan, math.nan, math.nan
    oracle_change, oracle_low, oracle_high = math.nan, math.nan, math.nan
    if all(len(s) for s in samples):
        share = float(_gain_share(*samples))
        oracle_change = float(_ratio_minus_one(samples[2], samples[0]))
    if all(len(s) > 1 for s in samples) and math.isfinite(share):
        low, high = _bootstrap_ci(samples, _gain_share, cfg, paired)
    if all(len(s) > 1 for s in samples) and math.isfinite(oracle_change):
        oracle_low, oracle_high = _bootstrap_ci([samples[2], samples[0]], _ratio_minus_one, cfg, paired)
    return {
        "variable": variable.column,
        "n": min(len(s) for s in samples),
        "yoked_mean": float(np.mean(samples[0])) if len(samples[0]) else math.nan,
        "seesys_mean": float(np.mean(samples[1])) if len(samples[1]) else math.nan,
        "oracle_mean": float(np.mean(samples[2])) if len(samples[2]) else math.nan,
        "share_of_oracle_gain": share,
        "ci_low": low,
        "ci_high": high,
        "oracle_vs_yoked": oracle_change,
        "oracle_ci_low": oracle_low,
        "oracle_ci_high": oracle_high,
    }
