"""Fixtures and helpers of the advisory tests: a private JACK dummy server, sandboxed configs and processes, test
publishers of real Estimate / FeatureFrame messages, and pulse detection in captured audio."""

from __future__ import annotations

import math
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import zmq

from advisory.config import AdvisoryConfig, load_advisory_config
from advisory.process import advisory_command
from advisory.sandbox import JACK_HOST_API, JackDummy, process_env
from advisory.synth import pulse_onsets as buffer_onsets
from advisory.wav import read_wav
from seesys.core import rts_schema
from seesys.core.messages import Estimate, FeatureFrame, encode
from seesys.core.session_layout import ADVISORY_CSV, EVENTS_CSV, PLAYBACK_CSV
from seesys.core.tracking_state import TrackingState
from seesys.io.config import write_config_dir
from seesys.io.transport import open_socket
from testkit.polling import wait_for

PUBLISH_HZ = 30.0


@pytest.fixture(scope="module")
def jack():
    """A JACK dummy server of its own for the module's tests (real-time paced, no sound card)."""
    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2; `make setup` installs it)")
    cfg = load_advisory_config()
    with JackDummy(cfg.audio.sample_rate, cfg.audio.blocksize) as server:
        yield server


class Sandbox:
    """A short private folder (ipc paths are limited to ~100 characters) with configs whose endpoints are ipc
    sockets inside it, so tests never collide with each other or with a running system."""

    def __init__(self, jack: JackDummy | None, **overrides: object):
        self.root = Path(tempfile.mkdtemp(prefix="sadv", dir="/tmp"))
        self.session = self.root / "session"
        self.estimates_endpoint = f"ipc://{self.root}/estimates"
        self.features_endpoint = f"ipc://{self.root}/features"
        settings = {
            "host_api": JACK_HOST_API if jack else "",
            "endpoint": f"ipc://{self.root}/handoff",
            "estimates_endpoint": self.estimates_endpoint,
            "features_endpoint": self.features_endpoint,
            **overrides,
        }
        self.config_dir = write_config_dir(self.root / "configs", settings)
        self.cfg: AdvisoryConfig = load_advisory_config(self.config_dir)
        self.env = process_env(self.config_dir, jack)
        self._processes: list[subprocess.Popen] = []

    def start(self, *args: str, name: str) -> subprocess.Popen:
        """Start ``seesys advisory ARGS``; its stderr goes to ``<name>.err`` in the sandbox."""
        with open(self.root / f"{name}.err", "a") as err:
            proc = subprocess.Popen(advisory_command(*args), env=self.env, stderr=err, stdout=subprocess.DEVNULL)
        self._processes.append(proc)
        return proc

    def player(self, capture: str = "capture.wav", name: str = "player") -> subprocess.Popen:
        return self.start("player", "--out", str(self.session), "--capture", str(self.root / capture), name=name)

    def generator(self, condition: str = "seesys") -> subprocess.Popen:
        return self.start("generator", "--condition", condition, "--out", str(self.session), name="generator")

    def stderr(self, name: str) -> str:
        return (self.root / f"{name}.err").read_text()

    def table(self, name: str) -> pd.DataFrame:
        return pd.read_csv(self.session / name)

    def advisory(self) -> pd.DataFrame:
        return self.table(ADVISORY_CSV)

    def playback(self) -> pd.DataFrame:
        return self.table(PLAYBACK_CSV)

    def events(self) -> pd.DataFrame:
        return self.table(EVENTS_CSV)

    def capture(self, name: str = "capture.wav") -> tuple[np.ndarray, int]:
        return read_wav(self.root / name)

    def print_diagnostics(self) -> None:
        """The events log and every process's stderr, for a failing test's report."""
        for path in [self.session / EVENTS_CSV, *sorted(self.root.glob("*.err"))]:
            if path.exists():
                print(f"--- {path.name}\n{path.read_text()[-4000:]}")

    def stop_all(self) -> None:
        """SIGTERM every process still running (they close their logs), then wait; kill any that hangs."""
        for proc in self._processes:
            if proc.poll() is None:
                proc.terminate()
        for proc in self._processes:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def wait_until(predicate: Callable[[], bool], what: str | Callable[[], str], timeout_s: float = 60.0) -> None:
    """Poll ``predicate`` until true; a generous timeout, as the machine may be shared and loaded. ``what`` (or
    what it returns, read at the timeout) says what did not happen."""
    wait_for(predicate, timeout_s, what, interval_s=0.1)


def wait_started(sandbox: Sandbox, process: str, count: int = 1, timeout_s: float = 60.0) -> None:
    """Wait until ``count`` processes named ``process`` have logged 'started' (imports take a while)."""

    def started() -> bool:
        path = sandbox.session / EVENTS_CSV
        if not path.exists():
            return False
        events = pd.read_csv(path)
        return int(((events.event == "started") & events.process.str.startswith(process + "[")).sum()) >= count

    wait_until(started, lambda: f"{process} to start; stderr: {sandbox.stderr(process)[-2000:]}", timeout_s)


