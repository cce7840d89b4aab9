"""``seesys analyze``: a study's tidy tables, statistics, figures and report.

Writes into the output folder (default ``STUDY/analysis``):

- ``participants.csv``: one row per participant (and condition): condition, position in the participant's order,
  status, attempts, and the metrics in SI units (``rpe_mean_m``, ``completeness`` as a fraction, ...);
- ``rpe_pairs.csv``: every RPE pair (participant, condition, attempt, timestamp, error_m);
- ``descriptives.csv``, ``assumptions.csv``, ``tests.csv``, ``posthoc.csv``: the statistics, one row per
  variable and condition / check / test / pair, in the reported units (R and JASP read them as they are);
- ``changes.csv``: the relative change of the means of ``changes_of`` (analysis.toml) against every other
  condition, with bootstrap CIs;
- ``oracle_share.csv``: where the study has the ``yoked``, ``seesys`` and ``oracle`` arms, the share of the oracle's
  gain that SEESys reaches on each error variable, (yoked − seesys) / (yoked − oracle), with a bootstrap CI, and
  the oracle's own change against yoked with its CI (the share means something only where the oracle gains);
- ``figures/*.png`` and ``report.md`` / ``report.html`` (the same report; the HTML embeds nothing, it links the
  figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from markdown_it import MarkdownIt

from analysis import plots
from analysis.config import AnalysisConfig
from analysis.stats import Comparison, compare, oracle_share, relative_changes
from seesys.core.errors import SeesysError
from study.config import MetricsConfig
from study.sessions import DONE, advice_thresholds, collect_study

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
HTML_STYLE = (
    "body{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}"
    "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.2em .6em}"
    "th{background:#eee}img{max-width:100%}code{background:#f4f4f4}"
)


@dataclass(frozen=True)
class AnalysisResult:
    out: Path
    comparisons: list[Comparison]
    table: pd.DataFrame


def fmt(value: float, decimals: int) -> str:
    """``value`` with ``decimals`` decimals, or "–" when there is none (None, NaN: an SD of one participant)."""
    return "–" if value is None or not math.isfinite(value) else f"{value:.{decimals}f}"


def _p(p: float) -> str:
    return "–" if not math.isfinite(p) else "< 0.001" if p < 0.001 else f"{p:.3f}"


def _p_clause(p: float) -> str:
    text = _p(p)
    return f"p {text}" if text.startswith("<") else f"p = {text}"


def table5(comparisons: list[Comparison], conditions: list[str], cfg: AnalysisConfig) -> pd.DataFrame:
    """The paper's Table 5 layout: variables as rows, conditions as columns, ``mean ± SD [95 % CI]`` cells."""
    rows = []
    for c in comparisons:
        d = c.descriptives.set_index("condition")
        v = c.variable
        row = {"Performance metric": v.title}
        for condition in conditions:
            r = d.loc[condition]
            row[cfg.condition_labels.get(condition, condition)] = (
                f"{fmt(r['mean'], v.decimals)} ± {fmt(r['sd'], v.decimals)} "
                f"[{fmt(r['ci_low'], v.decimals)}, {fmt(r['ci_high'], v.decimals)}] (n = {int(r['n'])})"
            )
        rows.append(row)
    return pd.DataFrame(rows)


def analyse_table(table: pd.DataFrame, conditions: list[str], design: str, cfg: AnalysisConfig) -> list[Comparison]:
    """Every configured variable present in ``table`` compared across ``conditions``."""
    return [compare(table, v, conditions, design, cfg) for v in cfg.variables if v.column in table]


def changes_of(
    table: pd.DataFrame, comparisons: list[Comparison], conditions: list[str], design: str, cfg: AnalysisConfig
) -> pd.DataFrame:
    """The relative changes (``changes_of`` of analysis.toml) of every compared variable, as one tidy table."""
    frames = [relative_changes(table, c.variable, conditions, design, cfg.changes_of, cfg) for c in comparisons]
    frames = [f for f in frames if not f.empty]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _tidy(comparisons: list[Comparison], part: str) -> pd.DataFrame:
    frames = [getattr(c, part).assign(variable=c.variable.column) for c in comparisons if not getattr(c, part).empty]
    if not frames:
        return pd.DataFrame()
    tidy = pd.concat(frames, ignore_index=True)
    return tidy[["variable", *[col for col in tidy.columns if col != "variable"]]]


def write_tables(comparisons: list[Comparison], out: Path) -> None:
    for part in ("descriptives", "assumptions", "tests", "posthoc"):
        _tidy(comparisons, part).to_csv(out / f"{part}.csv", index=False)


