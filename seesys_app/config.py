"""``configs/app.toml``: the defaults of ``seesys run``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core.errors import ConfigError
from seesys.io.config import load_section

MODES = ("rgbd", "mono")


@dataclass(frozen=True)
class DeviceConfig:
    mode: str
    pace: bool


@dataclass(frozen=True)
class SupervisionConfig:
    ready_timeout_s: float
    reach_timeout_s: float
    first_estimate_s: float
    restart_delay_s: float
    max_restarts: int
    stop_timeout_s: float
    status_interval_s: float


@dataclass(frozen=True)
class LocalEstimatorConfig:
    workers: int


@dataclass(frozen=True)
class ViewConfig:
    sparkline_s: float
    latency_window: int
    buffers_shown: int
    estimator_poll_s: float
    status_timeout_ms: int


@dataclass(frozen=True)
class OutputConfig:
    wav: str
    summary: str
    plot: str
    events: str


@dataclass(frozen=True)
class AppConfig:
    device: DeviceConfig
    supervision: SupervisionConfig
    local_estimator: LocalEstimatorConfig
    view: ViewConfig
    output: OutputConfig


def load_app_config(directory: Path | None = None) -> AppConfig:
    """Load and check ``configs/app.toml`` (``directory`` overrides the config folder); ConfigError names the
    problem."""
    cfg = load_section("app", AppConfig, directory)
    s, v = cfg.supervision, cfg.view
    problems = []
    if cfg.device.mode not in MODES:
        problems.append(f"device.mode must be one of {', '.join(MODES)} (got {cfg.device.mode!r})")
    positive = {
        "ready_timeout_s": s.ready_timeout_s,
        "reach_timeout_s": s.reach_timeout_s,
        "first_estimate_s": s.first_estimate_s,
        "stop_timeout_s": s.stop_timeout_s,
        "status_interval_s": s.status_interval_s,
        "sparkline_s": v.sparkline_s,
        "latency_window": v.latency_window,
        "buffers_shown": v.buffers_shown,
        "estimator_poll_s": v.estimator_poll_s,
        "status_timeout_ms": v.status_timeout_ms,
    }
    problems += [f"{name} must be positive (got {value})" for name, value in positive.items() if value <= 0]
    if s.restart_delay_s < 0 or s.max_restarts < 0:
        problems.append("restart_delay_s and max_restarts must not be negative")
    if cfg.local_estimator.workers < 0:
        problems.append(f"local_estimator.workers must not be negative (got {cfg.local_estimator.workers})")
    if problems:
        raise ConfigError("app.toml: " + "; ".join(problems))
    return cfg