class Publisher:
    """Publishes messages at 30 Hz on a real PUB socket from a thread; ``value`` may change at any time
    (None pauses the stream)."""

    def __init__(self, endpoint: str, make_message):
        self.value: float | None = None
        self._make = make_message
        self._ctx = zmq.Context()
        self._pub = open_socket(self._ctx, zmq.PUB, endpoint, "test publisher", bind=True)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self.index = 0

    def __enter__(self) -> Publisher:
        self._thread.start()
        return self

    def _loop(self) -> None:
        start = time.monotonic()
        while not self._stop.is_set():
            value = self.value
            if value is not None:
                self._pub.send_multipart(encode(self._make(self.index, self.index / PUBLISH_HZ, value)))
            self.index += 1
            self._stop.wait(max(start + self.index / PUBLISH_HZ - time.monotonic(), 0.0))

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._pub.close()
        self._ctx.term()


def estimate_message(index: int, timestamp: float, error_m: float) -> Estimate:
    return Estimate("test-device", index, timestamp, error_m, "test")


def rotation_frame(index: int, timestamp: float, speed_deg_s: float) -> FeatureFrame:
    """A tracked frame whose roll, pitch and yaw rotations (equal) make ``speed_deg_s`` at 30 frames/s."""
    rts = np.zeros(rts_schema.NUM_CHANNELS, dtype=np.float32)
    per_axis = math.radians(speed_deg_s) / PUBLISH_HZ
    for name in rts_schema.ROTATION_CHANNELS:
        rts[rts_schema.index_of(name)] = per_axis
    return FeatureFrame("test-device", index, timestamp, TrackingState.OK, rts)


def pulse_onsets(x: np.ndarray, sample_rate: int, threshold: float = 0.1, merge_s: float = 0.005) -> np.ndarray:
    """Sample indices where pulses start: samples above ``threshold`` closer than ``merge_s`` are one pulse."""
    loud = np.flatnonzero(np.abs(x) > threshold)
    if loud.size == 0:
        return loud
    starts = np.concatenate([[0], np.flatnonzero(np.diff(loud) > merge_s * sample_rate) + 1])
    return loud[starts]


def pulses_per_buffer(x: np.ndarray, rate: int, starts, pulses, eq, cues=None) -> list[int]:
    """Check audio buffer by buffer and return the pulse counts of the buffers that played whole.

    Buffer k starts at sample ``starts[k]`` and owns the audio up to the next start; ``pulses[k]`` is the number of
    pulses it holds. Its stretch must hold exactly those pulses, one every p + i from its first sample, to the
    sample; only the first ones when the next buffer replaced it early. Nothing may sound before the first buffer.
    Buffers flagged in ``cues`` hold the "no information" cue instead of pulses (:func:`cue_tones` finds it) and
    are not checked here.
    """
    starts = np.asarray(starts, dtype=int)
    ends = np.append(starts[1:], x.size)
    cues = np.zeros(len(starts), dtype=bool) if cues is None else np.asarray(cues, dtype=bool)
    assert len(pulse_onsets(x[: starts[0]], rate)) == 0
    pulse_length = round(eq.pulse_s * rate)
    whole = []
    for n, start, end, cue in zip(pulses, starts, ends, cues):
        if cue:
            continue
        expected = buffer_onsets(int(n), eq, rate)
        got = pulse_onsets(x[start:end], rate).tolist()
        assert got == [o for o in expected if o < end - start], (n, start, end, got)
        if not expected or expected[-1] + pulse_length <= end - start:
            whole.append(int(n))
    return whole


def run_lengths(values: list[int]) -> list[int]:
    """``[1, 1, 2, 2, 2, 1]`` → ``[1, 2, 1]``."""
    return [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]


@pytest.fixture
def make_sandbox():
    """``make_sandbox(jack_or_None, **config_overrides)``; every process is stopped and the folder removed after."""
    made: list[Sandbox] = []

    def make(jack: JackDummy | None, **overrides: object) -> Sandbox:
        sandbox = Sandbox(jack, **overrides)
        made.append(sandbox)
        return sandbox

    yield make
    for sandbox in made:
        sandbox.stop_all()
        sandbox.print_diagnostics()  # captured: pytest shows it only when the test failed
        shutil.rmtree(sandbox.root, ignore_errors=True)


def sound_stretches(samples: np.ndarray, rate: int, threshold: float, smooth_s: float = 0.005) -> list[tuple[int, int]]:
    """(start, length) in samples of each stretch where the signal's envelope (the largest |x| within ``smooth_s``)
    exceeds ``threshold``: a 1 ms pulse is a stretch of about ``smooth_s``, a cue tone one of its own length."""
    width = max(1, int(round(smooth_s * rate)))
    loud = np.abs(np.asarray(samples, dtype=np.float32)) > threshold
    envelope = np.convolve(loud.astype(np.int32), np.ones(width, dtype=np.int32), mode="same") > 0
    edges = np.diff(np.concatenate(([0], envelope.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return list(zip(starts.tolist(), (ends - starts).tolist()))


def cue_tones(samples: np.ndarray, rate: int, cue) -> list[int]:
    """Start samples of the "no information" cue's tones heard in ``samples`` (stretches at least half a cue tone
    long: a pulse is far shorter)."""
    return [
        start
        for start, length in sound_stretches(samples, rate, cue.cue_level / 10)
        if length >= cue.cue_tone_s * rate / 2
    ]