def changes_table(changes: pd.DataFrame, comparisons: list[Comparison], cfg: AnalysisConfig) -> pd.DataFrame:
    """One row per variable and pair: the relative change in percent with its CI."""
    titles = {c.variable.column: c.variable.title for c in comparisons}
    rows = []
    for r in changes.itertuples():
        label = cfg.condition_labels
        rows.append(
            {
                "Performance metric": titles.get(r.variable, r.variable),
                "change": f"{label.get(r.condition, r.condition)} vs {label.get(r.against, r.against)}",
                "relative change [CI]": f"{fmt(100 * r.relative_change, 1)} % "
                f"[{fmt(100 * r.ci_low, 1)}, {fmt(100 * r.ci_high, 1)}]",
                "n": f"{r.n_condition} vs {r.n_against}",
            }
        )
    return pd.DataFrame(rows)


def _section(c: Comparison, cfg: AnalysisConfig, figures: dict[str, Path], out: Path) -> list[str]:
    v = c.variable
    lines = [f"## {v.title}", ""]
    lines += [f"- {note}" for note in c.notes]
    if c.power_note:
        lines.append(f"- power: {c.power_note}")
    lines.append("")
    if not c.assumptions.empty:
        a = c.assumptions.assign(
            statistic=c.assumptions.statistic.map(lambda x: fmt(x, 3)),
            p=c.assumptions.p.map(_p),
            passed=[
                ("yes" if ok else "no") if math.isfinite(p) else "not checked (n < 3)"
                for ok, p in zip(c.assumptions.passed, c.assumptions.p)
            ],
        )
        lines += ["**Assumption checks**", "", a.to_markdown(index=False), ""]
    if not c.tests.empty:
        t = c.tests.copy()
        t["result"] = [
            f"{r.statistic}({fmt(r.df1, 2)}{'' if not math.isfinite(r.df2) else ', ' + fmt(r.df2, 2)}) "
            f"= {fmt(r.value, 3)}, {_p_clause(r.p)}"
            for r in t.itertuples()
        ]
        t["effect size"] = [
            f"{r.effect} = {fmt(r.effect_value, 3)}"
            + (f" [{fmt(r.effect_ci_low, 3)}, {fmt(r.effect_ci_high, 3)}]" if math.isfinite(r.effect_ci_low) else "")
            if r.effect
            else ""
            for r in t.itertuples()
        ]
        t["read"] = ["**yes**" if r.test == c.recommended_test else "" for r in t.itertuples()]
        lines += ["**Tests**", "", t[["test", "result", "effect size", "read"]].to_markdown(index=False), ""]
    if not c.posthoc.empty:
        ph = c.posthoc.copy()
        ph["difference"] = ph.mean_diff.map(lambda x: fmt(x, v.decimals + 1))
        ph["p (adjusted)"] = ph.p_adj.map(_p)
        ph["Hedges' g [CI]"] = [
            f"{fmt(r.hedges_g, 2)} [{fmt(r.g_ci_low, 2)}, {fmt(r.g_ci_high, 2)}]" for r in ph.itertuples()
        ]
        ph["read"] = ["**yes**" if m == c.recommended_posthoc else "" for m in ph.method]
        lines += [
            f"**Post hoc** (difference = a − b, {v.unit or 'units'})",
            "",
            ph[["method", "a", "b", "difference", "p (adjusted)", "Hedges' g [CI]", "read"]].to_markdown(index=False),
            "",
        ]
    if v.column in figures:
        lines += [f"![{v.label}]({figures[v.column].relative_to(out)})", ""]
    return lines


def metrics_note(metrics: MetricsConfig) -> str:
    """How the tracking error and completeness were computed, for the report."""
    return (
        f"Tracking error: the mean of evo's RPE (translation part, delta = {metrics.delta_frames} frames, "
        f"{'all' if metrics.all_pairs else 'non-overlapping'} pairs, association within "
        f"{metrics.association_max_dt_s * 1e3:g} ms, SE(3) alignment, Sim(3) for monocular) over a "
        "participant's task; completeness: the share of camera frames tracked from initialisation on."
    )


