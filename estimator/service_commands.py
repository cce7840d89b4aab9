"""``seesys estimator serve | worker | status | keys | untrained-model``: thin wrappers over
:mod:`estimator.service`. They join the ``seesys estimator`` group that :mod:`estimator.model_commands` creates."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seesys.core.errors import SeesysError


def _configs():
    from estimator.service.config import load_service_config
    from seesys.io.core_settings import load_window_config
    from seesys.io.network import load_network_config

    return load_service_config(), load_network_config(), load_window_config()


def _serve(args: argparse.Namespace) -> int:
    from estimator.service.broker import default_model
    from estimator.service.serve import serve

    config, network, windows = _configs()
    if args.workers is not None and args.workers < 0:
        raise SeesysError("--workers must be at least 0 (0: the broker runs the model itself)")
    model = default_model(config, args.model)
    devices = list(args.device or [])
    if config.connect_device_stream and not config.curve.enabled:
        devices.insert(0, network.features_endpoint)
    workers = config.workers if args.workers is None else args.workers

    def ready(broker) -> None:
        endpoints = broker.endpoints
        print(
            f"serving {broker.model_version} "
            + (f"on {workers} worker(s)" if workers else "in the broker's process")
            + f": features in at {endpoints['ingest']}"
            + "".join(f" and {d}" for d in devices)
            + f", estimates out at {endpoints['estimates']}, status at "
            f"{endpoints['status']}, workers at {endpoints['workers']}",
            flush=True,
        )

    broker = serve(config, network, windows, model, workers, devices, on_ready=ready)
    status = broker.status()
    estimates = sum(d["estimates"] for d in status["devices"].values())
    print(
        f"stopped: {len(status['devices'])} device(s), {estimates} estimates published, rejected "
        + ", ".join(f"{k} {v}" for k, v in status["rejected"].items()),
        flush=True,
    )
    return 0


def _worker(args: argparse.Namespace) -> int:
    from estimator.service.broker import default_model
    from estimator.service.worker import run_worker

    config, _, windows = _configs()
    run_worker(args.broker or config.worker_endpoint, default_model(config, args.model), windows, config, args.name)
    return 0


def _status(args: argparse.Namespace) -> int:
    from estimator.service.status import format_status, query_status

    config, _, _ = _configs()
    status = query_status(args.endpoint or config.status_endpoint, args.timeout_ms)
    print(json.dumps(status, indent=2) if args.json else format_status(status))
    return 0


def _keys(args: argparse.Namespace) -> int:
    from estimator.service.keys import make_key_pair

    public, secret = make_key_pair(args.out, args.name)
    print(
        f"public key {public} (give it to the other end; a server lists its clients' in its allow-list folder), "
        f"secret key {secret} (keep it here)"
    )
    return 0


def _untrained_model(args: argparse.Namespace) -> int:
    from estimator.deepsee.export import export_untrained
    from estimator.service.model import model_version
    from seesys.core.psd import PsdGeometry
    from seesys.io.core_settings import load_window_config
    from slam_monitor.monitor_config import load_monitor_config

    # Camera normalisation puts every camera's PSD on the reference camera's grid.
    monitor = load_monitor_config()
    camera, psd = monitor.reference_camera, monitor.psd
    height, width, _ = PsdGeometry(camera.width, camera.height, psd.patch_px, psd.expansion).shape
    path = export_untrained(args.out, load_window_config(), (height, width), args.seed)
    print(
        f"wrote {path} ({model_version(path)}): DeepSEE of the configured size for {height}x{width} PSD "
        f"matrices, with untrained weights (serves the right shape and cost; its estimates mean nothing)"
    )
    return 0


def _estimator_group(subparsers: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """The subcommands of the existing ``seesys estimator`` parser."""
    parser = subparsers.choices["estimator"]
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the service's commands to ``seesys estimator``."""
    sub = _estimator_group(subparsers)

    p = sub.add_parser(
        "serve",
        help="serve estimates to devices: a broker and a pool of worker processes",
        description="Subscribe to device feature streams, run the model at every window end and "
        "publish each estimate (configs/service.toml, network.toml). Stops on SIGINT or "
        "SIGTERM.",
    )
    p.add_argument("--model", type=Path, help="ONNX model (default: model of configs/service.toml)")
    p.add_argument(
        "--workers",
        type=int,
        help="local worker processes; 0: the broker runs the model itself (default: configs/service.toml)",
    )
    p.add_argument(
        "--device",
        action="append",
        metavar="ENDPOINT",
        help="also connect to a device that binds its feature stream here (repeatable)",
    )
    p.set_defaults(func=_serve)

    p = sub.add_parser("worker", help="one more worker for a running service (this machine or another)")
    p.add_argument("--broker", metavar="ENDPOINT", help="the service's worker endpoint (default: configs/service.toml)")
    p.add_argument("--model", type=Path, help="ONNX model, the same file as the service's (default: configs)")
    p.add_argument("--name", help="name in `seesys estimator status` (default host:pid)")
    p.set_defaults(func=_worker)

    p = sub.add_parser("status", help="devices, rates, queue depths, drops and latency of a running service")
    p.add_argument("--endpoint", help="status endpoint (default: configs/service.toml)")
    p.add_argument("--timeout-ms", type=int, default=2000, help="how long to wait for an answer (default 2000)")
    p.add_argument("--json", action="store_true", help="print the raw status as JSON")
    p.set_defaults(func=_status)

    p = sub.add_parser("keys", help="make a CurveZMQ key pair (NAME.key public, NAME.key_secret secret)")
    p.add_argument("--out", type=Path, required=True, help="folder for the key files")
    p.add_argument("--name", required=True, help="key pair name, e.g. server or device-0")
    p.set_defaults(func=_keys)

    p = sub.add_parser(
        "untrained-model",
        help="export an untrained DeepSEE of the configured size (a stand-in to serve until a trained model ships)",
    )
    p.add_argument("--out", type=Path, required=True, help="ONNX file to write")
    p.add_argument("--seed", type=int, default=0, help="seed of the random weights (default 0)")
    p.set_defaults(func=_untrained_model)
