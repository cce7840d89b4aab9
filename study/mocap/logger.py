"""Live motion capture: rigid-body poses from the ``motioncapture`` package, stamped on receipt, appended to the
session's ``mocap.tum``.

``motioncapture`` (libmotioncapture) reads Vicon DataStream (``vicon``), OptiTrack, Qualisys and VRPN, and has a
static ``mock`` backend for dry runs. Its Python binding exposes no frame timestamps, so every pose is stamped
with the configured clock when ``waitForNextFrame`` returns: ``realtime`` is the clock of RealSense global
timestamps, which makes the mocap and camera clocks the same up to latency, and the calibration measures what
remains. Frames where the body is not seen (occluded) are counted, not logged. ``mocap_stats.json`` (frames,
poses, missing, rate) is rewritten every ``stats_interval_s``.

The vicon backend retries forever when no server answers, so the server's port is probed first and an
unreachable server is an error naming the address.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from seesys.core.errors import SeesysError
from seesys.core.trajectory import TUM_HEADER, tum_line
from seesys.io.logfiles import open_log, write_json_atomically
from study.config import MocapConfig
from study.mocap.calibrate import MOCAP_LOG

MOCAP_STATS = "mocap_stats.json"
CLOCKS: dict[str, Callable[[], float]] = {"realtime": time.time, "monotonic": time.monotonic}


class MocapUnavailable(SeesysError):
    """The motion-capture system cannot be reached or does not stream the configured body."""


@dataclass
class MocapStats:
    backend: str
    body: str
    frames: int = 0
    poses: int = 0
    missing: int = 0
    rate_hz: float = 0.0
    last_pose_time: float | None = None
    status: str = "running"


def connect(cfg: MocapConfig):
    """An open ``motioncapture`` connection for ``cfg.backend``."""
    import motioncapture

    if cfg.backend == "mock":
        return motioncapture.connect(
            "mock", {"rigid_bodies": cfg.mock_rigid_bodies, "frequency": str(cfg.mock_frequency_hz)}
        )
    try:
        socket.create_connection((cfg.hostname, cfg.port), timeout=cfg.connect_timeout_s).close()
    except OSError as e:
        raise MocapUnavailable(
            f"no {cfg.backend} server at {cfg.hostname}:{cfg.port} ({e}); check hostname and port in configs/study.toml"
        ) from None
    try:
        return motioncapture.connect(cfg.backend, {"hostname": cfg.hostname})
    except RuntimeError as e:
        raise MocapUnavailable(f"cannot connect to {cfg.backend} at {cfg.hostname}: {e}") from None


def log_mocap(cfg: MocapConfig, folder: Path, stop: threading.Event, duration_s: float | None = None) -> MocapStats:
    """Append poses of ``cfg.body`` to ``folder/mocap.tum`` until ``stop`` is set (or ``duration_s`` passed)."""
    if cfg.clock not in CLOCKS:
        raise SeesysError(f"unknown mocap clock {cfg.clock!r} (one of {', '.join(CLOCKS)})")
    clock = CLOCKS[cfg.clock]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stats = MocapStats(cfg.backend, cfg.body)
    connection = connect(cfg)
    started = window_start = time.monotonic()
    window_frames = 0
    with open_log(folder / MOCAP_LOG, TUM_HEADER) as log:
        while not stop.is_set() and (duration_s is None or time.monotonic() - started < duration_s):
            connection.waitForNextFrame()
            stamp = clock()
            stats.frames += 1
            window_frames += 1
            body = connection.rigidBodies.get(cfg.body)
            if body is None:
                stats.missing += 1
            else:
                q = body.rotation
                log.write(tum_line(stamp, np.asarray(body.position, float), np.array([q.x, q.y, q.z, q.w])))
                stats.poses += 1
                stats.last_pose_time = stamp
            now = time.monotonic()
            if now - window_start >= cfg.stats_interval_s:
                stats.rate_hz = window_frames / (now - window_start)
                window_start, window_frames = now, 0
                write_json_atomically(folder / MOCAP_STATS, asdict(stats))
    stats.status = "stopped"
    write_json_atomically(folder / MOCAP_STATS, asdict(stats))
    return stats