def render_report(
    table: pd.DataFrame,
    comparisons: list[Comparison],
    conditions: list[str],
    design: str,
    cfg: AnalysisConfig,
    figures: dict[str, Path],
    out: Path,
    title: str,
    note: str = "",
    changes: pd.DataFrame | None = None,
    shares: pd.DataFrame | None = None,
) -> str:
    measured = table.dropna(subset=[c.variable.column for c in comparisons], how="all")
    counts = measured.groupby("condition").participant.nunique().reindex(conditions, fill_value=0)
    statuses = table.status.value_counts().to_dict() if "status" in table else {}
    lines = [
        f"# {title}",
        "",
        f"Design: {design}-subjects, conditions {', '.join(conditions)}; participants with data per "
        f"condition: "
        f"{', '.join(f'{c} {n}' for c, n in counts.items())}"
        + (f"; sessions {', '.join(f'{k} {v}' for k, v in statuses.items())}." if statuses else "."),
        f"Tests at alpha = {cfg.alpha}; intervals at {cfg.confidence:.0%}. Tidy tables: participants.csv, "
        "rpe_pairs.csv, descriptives.csv, assumptions.csv, tests.csv, posthoc.csv.",
        "",
    ]
    if note:
        lines.append(note)
    lines += [
        "",
        "## Results per condition (Table 5 layout: mean ± SD [95 % CI])",
        "",
        table5(comparisons, conditions, cfg).to_markdown(index=False),
        "",
    ]
    if changes is not None and not changes.empty:
        lines += [
            f"## Relative change of the means ({cfg.confidence:.0%} percentile bootstrap CI)",
            "",
            "mean of the condition / mean of the other − 1; negative is lower. Tidy table: changes.csv.",
            "",
            changes_table(changes, comparisons, cfg).to_markdown(index=False),
            "",
        ]
    if shares is not None and not shares.empty:
        lines += _shares_section(shares, comparisons, cfg)
    tradeoffs = [p for key, p in figures.items() if key.startswith("tradeoff_")]
    if tradeoffs:
        lines += [
            "## Time on task against tracking error",
            "",
            "One point per participant and condition; diamonds: the conditions' means; dashed: the least-squares line "
            "through the conditions that sound without information about the error (none, yoked), i.e. what slowing "
            "down alone buys.",
            "",
        ]
        lines += [f"![{p.stem}]({p.relative_to(out)})\n" for p in tradeoffs]
    for c in comparisons:
        lines += _section(c, cfg, figures, out)
    extra = [p for key, p in figures.items() if key.startswith(("trajectories_", "error_over_time_"))]
    if extra:
        lines += ["## Trajectories and error over time", ""]
        lines += [f"![{p.stem}]({p.relative_to(out)})\n" for p in extra]
    return "\n".join(lines) + "\n"


#: The error variables the oracle's share is reported on, where the participants table has them.
SHARE_VARIABLES = ("error_per_metre", "error_per_radian", "rpe_mean_m")
#: The trade-off figures: time on task against these.
TRADEOFF_OF = ("time_on_task_s", ("rpe_mean_m", "error_per_metre"))


def shares_of(table: pd.DataFrame, design: str, cfg: AnalysisConfig) -> pd.DataFrame:
    """The oracle's share (:func:`analysis.stats.oracle_share`) of every variable of :data:`SHARE_VARIABLES`."""
    rows = [oracle_share(table, v, design, cfg) for v in cfg.variables if v.column in SHARE_VARIABLES]
    return pd.DataFrame([r for r in rows if r is not None])


def _shares_section(shares: pd.DataFrame, comparisons: list[Comparison], cfg: AnalysisConfig) -> list[str]:
    titles = {c.variable.column: c.variable for c in comparisons}
    rows = []
    for r in shares.itertuples():
        v = titles.get(r.variable)
        rows.append(
            {
                "Performance metric": v.title if v else r.variable,
                "yoked": fmt(r.yoked_mean, 3),
                "seesys": fmt(r.seesys_mean, 3),
                "oracle": fmt(r.oracle_mean, 3),
                f"oracle vs yoked [{cfg.confidence:.0%} CI]": f"{fmt(100 * r.oracle_vs_yoked, 1)} % "
                f"[{fmt(100 * r.oracle_ci_low, 1)}, {fmt(100 * r.oracle_ci_high, 1)}]",
                f"share of the oracle's gain [{cfg.confidence:.0%} CI]": f"{fmt(100 * r.share_of_oracle_gain, 1)} % "
                f"[{fmt(100 * r.ci_low, 1)}, {fmt(100 * r.ci_high, 1)}]",
                "n": r.n,
            }
        )
    return [
        "## How much of the oracle's gain SEESys reaches",
        "",
        "(mean of yoked − mean of seesys) / (mean of yoked − mean of oracle), lower error being better: 0 % is no "
        "better than the same sound without information, 100 % as good as Equation 2 on the true error. "
        f"Means in the reported units; {cfg.confidence:.0%} percentile bootstrap CI over participants. "
        "The share means something only where the oracle gains over yoked (its change's interval below 0): where "
        "the oracle's gain is near 0 the ratio, and its interval, are a division by almost nothing. "
        "Tidy table: oracle_share.csv.",
        "",
        pd.DataFrame(rows).to_markdown(index=False),
        "",
    ]


