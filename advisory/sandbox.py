"""An isolated advisory set-up for tests, benchmarks and demos on a machine with no sound card.

- :class:`JackDummy`: a private JACK server with the ``dummy`` backend (paced in real time, no hardware), under a
  server name no running server has, so that it cannot clash with another JACK server on the machine. Processes
  find it through ``JACK_DEFAULT_SERVER`` in :meth:`JackDummy.env`.
- a copy of ``configs/`` with private ``ipc://`` endpoints and the JACK host API comes from
  :func:`seesys.io.config.write_config_dir`, for ``SEESYS_CONFIG_DIR``.
- :func:`process_env`: the environment of an advisory process in the sandbox.

PortAudio scans devices when ``sounddevice`` is imported, so the server must run before the audio process starts;
that is why the audio always runs in child processes here.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

from seesys.core.errors import SeesysError
from seesys.io.config import CONFIG_DIR_ENV
from seesys.io.processes import dying_with_parent

JACK_HOST_API = "JACK Audio Connection Kit"
_JACK_WAIT_S = 5
_JACK_STOP_S = 10
_SERVER_NAMES = tuple(f"seesys-{i}" for i in range(4))


class JackDummy:
    """A ``jackd -d dummy`` server under a name of its own, started on enter and stopped (by its pid) on exit.

    Names come from a small pool (``seesys-0`` …): JACK registers every server name in shared memory, at most 8,
    and an entry left by a server that died without cleaning up is only reclaimed by a server of the same name.
    Fresh names at every run would fill the registry ("Too many servers already active"); a pool reuses them.
    """

    def __init__(self, sample_rate: int, period: int):
        self.name = ""
        self._args = ["--no-realtime", "-d", "dummy", "-r", str(sample_rate), "-p", str(period)]
        self._proc: subprocess.Popen | None = None
        self._log: tempfile._TemporaryFileWrapper | None = None

    @staticmethod
    def available() -> bool:
        return shutil.which("jackd") is not None and shutil.which("jack_wait") is not None

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc else None

    def env(self) -> dict[str, str]:
        return {"JACK_DEFAULT_SERVER": self.name, "JACK_NO_AUDIO_RESERVATION": "1"}

    @staticmethod
    def _jack_wait(name: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            ["jack_wait", "-s", name, *args],
            capture_output=True,
            text=True,
            env={**os.environ, "JACK_NO_AUDIO_RESERVATION": "1"},
        )

    def start(self) -> None:
        if not self.available():
            raise SeesysError("jackd is not installed (apt package jackd2)")
        problems = []
        for name in _SERVER_NAMES:
            if self._jack_wait(name, "-c").stdout.strip() == "running":
                continue
            self.name = name
            # jackd reports every xrun: its output goes to a file, as a pipe nobody reads would fill up and block it.
            self._log = tempfile.NamedTemporaryFile(prefix="jackd-", suffix=".log")
            # A JACK server left behind by a killed parent would hold one of the pool's names for good: the kernel
            # stops it with its parent (SIGTERM, so it clears its registry entry).
            self._proc = subprocess.Popen(
                dying_with_parent(["jackd", "-n", name, *self._args], signal.SIGTERM),
                env={**os.environ, **self.env()},
                stdout=self._log,
                stderr=subprocess.STDOUT,
            )
            ready = self._jack_wait(name, "-w", "-t", str(_JACK_WAIT_S))
            if ready.returncode == 0 and self._proc.poll() is None:
                return
            problems.append(f"{name}: {Path(self._log.name).read_text(errors='replace')[-300:].strip()}")
            self.stop()
        raise SeesysError(
            "could not start a JACK dummy server: " + ("; ".join(problems) or f"{', '.join(_SERVER_NAMES)} all running")
        )

    def stop(self) -> None:
        if self._proc is None:
            return
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(_JACK_STOP_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc = None
        assert self._log is not None  # opened with the process
        self._log.close()

    def __enter__(self) -> JackDummy:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def process_env(config: Path, jack: JackDummy | None) -> dict[str, str]:
    """The environment of an advisory process using ``config`` and, if given, the JACK server."""
    return {**os.environ, CONFIG_DIR_ENV: str(config), **(jack.env() if jack else {})}
