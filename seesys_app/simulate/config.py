"""``configs/simulate.toml`` as typed, frozen dataclasses, checked for consistency."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from advisory.conditions import Condition
from seesys.core.errors import ConfigError
from seesys.io.config import load_section
from seesys_app.simulate.operator import OperatorRanges, ResponseRanges
from seesys_app.simulate.scan_task import TaskConfig

DESIGNS = ("between", "within")
#: Every advisory condition a simulated study may have, the simulation-only controls included.
CONDITIONS = tuple(c.value for c in Condition)


@dataclass(frozen=True)
class StudyDefaults:
    conditions: list[str]
    participants_per_condition: int
    design: str
    operator_seed: int
    processes: int
    retries: int
    stall_timeout_s: float


@dataclass(frozen=True)
class LoopConfig:
    estimate_latency_s: float
    audio_latency_s: float


@dataclass(frozen=True)
class SimulateConfig:
    study: StudyDefaults
    task: TaskConfig
    operator: OperatorRanges
    response: ResponseRanges
    loop: LoopConfig


def load_simulate_config(directory: Path | None = None) -> SimulateConfig:
    """Load ``configs/simulate.toml``; :class:`ConfigError` names a value that cannot work."""
    cfg = load_section("simulate", SimulateConfig, directory)
    unknown = [c for c in cfg.study.conditions if c not in CONDITIONS]
    if unknown:
        raise ConfigError(f"simulate.toml: unknown condition(s) {', '.join(unknown)} (use {', '.join(CONDITIONS)})")
    if cfg.study.design not in DESIGNS:
        raise ConfigError(f"simulate.toml: design {cfg.study.design!r} is neither between nor within")
    if len(cfg.operator.motion_groups) != len(cfg.operator.motion_group_weights):
        raise ConfigError("simulate.toml: motion_groups and motion_group_weights differ in length")
    # The operator moves a little ahead of the frame being rendered (its exposure); a reaction faster than that
    # would need buffers the loop has not made yet.
    if cfg.response.reaction_delay_s[0] < 0.2:
        raise ConfigError(
            "simulate.toml: reaction_delay_s must be at least 0.2 s (the loop renders ahead of the "
            "advice by up to one frame and an exposure)"
        )
    return cfg