def write_report(markdown: str, out: Path, title: str) -> None:
    (out / REPORT_MD).write_text(markdown)
    body = MarkdownIt("commonmark").enable("table").render(markdown)
    (out / REPORT_HTML).write_text(
        f'<!DOCTYPE html>\n<html><head><meta charset="utf-8"><title>{title}</title>'
        f"<style>{HTML_STYLE}</style></head><body>\n{body}</body></html>\n"
    )


def analyse_study(study: Path, out: Path | None, cfg: AnalysisConfig, metrics: MetricsConfig) -> AnalysisResult:
    """The whole analysis of a study folder (see the module docstring)."""
    out = Path(out or Path(study) / "analysis")
    data = collect_study(study, metrics, advice_thresholds())
    table = data.participants
    if not cfg.include_incomplete:
        table = table[table.status == DONE]
    if table[[v.column for v in cfg.variables if v.column in table]].dropna(how="all").empty:
        raise SeesysError(f"{study}: no participant has a trajectory with ground truth yet (`seesys study status`)")
    # Only once there is something to analyse: an error above leaves no empty analysis folder behind.
    figures_dir = out / "figures"
    figures_dir.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "participants.csv", index=False)
    data.pairs.to_csv(out / "rpe_pairs.csv", index=False)
    conditions = data.protocol.conditions
    comparisons = analyse_table(table, conditions, data.protocol.design, cfg)
    write_tables(comparisons, out)
    changes = changes_of(table, comparisons, conditions, data.protocol.design, cfg)
    changes.to_csv(out / "changes.csv", index=False)
    shares = shares_of(table, data.protocol.design, cfg)
    if not shares.empty:
        shares.to_csv(out / "oracle_share.csv", index=False)
    figures: dict[str, Path] = {
        c.variable.column: plots.box_strip(table, c.variable, conditions, figures_dir) for c in comparisons
    }
    variables = {v.column: v for v in cfg.variables}
    x_column, y_columns = TRADEOFF_OF
    for y_column in y_columns:
        if x_column in variables and y_column in variables:
            path = plots.tradeoff(table, conditions, variables[x_column], variables[y_column], figures_dir)
            if path is not None:
                figures[f"tradeoff_{y_column}"] = path
    for condition in conditions:
        for kind, draw in (("trajectories", plots.trajectories), ("error_over_time", plots.error_over_time)):
            path = draw(data, condition, cfg, figures_dir)
            if path is not None:
                figures[f"{kind}_{condition}"] = path
    title = f"Study {Path(study).resolve().name}"
    write_report(
        render_report(
            table,
            comparisons,
            conditions,
            data.protocol.design,
            cfg,
            figures,
            out,
            title,
            metrics_note(metrics),
            changes,
            shares,
        ),
        out,
        title,
    )
    return AnalysisResult(out, comparisons, table)


def analyse_csv(path: Path, out: Path, design: str, cfg: AnalysisConfig) -> AnalysisResult:
    """The statistics and box plots of a tidy participants table (``participants.csv`` or one edited by hand)."""
    try:
        table = pd.read_csv(path)
    except (OSError, pd.errors.ParserError) as e:
        raise SeesysError(f"cannot read {path}: {e}") from None
    missing = {"participant", "condition"} - set(table)
    if missing:
        raise SeesysError(f"{path}: missing column(s) {', '.join(sorted(missing))}")
    if "position" not in table:
        table["position"] = 1
    out.mkdir(parents=True, exist_ok=True)
    (out / "figures").mkdir(exist_ok=True)
    conditions = list(dict.fromkeys(table.condition))
    comparisons = analyse_table(table, conditions, design, cfg)
    write_tables(comparisons, out)
    figures = {c.variable.column: plots.box_strip(table, c.variable, conditions, out / "figures") for c in comparisons}
    title = f"Analysis of {path.name}"
    write_report(render_report(table, comparisons, conditions, design, cfg, figures, out, title), out, title)
    return AnalysisResult(out, comparisons, table)
