"""The ZeroMQ endpoints of ``configs/network.toml``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.config import load_section


@dataclass(frozen=True)
class NetworkConfig:
    features_endpoint: str
    estimates_endpoint: str
    send_high_water_mark: int


def load_network_config(directory: Path | None = None) -> NetworkConfig:
    return load_section("network", NetworkConfig, directory)
