"""The typed form of ``configs/service.toml``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core.errors import ConfigError
from seesys.io.config import load_section


@dataclass(frozen=True)
class CurveConfig:
    """The server's secret key file and the allow-list folder of client public keys; both empty: plaintext."""

    server_secret_key: str
    allowed_clients: str

    def __post_init__(self) -> None:
        if bool(self.server_secret_key) != bool(self.allowed_clients):
            raise ConfigError(
                "service.toml: [curve] needs both server_secret_key and allowed_clients (or neither, for plaintext)"
            )

    @property
    def enabled(self) -> bool:
        return bool(self.server_secret_key)


@dataclass(frozen=True)
class ServiceConfig:
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
    id_takeover_after_s: float
    curve: CurveConfig

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ConfigError(f"service.toml: workers must be at least 0, got {self.workers}")
        for name in (
            "max_message_bytes",
            "max_batch",
            "worker_queue",
            "ingest_queue",
            "heartbeat_ms",
            "latency_window",
        ):
            if getattr(self, name) < 1:
                raise ConfigError(f"service.toml: {name} must be at least 1, got {getattr(self, name)}")
        if self.worker_timeout_ms <= 2 * self.heartbeat_ms:
            raise ConfigError("service.toml: worker_timeout_ms must exceed two heartbeats")


#: The file of :class:`ServiceConfig` in the configuration folder.
SECTION = "service"


def load_service_config(directory: Path | None = None) -> ServiceConfig:
    return load_section(SECTION, ServiceConfig, directory)
