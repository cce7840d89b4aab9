"""`seesys run --estimator HOST:PORT`: the app with an estimator service it did not start (here a real
`seesys estimator serve` with the shipped model on a free loopback TCP port), in the rotation condition, with
stdout not a terminal (the plain line-per-second view)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pytest

from advisory.sandbox import JackDummy
from estimator.service.broker import default_model
from estimator.service.config import load_service_config
from estimator.service.sandbox import private_configs, start_service, wait_ready

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / "data" / "sample"
FRAMES = 60
START_TIMEOUT_S = 240

pytestmark = [pytest.mark.slam, pytest.mark.audio]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.system
def test_a_remote_estimator_feeds_the_app_in_the_rotation_condition():
    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2)")
    root = Path(tempfile.mkdtemp(prefix="sapr", dir="/tmp"))  # ipc paths must stay short
    port = free_port()
    config_dir, endpoints = private_configs(
        root, endpoint=f"ipc://{root}/handoff", estimates_endpoint=f"tcp://127.0.0.1:{port}", stale_after_ms=60000.0
    )
    log = root / "serve.log"
    service = start_service(config_dir, default_model(load_service_config(config_dir), None), log=log)
    try:
        wait_ready(service, endpoints["status"], START_TIMEOUT_S, log)
        out = root / "session"
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "seesys",
                "run",
                "--source",
                f"tum:{SAMPLE}",
                "--estimator",
                f"127.0.0.1:{port}",
                "--condition",
                "rotation",
                "--wav",
                "--max-frames",
                str(FRAMES),
                "--out",
                str(out),
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
            env={**os.environ, "SEESYS_CONFIG_DIR": str(config_dir)},
            timeout=600,
        )
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"] == "completed" and summary["frames"] == FRAMES
        assert summary["estimator"] == f"127.0.0.1:{port}" and "estimator" not in summary["parts"]
        assert summary["estimates"] > 0
        # Plain mode: one line a second with the view's fields, and the app's events as they happen.
        lines = [line for line in done.stdout.splitlines() if "| estimate" in line]
        assert lines and f"estimator remote 127.0.0.1:{port}" in lines[-1] and "drops skipped" in lines[-1]
        assert "device: started" in done.stdout
        buffers = pd.read_csv(out / "advisory.csv")
        assert (buffers.condition == "rotation").all() and (buffers.status == "live").any()
        assert (out / "advisory.wav").stat().st_size > 0
    finally:
        service.terminate()
        service.wait(30)
        shutil.rmtree(root, ignore_errors=True)
