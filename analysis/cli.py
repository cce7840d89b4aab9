"""``seesys analyze``: the statistics, tables, figures and report of a study."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from seesys.core.errors import SeesysError


def analyze_command(args: argparse.Namespace) -> int:
    from analysis.config import load_analysis_config
    from analysis.report import REPORT_HTML, REPORT_MD, analyse_csv, analyse_study, fmt
    from study.config import load_study_config

    cfg = load_analysis_config()
    with warnings.catch_warnings():
        # scipy and pingouin warn on small groups; the report states which tests apply and why.
        warnings.simplefilter("ignore")
        if args.table:
            if args.out is None:
                raise SeesysError("--table needs --out")
            result = analyse_csv(args.table, args.out, args.design, cfg)
        elif args.study:
            result = analyse_study(args.study, args.out, cfg, load_study_config().metrics)
        else:
            raise SeesysError("give a study folder or --table CSV")
    for c in result.comparisons:
        print(
            f"{c.variable.title}: "
            + ", ".join(
                f"{r.condition} {fmt(r.mean, c.variable.decimals)} ± {fmt(r.sd, c.variable.decimals)} (n={r.n})"
                for r in c.descriptives.itertuples()
            )
        )
        if c.recommended_test:
            t = c.tests[c.tests.test == c.recommended_test].iloc[0]
            print(f"  {c.recommended_test}: {t.statistic} = {t.value:.3f}, p = {t.p:.4f}")
    print(f"report: {result.out / REPORT_MD}, {result.out / REPORT_HTML}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add ``seesys analyze``."""
    p = subparsers.add_parser(
        "analyze",
        help="statistics, Table 5, figures and report of a study",
        description="Per-participant metrics of a study folder, the Table 5 layout, assumption checks, ANOVA / "
        "Welch / Kruskal-Wallis (or repeated measures), post hoc tests, effect sizes with CIs, a "
        "power note, figures, a Markdown and HTML report and tidy CSVs (configs/analysis.toml).",
    )
    p.add_argument("study", nargs="?", type=Path, metavar="STUDY_DIR")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default STUDY_DIR/analysis)")
    p.add_argument(
        "--table",
        type=Path,
        metavar="CSV",
        help="analyse a tidy participants table (participant, condition, metric columns) instead",
    )
    p.add_argument("--design", choices=("between", "within"), default="between", help="design of --table")
    p.set_defaults(func=analyze_command)
    return {}
