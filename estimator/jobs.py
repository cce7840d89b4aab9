"""The jobs of a long command, run here one after another or as Ray tasks on a cluster.

``seesys dataset build`` (renders, then SLAM runs) and ``seesys estimator train-table`` (rows × rounds) make lists
of :class:`Job`: a module-level function and the values it needs. :class:`LocalExecutor` runs them in this process,
in order, as these commands do without ``--ray``; :class:`RayExecutor` runs each as a Ray task that reserves the
job's CPUs and GPUs. What a job does, skips and writes is the same code either way: Ray only replaces the loop.

A job function is called as ``fn(*args, env)``; :class:`JobEnv` gives it

- ``progress``: the command's rich ``Progress`` (``add_task``, ``update``, ``advance``, ``remove_task``,
  ``console.log``). In a Ray task it is a :class:`ProgressRelay`, which sends the calls (batched) to the driver,
  where they are made on the command's ``Progress``: a cluster's jobs show in the same display as local ones.
- ``config_dir``: the configs/ folder to load settings from. A task on another node must use the driver's settings,
  not those of its own install: the driver's settings (a ``ConfigSet``) travel with the tasks, and each task writes
  them to a temporary folder, its ``config_dir`` and ``$SEESYS_CONFIG_DIR`` while it runs.

Paths among a job's values are the driver's: on a cluster they must be on a filesystem every node mounts at the
same place (docs/ray.md). ``ray`` is imported by :func:`ray_executor` only, so that other commands do not pay for
it.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seesys.core.errors import ConfigError, SeesysError
from seesys.io.config import CONFIG_DIR_ENV, ConfigSet, load_section

WAIT_S = 0.2  # how often the driver takes the relayed progress calls while it waits for tasks
RELAY_INTERVAL_S = 0.25  # a task sends its progress calls at most this often (a frame bar updates 30 times a second)
CONNECT_TIMEOUT_S = 10.0  # for a HOST:PORT given to --ray to accept a connection


@dataclass(frozen=True)
class RaySettings:
    """``configs/ray.toml``: what a task reserves."""

    slam_cpus: int
    train_cpus: int


def load_ray_settings(directory: Path | None = None) -> RaySettings:
    settings = load_section("ray", RaySettings, directory)
    for name in ("slam_cpus", "train_cpus"):
        if getattr(settings, name) < 1:
            raise ConfigError(f"configs/ray.toml: {name} must be at least 1")
    return settings


@dataclass(frozen=True)
class Job:
    """One unit of work: ``fn(*args, env)``, a module-level function (a Ray task imports it by name).

    ``cpus`` and ``gpus`` are what its Ray task reserves; ``after`` names jobs of the same list that must have
    finished before it starts (they come earlier in the list)."""

    name: str
    fn: Callable[..., Any]
    args: tuple
    cpus: float = 1
    gpus: float = 0
    after: tuple[str, ...] = ()


@dataclass(frozen=True)
class JobEnv:
    progress: Any  # a rich Progress, or a ProgressRelay in a Ray task
    config_dir: Path | None  # None: the process's configs/ ($SEESYS_CONFIG_DIR or the SEESys home's)


OnDone = Callable[[Job, Any], None]


class LocalExecutor:
    """The jobs in this process, in order (what the commands do without ``--ray``)."""

    def run(self, jobs: list[Job], progress, on_done: OnDone | None = None, config_dir: Path | None = None) -> list:
        env = JobEnv(progress, config_dir)
        results = []
        for job in jobs:
            result = job.fn(*job.args, env)
            if on_done is not None:
                on_done(job, result)
            results.append(result)
        return results


# --- Ray -------------------------------------------------------------------------------------------------------


class ProgressRelay:
    """A rich ``Progress`` stand-in for a Ray task: its calls go to the driver's ``Progress`` through a sink actor,
    a batch at most every :data:`RELAY_INTERVAL_S` (adding or removing a bar and a log line are sent at once)."""

    def __init__(self, sink, job: str):
        self._sink = sink
        self._job = job
        self._calls: list[tuple] = []
        self._next_id = 0
        self._sent = 0.0
        self._last_put = None  # the ObjectRef of the last batch sent
        self.console = _ConsoleRelay(self)

    def add_task(self, description: str, **kwargs) -> int:
        self._next_id += 1
        self._call("add_task", self._next_id, (description,), kwargs, at_once=True)
        return self._next_id

    def update(self, task: int, **kwargs) -> None:
        self._call("update", task, (), kwargs)

    def advance(self, task: int, advance: float = 1) -> None:
        self._call("advance", task, (advance,), {})

    def remove_task(self, task: int) -> None:
        self._call("remove_task", task, (), {}, at_once=True)

    def log(self, *objects) -> None:
        self._call("log", 0, tuple(str(o) for o in objects), {}, at_once=True)

    def _call(self, method: str, task: int, args: tuple, kwargs: dict, at_once: bool = False) -> None:
        self._calls.append((method, task, args, kwargs))
        if at_once or time.monotonic() - self._sent >= RELAY_INTERVAL_S:
            self.flush()

    def flush(self, wait: bool = False) -> None:
        """Send the calls not sent yet; ``wait``: until the sink has every call sent so far (a task's last flush,
        so that its bars are up to date when the driver hears that it ended). The sink runs one caller's calls in
        order, so waiting for the last one sent is waiting for all: a batch sent at once (a removed bar) and not
        waited for could otherwise reach the sink after the driver's last look."""
        if self._calls:
            self._last_put = self._sink.put.remote(self._job, self._calls)
            self._calls = []
            self._sent = time.monotonic()
        if wait and self._last_put is not None:
            import ray

            ray.get(self._last_put)


