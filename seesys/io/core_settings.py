"""Settings of the core's concepts, loaded from ``configs/``: model windows (``windows.toml``), the label
definition (``labels.toml``) and Equation 2 with the advisory timing it is scored on (``advisory.toml``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core.equation2 import Equation2Config, PulseSettings
from seesys.core.labels import LabelConfig
from seesys.core.windows import WindowConfig
from seesys.io.config import build, config_dir, load_section, read_toml


def load_window_config(directory: Path | None = None) -> WindowConfig:
    """The model windows of ``configs/windows.toml``."""
    return load_section("windows", WindowConfig, directory)


def load_label_config(directory: Path | None = None) -> LabelConfig:
    """The pose-error label's settings, ``configs/labels.toml``."""
    return load_section("labels", LabelConfig, directory)


@dataclass(frozen=True)
class _PulseTiming:
    buffer_s: float
    window_s: float


def load_pulse_settings(directory: Path | None = None) -> PulseSettings:
    """Equation 2 and the two timings its pulse counts depend on, from ``configs/advisory.toml`` (the advisory
    itself loads and checks the whole file)."""
    path = (directory or config_dir()) / "advisory.toml"
    data = read_toml(path)
    equation2 = build(Equation2Config, data.get("equation2", {}), f"{path} [equation2]")
    timing = data.get("timing", {})
    picked = build(_PulseTiming, {k: timing[k] for k in ("buffer_s", "window_s") if k in timing}, f"{path} [timing]")
    return PulseSettings(equation2, picked.buffer_s, picked.window_s)
