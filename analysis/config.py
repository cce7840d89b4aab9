"""``configs/analysis.toml``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.io.config import load_section


@dataclass(frozen=True)
class Variable:
    column: str
    label: str
    unit: str
    scale: float
    decimals: int

    @property
    def title(self) -> str:
        return f"{self.label} ({self.unit})" if self.unit else self.label


@dataclass(frozen=True)
class AnalysisConfig:
    alpha: float
    confidence: float
    target_power: float
    bootstrap_resamples: int
    bootstrap_seed: int
    include_incomplete: bool
    plots_per_condition: int
    changes_of: list[str]
    condition_labels: dict[str, str]
    variables: list[Variable]


def load_analysis_config(directory: Path | None = None) -> AnalysisConfig:
    return load_section("analysis", AnalysisConfig, directory)