class _ConsoleRelay:
    def __init__(self, relay: ProgressRelay):
        self._relay = relay

    def log(self, *objects) -> None:
        self._relay.log(*objects)


class ProgressSink:
    """The Ray actor that holds the relayed progress calls until the driver takes them."""

    def __init__(self):
        self._batches: list[tuple[str, list[tuple]]] = []

    def put(self, job: str, calls: list[tuple]) -> None:
        self._batches.append((job, calls))

    def take(self) -> list[tuple[str, list[tuple]]]:
        batches, self._batches = self._batches, []
        return batches


class _ProgressMirror:
    """Makes the relayed calls on the driver's ``Progress``, each task's bar ids mapped to the driver's."""

    def __init__(self, progress):
        self._progress = progress
        self._ids: dict[tuple[str, int], Any] = {}

    def apply(self, batches: list[tuple[str, list[tuple]]]) -> None:
        for job, calls in batches:
            for method, task, args, kwargs in calls:
                if method == "log":
                    self._progress.console.log(*args)
                elif method == "add_task":
                    self._ids[(job, task)] = self._progress.add_task(*args, **kwargs)
                elif (job, task) in self._ids:
                    real = self._ids[(job, task)]
                    if method == "remove_task":
                        del self._ids[(job, task)]
                    getattr(self._progress, method)(real, *args, **kwargs)


def config_snapshot(directory: Path | None = None) -> ConfigSet:
    """The settings of ``directory`` (default: this process's configs/), for tasks on other nodes."""
    configs = ConfigSet.read(directory)
    if not configs.sections:
        raise SeesysError(f"no configuration files (*.toml) in {configs.folder}")
    return configs


@contextlib.contextmanager
def materialised(snapshot: ConfigSet) -> Iterator[Path]:
    """The settings written to a temporary folder, which is ``$SEESYS_CONFIG_DIR`` until the block ends."""
    before = os.environ.get(CONFIG_DIR_ENV)
    with tempfile.TemporaryDirectory(prefix="seesys-configs-") as folder:
        snapshot.write(Path(folder))
        os.environ[CONFIG_DIR_ENV] = folder
        try:
            yield Path(folder)
        finally:
            if before is None:
                os.environ.pop(CONFIG_DIR_ENV, None)
            else:
                os.environ[CONFIG_DIR_ENV] = before


