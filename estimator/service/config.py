"""The typed form of ``configs/service.toml``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.config import load_section
from seesys.errors import ConfigError


@dataclass(frozen=True)
class CurveConfig:
    enabled: bool
    server_secret_key: str
    allowed_clients: str


@dataclass(frozen=True)
class ServiceConfig:
    ingest_endpoint: str
    connect_device_stream: bool
    worker_endpoint: str
    status_endpoint: str
    workers: int
    model: str
    providers: str
    max_message_bytes: int
    max_batch: int
    stale_after_ms: float
    worker_queue: int
    ingest_queue: int
    heartbeat_ms: int
    worker_timeout_ms: int
    worker_start_timeout_s: float
    latency_window: int
    rate_window_s: float
    curve: CurveConfig

    def __post_init__(self) -> None:
        for name in ("workers", "max_message_bytes", "max_batch", "worker_queue", "ingest_queue", "heartbeat_ms",
                     "latency_window"):
            if getattr(self, name) < 1:
                raise ConfigError(f"service.toml: {name} must be at least 1, got {getattr(self, name)}")
        if self.worker_timeout_ms <= 2 * self.heartbeat_ms:
            raise ConfigError("service.toml: worker_timeout_ms must exceed two heartbeats")
        if self.curve.enabled and not (self.curve.server_secret_key and self.curve.allowed_clients):
            raise ConfigError("service.toml: [curve] enabled needs server_secret_key and allowed_clients")


def load_service_config(directory: Path | None = None) -> ServiceConfig:
    return load_section("service", ServiceConfig, directory)
