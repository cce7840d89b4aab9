"""Settings of the core's concepts, loaded from ``configs/``: model windows (``windows.toml``), the label
definition (``labels.toml``), Equation 2 with the advisory timing it is scored on (``advisory.toml``) and the
device settings a model depends on (``monitor.toml``, ``slam.toml``; for a model made here, ``dataset.toml`` and
``synth.toml``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from seesys.core.camera_normalisation import ReferenceCamera
from seesys.core.device_settings import DeviceSettings, model_settings_record
from seesys.core.equation2 import Equation2Config, PulseSettings
from seesys.core.errors import ConfigError
from seesys.core.labels import LabelConfig
from seesys.core.windows import WindowConfig
from seesys.io.config import ConfigSet, build, load_section


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
    configs = ConfigSet.read(directory)
    path, data = configs.path("advisory"), configs.data("advisory")
    equation2 = build(Equation2Config, data.get("equation2", {}), f"{path} [equation2]")
    timing = data.get("timing", {})
    picked = build(_PulseTiming, {k: timing[k] for k in ("buffer_s", "window_s") if k in timing}, f"{path} [timing]")
    return PulseSettings(equation2, picked.buffer_s, picked.window_s)


def _value(directory: Path | None, file: str, *keys: str) -> tuple[Path, object]:
    """The value at ``keys`` of ``file``, as parsed, with the file's path for an error about it."""
    configs = ConfigSet.read(directory)
    path, data = configs.path(file), configs.data(file)
    for key in keys:
        if not isinstance(data, dict) or key not in data:
            raise ConfigError(f"{path}: missing {'.'.join(keys)}")
        data = data[key]
    return path, data


# The few values read here without their part's dataclass, checked as the loader checks a field
# (seesys.io.config): bool is no number, and an integer is a number.


def _int(directory: Path | None, file: str, *keys: str) -> int:
    path, value = _value(directory, file, *keys)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{path}: {'.'.join(keys)}: expected an integer, got {value!r}")
    return value


def _number(directory: Path | None, file: str, *keys: str) -> float:
    path, value = _value(directory, file, *keys)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{path}: {'.'.join(keys)}: expected a number, got {value!r}")
    return value


def _table(directory: Path | None, file: str, *keys: str) -> dict[str, Any]:
    path, value = _value(directory, file, *keys)
    if not isinstance(value, dict):
        raise ConfigError(f"{path}: {'.'.join(keys)}: expected a table, got {value!r}")
    return value


def _strings(directory: Path | None, file: str, *keys: str) -> list[str]:
    path, value = _value(directory, file, *keys)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{path}: {'.'.join(keys)}: expected a list of names, got {value!r}")
    return value


def load_device_settings(slam_mode: str, fps: float, directory: Path | None = None) -> DeviceSettings:
    """A device's settings (:class:`~seesys.core.device_settings.DeviceSettings`) running ``slam_mode`` at ``fps``
    with the configured PSD (``[psd]`` of monitor.toml) and ORB feature count (``[orb] features`` of slam.toml)."""
    return DeviceSettings.of(
        slam_mode,
        fps,
        _int(directory, "slam", "orb", "features"),
        _int(directory, "monitor", "psd", "patch_px"),
        _int(directory, "monitor", "psd", "expansion"),
        _number(directory, "monitor", "psd", "near_depth"),
    )


def load_reference_camera(directory: Path | None = None) -> ReferenceCamera:
    """The camera normalisation's reference camera, ``[reference_camera]`` of monitor.toml."""
    return build(
        ReferenceCamera,
        _table(directory, "monitor", "reference_camera"),
        f"{ConfigSet.read(directory).path('monitor')} [reference_camera]",
    )


def load_model_device_record(directory: Path | None = None) -> dict:
    """The device part of the compatibility record of a model trained here: the configured device settings (with
    this SEESys's camera normalisation version), the reference camera of the camera normalisation
    (``reference_camera``), the SLAM modes the dataset builder runs (``modes`` of dataset.toml) and the frame rate
    of its rendered sequences (``[camera] fps`` of synth.toml)."""
    modes = _strings(directory, "dataset", "modes")
    settings = load_device_settings(modes[0], _number(directory, "synth", "camera", "fps"), directory)
    return {**model_settings_record(settings, modes), "reference_camera": asdict(load_reference_camera(directory))}
