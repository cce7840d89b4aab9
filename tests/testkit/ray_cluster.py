"""A local Ray instance for the ``--ray`` tests: 2 CPUs, no GPU, no dashboard, task output kept out of the test's,
its files in a short folder of the test session's temporary folder, and nothing left running after it.

Ray's Unix socket paths (``<temp>/session_<date>_<pid>/sockets/plasma_store``) must fit in 107 bytes, so the
instance's folder is ``<pytest base temp>/r<n>`` rather than a test's own ``tmp_path`` (too long for Ray); when even
that is too long, a short folder under the system's temporary folder, removed afterwards. The cluster's token
comes from the environment (``RAY_AUTH_TOKEN``), so that Ray writes none into ``~/.ray``.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import tempfile
from pathlib import Path

import psutil
import pytest

from testkit.polling import wait_for

SOCKET_PATH_MAX = 107
SESSION_AND_SOCKET = 64  # "/session_2026-11-25_08-27-14_639978_92400/sockets/plasma_store" and a margin
RAY_ENV = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_ADDRESS")
# One token for the test process: Ray's driver keeps the first token it read, and a later instance must accept it.
TOKEN = secrets.token_hex(16)


def _short_folder(tmp_path_factory) -> tuple[Path, bool]:
    """A folder for Ray's files and whether it is outside pytest's (to be removed here)."""
    base = tmp_path_factory.getbasetemp()
    if len(str(base)) + 3 + SESSION_AND_SOCKET <= SOCKET_PATH_MAX:
        return tmp_path_factory.mktemp("r"), False
    return Path(tempfile.mkdtemp(prefix="ray", dir="/tmp")), True


def _is_ray(process: psutil.Process, ray_dir: str) -> bool:
    """Ray's servers (``gcs_server``, ``raylet``, its Python services under the ray package) and workers
    (``ray::...``); not, say, multiprocessing's resource tracker, which a local build in the test starts."""
    command = " ".join(process.cmdline())
    return process.name() in ("gcs_server", "raylet") or command.startswith("ray::") or ray_dir in command


def _ray_processes(before: set[int], ray_dir: str) -> list[psutil.Process]:
    """This process's descendants started by Ray since ``before`` that are still running."""
    alive = []
    for child in psutil.Process().children(recursive=True):
        try:
            if child.pid not in before and child.status() != psutil.STATUS_ZOMBIE and _is_ray(child, ray_dir):
                alive.append(child)
        except psutil.NoSuchProcess:
            continue
    return alive


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    """``ray`` initialised on a local 2-CPU instance for the module's tests; shut down and checked gone after."""
    import ray

    folder, own_folder = _short_folder(tmp_path_factory)
    saved = {name: os.environ.get(name) for name in RAY_ENV}
    for name in ("RAY_ADDRESS", "RAY_AUTH_MODE"):
        os.environ.pop(name, None)
    # With no RAY_AUTH_MODE a new local instance turns token authentication on (for this process and its children,
    # through the environment) and uses this token rather than writing one into ~/.ray.
    os.environ["RAY_AUTH_TOKEN"] = TOKEN
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    try:
        ray.init(
            num_cpus=2,
            num_gpus=0,
            include_dashboard=False,
            log_to_driver=False,
            _temp_dir=str(folder),
            _node_ip_address="127.0.0.1",
            object_store_memory=200 * 1024 * 1024,
            logging_level=logging.WARNING,
        )
        yield ray
    finally:
        ray.shutdown()
        ray_dir = str(Path(ray.__file__).parent)
        wait_for(
            lambda: not _ray_processes(before, ray_dir),
            120,
            lambda: f"Ray's processes to end: {[p.cmdline()[:3] for p in _ray_processes(before, ray_dir)]}",
        )
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        if own_folder:
            shutil.rmtree(folder, ignore_errors=True)
