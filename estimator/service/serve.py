"""``seesys estimator serve``: the broker in this process and a pool of local worker processes beside it, or, with
no worker processes, the model run by the broker itself.

Start-up: the broker binds the worker endpoint, the workers (``spawn``-ed, each dying with this process) load the
model and say ready, and only then does the broker bind the device-facing endpoints. Shutdown: SIGINT or SIGTERM
ends the broker loop; the workers are told to stop, waited for, and killed if they do not end in time.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable
from pathlib import Path

from estimator.service.broker import Broker
from estimator.service.config import ServiceConfig
from estimator.service.model import ServedModel
from estimator.service.worker import worker_process_main
from estimator.service.worker_core import WorkerCore
from seesys.core.windows import WindowConfig
from seesys.io.network import NetworkConfig

# Seconds a stopping worker gets to finish its batch before it is killed.
_WORKER_EXIT_S = 10.0
#: The name ``status`` gives the worker in the broker's process (``workers = 0``).
IN_BROKER_NAME = "in-broker"


def serve(
    config: ServiceConfig,
    network: NetworkConfig,
    windows: WindowConfig,
    model: Path,
    workers: int,
    device_endpoints: list[str],
    on_ready: Callable[[Broker], None] = lambda broker: None,
) -> Broker:
    """Run the service until SIGINT/SIGTERM; returns the stopped broker (its final counters). ``workers`` worker
    processes; 0: the broker runs the model in its own loop (:mod:`estimator.service.broker`). A model made for
    other inputs, or a file that is no model, is refused here with one message (``ModelMismatch``), not in each
    worker."""
    served = ServedModel.load(model, windows, threads=1, providers=config.providers)
    core = WorkerCore(served, windows, config, IN_BROKER_NAME) if workers == 0 else None
    broker = Broker(config, network, device_endpoints, core=core)
    context = multiprocessing.get_context("spawn")
    backend = broker.endpoints["workers"]
    processes = [
        context.Process(
            target=worker_process_main,
            name=f"seesys-estimator-worker-{k}",
            args=(backend, model, windows, config, os.getpid(), f"local-{k}"),
        )
        for k in range(workers)
    ]
    previous = {s: signal.signal(s, broker.stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for process in processes:
            process.start()
        if broker.wait_for_workers(
            workers, config.worker_start_timeout_s, alive=lambda: all(p.is_alive() for p in processes)
        ):
            broker.open()
            on_ready(broker)
            broker.run()
    finally:
        broker.close()
        for process in processes:
            process.join(_WORKER_EXIT_S)
            if process.is_alive():
                process.kill()
                process.join()
        for s, handler in previous.items():
            signal.signal(s, handler)
    return broker
