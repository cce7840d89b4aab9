"""`seesys run`'s bad input: each a one-line error naming the problem, before anything starts."""

from __future__ import annotations

import json
import os

import pandas as pd
import pytest
from testkit.sample import SAMPLE, run_seesys

from seesys.core.errors import ConfigError, SeesysError
from seesys.io.config import CONFIG_DIR_ENV, write_config_dir
from seesys_app.config import load_app_config
from seesys_app.run import estimates_endpoint


def test_estimator_address_is_host_and_port():
    assert estimates_endpoint("192.168.1.20:5556") == "tcp://192.168.1.20:5556"
    for bad in ("192.168.1.20", ":5556", "host:port", "host:70000"):
        with pytest.raises(SeesysError, match="--estimator wants HOST:PORT"):
            estimates_endpoint(bad)


@pytest.mark.system
def test_a_session_folder_in_use_is_refused(tmp_path):
    (tmp_path / "earlier.csv").write_text("x\n")
    done = run_seesys("run", "--source", f"tum:{SAMPLE}", "--local", "--condition", "none", "--out", str(tmp_path))
    assert done.returncode == 2
    assert done.stderr.strip() == (
        f"seesys: error: {tmp_path} exists and is not an empty folder: give a new folder for the session"
    )


@pytest.mark.system
def test_a_bad_estimator_address_leaves_no_session_folder(tmp_path):
    done = run_seesys(
        "run",
        "--source",
        f"tum:{SAMPLE}",
        "--estimator",
        "edge-server",
        "--condition",
        "none",
        "--out",
        str(tmp_path / "s"),
    )
    assert done.returncode == 2 and "--estimator wants HOST:PORT" in done.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.system
def test_local_and_remote_estimator_exclude_each_other(tmp_path):
    done = run_seesys(
        "run",
        "--source",
        f"tum:{SAMPLE}",
        "--local",
        "--estimator",
        "h:1",
        "--condition",
        "none",
        "--out",
        str(tmp_path / "s"),
    )
    assert done.returncode == 2 and "not allowed with argument" in done.stderr


def test_app_config_is_checked(tmp_path):
    configs = write_config_dir(tmp_path / "configs", {"app.mode": "stereo", "max_restarts": -1, "app.workers": -1})
    with pytest.raises(
        ConfigError,
        match="device.mode must be one of rgbd, mono .*max_restarts must not be negative; "
        r"local_estimator.workers must not be negative \(got -1\)",
    ):
        load_app_config(configs)


@pytest.mark.system
def test_an_unreachable_estimator_fails_the_run_at_start(tmp_path):
    configs = write_config_dir(tmp_path / "configs", {"reach_timeout_s": 2.0})
    out = tmp_path / "s"
    done = run_seesys(
        "run",
        "--source",
        f"tum:{SAMPLE}",
        "--estimator",
        "127.0.0.1:1",
        "--condition",
        "none",
        "--out",
        str(out),
        env={**os.environ, CONFIG_DIR_ENV: str(configs)},
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stderr.strip().splitlines() == [
        f"seesys: error: the estimator at 127.0.0.1:1 cannot be reached: no ZeroMQ peer answered at "
        f"tcp://127.0.0.1:1 within 2 s (is `seesys estimator serve` running there, its estimates_endpoint bound on "
        f"an address this device reaches, and Curve set alike on both?) (session {out})"
    ]
    events = pd.read_csv(out / "app_events.csv")
    assert "device" not in set(events.part)  # nothing was tracked
    started, failed = (events[events.event == e].wall_time.iloc[0] for e in ("started", "failed"))
    assert failed - started >= 2.0  # it waited the configured time, and gave up
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "cannot be reached" in summary["error"]