def _run_task(fn: Callable[..., Any], args: tuple, snapshot: ConfigSet, relay: ProgressRelay, *after) -> Any:
    """A job in a Ray task (``after``: the results of the jobs it waited for, unused)."""
    with materialised(snapshot) as folder:
        try:
            return fn(*args, JobEnv(relay, folder))
        finally:
            relay.flush(wait=True)


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class RayExecutor:
    """Each job as a Ray task (``num_cpus``, ``num_gpus`` as the job says), results in job order."""

    def __init__(self, ray_module):
        self._ray = ray_module

    def check_resources(self, jobs: list[Job]) -> None:
        """A job no node of the cluster can take would wait for ever: say so instead, in one line."""
        nodes = [n.get("Resources", {}) for n in self._ray.nodes() if n.get("Alive")]
        for job in jobs:
            if not any(n.get("CPU", 0) >= job.cpus and n.get("GPU", 0) >= job.gpus for n in nodes):
                have = ", ".join(f"{n.get('CPU', 0):g} CPU + {n.get('GPU', 0):g} GPU" for n in nodes) or "no node"
                raise SeesysError(
                    f"{job.name} needs {job.cpus:g} CPU + {job.gpus:g} GPU on one node; the Ray "
                    f"cluster's nodes have {have}"
                )

    def run(self, jobs: list[Job], progress, on_done: OnDone | None = None, config_dir: Path | None = None) -> list:
        if not jobs:
            return []
        ray = self._ray
        self.check_resources(jobs)
        snapshot = ray.put(config_snapshot(config_dir))
        sink = ray.remote(ProgressSink).options(num_cpus=0).remote()
        task = ray.remote(_run_task)
        refs: dict[str, Any] = {}
        job_of: dict[Any, Job] = {}
        for job in jobs:
            after = [refs[name] for name in job.after if name in refs]
            ref = task.options(num_cpus=job.cpus, num_gpus=job.gpus, name=job.name).remote(
                job.fn, job.args, snapshot, ProgressRelay(sink, job.name), *after
            )
            refs[job.name] = ref
            job_of[ref] = job
        mirror = _ProgressMirror(progress)
        results: dict[str, Any] = {}
        pending = list(job_of)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=WAIT_S)
                mirror.apply(ray.get(sink.take.remote()))
                for ref in ready:
                    job = job_of[ref]
                    results[job.name] = self._result(ref, job)
                    if on_done is not None:
                        on_done(job, results[job.name])
        except BaseException:
            for ref in pending:
                ray.cancel(ref)
            raise
        finally:
            ray.kill(sink)
        return [results[job.name] for job in jobs]

    def _result(self, ref, job: Job) -> Any:
        ray = self._ray
        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as e:
            cause = getattr(e, "cause", None)
            if isinstance(cause, SeesysError):
                raise cause.with_traceback(None) from None
            raise
        except ray.exceptions.RayError as e:  # a worker or node died (after Ray's retries), an object was lost
            raise SeesysError(f"{job.name}: {type(e).__name__} on the Ray cluster: {_first_line(e)}") from None


def _check_reachable(address: str) -> None:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise SeesysError(
            f"--ray {address}: expected auto or HOST:PORT (the head node's address, port 6379 unless "
            f"`ray start --head --port` said otherwise)"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise SeesysError(
            f"cannot reach the Ray cluster at {address}: {e.strerror or _first_line(e)} (is `ray start "
            f"--head` running there?)"
        ) from None


def add_ray_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--ray [ADDRESS]`` of a command; the namespace gets ``ray``: None without it, "" for Ray's default."""
    parser.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDRESS",
        help=f"run {what} as a Ray task: on the cluster at ADDRESS (auto, or the head's HOST:PORT), "
        f"or, with no ADDRESS, on $RAY_ADDRESS, this machine's `ray start` instance or a new "
        f"local one (docs/ray.md)",
    )


@contextlib.contextmanager
def ray_executor(address: str | None) -> Iterator[RayExecutor]:
    """A :class:`RayExecutor` on the cluster at ``address`` (``auto``, ``HOST:PORT``), or with ``None`` on Ray's
    default: ``$RAY_ADDRESS``, a ``ray start`` instance of this machine, else a new local instance that ends with the
    block. A Ray already initialised in this process (a test's) is used as it is, and left running."""
    try:
        import ray
    except ImportError:
        raise SeesysError(
            "--ray needs the ray package (it is among the project's dependencies: reinstall the project)"
        ) from None
    if ray.is_initialized():
        yield RayExecutor(ray)
        return
    if address not in (None, "auto"):
        _check_reachable(address)
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except Exception as e:  # ConnectionError, RuntimeError, ValueError, AuthenticationError ... by Ray version
        where = f"the Ray cluster at {address}" if address else "Ray"
        raise SeesysError(f"cannot connect to {where}: {_first_line(e)}") from None
    try:
        yield RayExecutor(ray)
    finally:
        ray.shutdown()
