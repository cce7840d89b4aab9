"""``configs/dataset.toml`` as typed records."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from seesys.core.errors import ConfigError
from seesys.io.config import load_section
from slam_monitor.orbslam_settings import SlamMode
from synth.batch import CameraDraw


@dataclass(frozen=True)
class ReportConfig:
    thresholds_m: tuple[float, ...]
    histogram_range_m: tuple[float, float]
    histogram_bins: int
    top_features: int
    scatter_plots: int
    min_samples: int


@dataclass(frozen=True)
class TargetConfig:
    median_m: tuple[float, float]
    p90_m: tuple[float, float]
    p99_min_m: float
    above_12mm_fraction: tuple[float, float]
    tracked_min_fraction: float
    spearman_min_abs: float


@dataclass(frozen=True)
class SplitConfig:
    rounds: int
    seed: int
    heldout_environments: tuple[str, ...]  # the same rooms held out in every round; () to rotate them
    heldout_cameras: tuple[str, ...]  # round r holds out the (r mod n)-th
    heldout_environments_per_round: int = 0  # rooms held out per round, rotated, when heldout_environments is ()


@dataclass(frozen=True)
class LockboxConfig:
    """A room and a camera model whose runs no split round uses, and the SHA-256 of ``"room|camera"`` recorded
    when they were chosen (so that a changed lockbox is noticed)."""

    environment: str
    camera_model: str
    sha256: str

    def __post_init__(self) -> None:
        if lockbox_hash(self.environment, self.camera_model) != self.sha256:
            raise ValueError(
                f"lockbox {self.environment}|{self.camera_model} does not match its recorded sha256: "
                f"the lockbox was chosen once and must not change"
            )


def lockbox_hash(environment: str, camera_model: str) -> str:
    return hashlib.sha256(f"{environment}|{camera_model}".encode()).hexdigest()


@dataclass(frozen=True)
class SampleSequenceConfig:
    environment: str
    motion: str
    seed: int
    frames: int
    jpeg_quality: int


@dataclass(frozen=True)
class DatasetConfig:
    environments: tuple[str, ...]
    motions: tuple[str, ...]
    seeds: tuple[int, ...]
    trials: int
    modes: tuple[str, ...]
    pace: bool
    wait_for_mapping_modes: tuple[str, ...]
    keep_sessions: bool
    window_end_stride: int
    cameras: CameraDraw
    report: ReportConfig
    targets: TargetConfig
    splits: SplitConfig
    lockbox: LockboxConfig
    sample: SampleSequenceConfig


def load_dataset_config(directory: Path | None = None) -> DatasetConfig:
    """Load ``configs/dataset.toml``."""
    config = load_section("dataset", DatasetConfig, directory)
    known = {mode.value for mode in SlamMode}
    unknown = sorted(set(config.modes + config.wait_for_mapping_modes) - known)
    if unknown:
        raise ConfigError(
            f"configs/dataset.toml: unknown SLAM mode(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})"
        )
    return config
