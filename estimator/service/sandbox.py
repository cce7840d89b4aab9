"""Running the service beside others (tests, benchmarks): a private copy of the configuration in which every
endpoint of the service, its devices and its subscribers is an ipc:// socket in one folder, and the service started
as a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from estimator.service import config as service_config
from estimator.service.broker import ServiceError
from estimator.service.status import query_status
from seesys.io import network as network_config
from seesys.io.config import CONFIG_DIR_ENV, ConfigSet

ENDPOINTS = ("ingest", "workers", "status", "estimates", "features")


def private_configs(folder: Path, **overrides: object) -> tuple[Path, dict[str, str]]:
    """``folder/configs`` with ipc endpoints in ``folder`` (keep it short: ipc paths are at most 107 bytes) and
    ``overrides`` (config keys by name or as ``file.key``); returns it and the endpoints by name."""
    endpoints = {name: f"ipc://{Path(folder).resolve()}/{name}" for name in ENDPOINTS}
    configs = ConfigSet.read()
    network = replace(
        configs.section(network_config.SECTION, network_config.NetworkConfig),
        ingest_endpoint=endpoints["ingest"],
        estimates_endpoint=endpoints["estimates"],
        features_endpoint=endpoints["features"],
    )
    service = replace(
        service_config.load_service_config(), worker_endpoint=endpoints["workers"], status_endpoint=endpoints["status"]
    )
    configs = (
        configs.replaced(network_config.SECTION, network)
        .replaced(service_config.SECTION, service)
        .with_values(overrides)
    )
    return configs.write(Path(folder) / "configs"), endpoints


def start_service(config_dir: Path, model: Path, *args: str, log: Path) -> subprocess.Popen:
    """``seesys estimator serve --model MODEL ARGS`` with ``config_dir``, its output into ``log``."""
    with open(log, "w") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "seesys", "estimator", "serve", "--model", str(model), *args],
            env={**os.environ, CONFIG_DIR_ENV: str(config_dir)},
            stdout=out,
            stderr=subprocess.STDOUT,
        )


def wait_ready(process: subprocess.Popen, status_endpoint: str, timeout_s: float, log: Path) -> dict:
    """The status of the started service once it answers; :class:`ServiceError` if it ends or never answers."""
    deadline = time.monotonic() + timeout_s
    while True:
        if process.poll() is not None:
            raise ServiceError(f"the service ended with status {process.returncode}:\n{log.read_text()}")
        try:
            return query_status(status_endpoint, 500)
        except ServiceError:
            if time.monotonic() > deadline:
                raise ServiceError(f"the service did not answer within {timeout_s:g} s") from None
