"""The ZeroMQ endpoints of ``configs/network.toml`` and the CurveZMQ keys of a client of the estimator service."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from seesys.core.errors import ConfigError
from seesys.io.config import load_section


@dataclass(frozen=True)
class ClientCurveConfig:
    """This client's key pair and the estimator service's public key (files made by ``seesys estimator keys``,
    relative to the SEESys home). Both empty: plaintext, for a service on the same machine or a trusted network."""

    server_public_key: str
    client_secret_key: str

    def __post_init__(self) -> None:
        if bool(self.server_public_key) != bool(self.client_secret_key):
            raise ConfigError(
                "network.toml: [curve] needs both server_public_key and client_secret_key (or neither, for plaintext)"
            )

    @property
    def enabled(self) -> bool:
        return bool(self.server_public_key)


@dataclass(frozen=True)
class NetworkConfig:
    features_endpoint: str
    ingest_endpoint: str
    estimates_endpoint: str
    send_high_water_mark: int
    curve: ClientCurveConfig

    def client_options(self, endpoint: str) -> Mapping[int, int | bytes]:
        """Socket options of a client connecting to ``endpoint``: this client's Curve keys where ``endpoint`` is the
        estimator service's (``ingest_endpoint``, ``estimates_endpoint``) and ``[curve]`` is set, else none.
        Raises :class:`seesys.io.transport.CurveKeyError` when a key file cannot be read."""
        if not self.curve.enabled or endpoint not in (self.ingest_endpoint, self.estimates_endpoint):
            return {}
        from seesys.io.resources import resolve
        from seesys.io.transport import ClientKeys

        return ClientKeys(resolve(self.curve.client_secret_key), resolve(self.curve.server_public_key)).socket_options()


#: The file of :class:`NetworkConfig` in the configuration folder.
SECTION = "network"


def load_network_config(directory: Path | None = None) -> NetworkConfig:
    return load_section(SECTION, NetworkConfig, directory)
