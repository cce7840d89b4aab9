"""`seesys study run` stops when told: real ORB-SLAM3 on the sample spread out in time (a paced recording that would
run for half a minute), the seesys condition on a machine without the configured sound card (the runner starts a
JACK dummy server, as `seesys run` does), estimates replayed, no mocap.

- `q` at frame 20: the task ends there (run.json `stopped` with its `task_end`, an event `task_end`), the device is
  interrupted and closes its files (session.json `interrupted`, monitor_stats.json), it logs only a few frames
  after the end, which stay in the session and out of the metrics.
- Ctrl-C (SIGINT to the runner) at frame 20: run.json `interrupted`, the device's files final the same way, exit 130.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from testkit.polling import wait_for
from testkit.sample import REPO, stretched_sample

from advisory.sandbox import JackDummy
from estimator.service.sandbox import private_configs
from seesys.io.config import CONFIG_DIR_ENV
from study.config import load_study_config
from study.protocol import make_protocol, write_protocol
from study.sessions import participant_metrics, read_events, read_run

pytestmark = [pytest.mark.slam, pytest.mark.audio]
STRETCH = 6  # the sample's 150 frames at 5 fps: 30 s paced
STOP_AT = 20


@pytest.fixture(scope="module")
def study():
    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2)")
    root = Path(tempfile.mkdtemp(prefix="sstop", dir="/tmp"))  # ipc paths are at most 107 bytes
    configs, _ = private_configs(root, endpoint=f"ipc://{root}/handoff", output_device="no-such-sound-card")
    source = stretched_sample(root / "source", STRETCH)
    times = [float(line.split()[0]) for line in (source / "rgb.txt").read_text().splitlines() if line[:1] != "#"]
    pd.DataFrame({"frame_index": range(len(times)), "timestamp": times, "error_m": 0.006}).to_csv(
        root / "estimates.csv", index=False
    )
    protocol = make_protocol(load_study_config(configs).protocol, participants_per_condition=2)
    write_protocol(root / "study", protocol)
    people = [p.id for p in protocol.participants if p.conditions == ["seesys"]]
    yield root, {**os.environ, CONFIG_DIR_ENV: str(configs)}, source, people
    shutil.rmtree(root, ignore_errors=True)


def frames_logged(attempt: Path) -> int:
    try:
        return len((attempt / "frames.csv").read_text().splitlines()) - 1
    except OSError:
        return 0


def run_until_frame(root: Path, env: dict, source: Path, participant: str) -> tuple[subprocess.Popen, Path]:
    attempt = root / "study" / "participants" / participant / "task" / "attempt-1"
    runner = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "seesys",
            "study",
            "run",
            str(root / "study"),
            "--participant",
            participant,
            "--phase",
            "task",
            "--source",
            f"tum:{source}",
            "--pace",
            "--no-mocap",
            "--replay-estimates",
            str(root / "estimates.csv"),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=env,
    )
    runner.stdin.write("i\n")
    runner.stdin.flush()
    wait_for(
        lambda: frames_logged(attempt) >= STOP_AT or runner.poll() is not None,
        300,
        f"{STOP_AT} frames tracked",
        interval_s=0.05,
    )
    assert runner.poll() is None, runner.communicate()[1][-3000:]
    return runner, attempt


def check_the_device_stopped(attempt: Path, told_at: float) -> dict:
    """The device was interrupted, closed its files and stopped long before the recording's end."""
    manifest = json.loads((attempt / "session.json").read_text())
    ended = datetime.fromisoformat(manifest["end_time"]).timestamp()  # to the second
    # For the record (-s); a loaded machine may take longer, so the bound below is on frames, not seconds.
    print(
        f"{attempt}: the device ended {ended - told_at:+.1f} s (end_time to the second) after it was told, with "
        f"{frames_logged(attempt)} frames"
    )
    assert manifest["status"] == "interrupted", manifest
    stats = json.loads((attempt / "monitor_stats.json").read_text())
    assert stats["frames_seen"] == frames_logged(attempt)
    frames = pd.read_csv(attempt / "frames.csv")
    # At 5 fps, a device stopped within 2 s logs about 10 more frames; one left running logs all 150.
    assert STOP_AT <= len(frames) < STOP_AT + 60, len(frames)
    events = read_events(attempt)
    assert events.kind.iloc[-1] == "stop"
    run = read_run(attempt)
    assert run["exit_codes"]["device"] is not None and "pid" in run
    assert run["audio"].startswith("JACK dummy server")  # no sound card: the runner's own dummy server
    assert len(pd.read_csv(attempt / "playback.csv")) > 0  # and the player played into it
    return run


@pytest.mark.system
def test_q_ends_the_task_and_stops_the_device(study):
    root, env, source, people = study
    runner, attempt = run_until_frame(root, env, source, people[0])
    runner.stdin.write("q\n")
    runner.stdin.flush()
    out, err = runner.communicate(timeout=300)
    assert runner.returncode == 0, err[-3000:]
    assert "stopped" in out
    run = check_the_device_stopped(attempt, float(read_events(attempt).query("kind == 'end'").time.iloc[0]))
    assert run["status"] == "stopped"
    end = run["task_end"]
    frames = pd.read_csv(attempt / "frames.csv")
    assert STOP_AT - 1 <= end["frame_index"] < len(frames)
    assert end["timestamp"] == pytest.approx(frames.timestamp[frames.frame_index == end["frame_index"]].item())
    events = read_events(attempt)
    assert {"end", "task_end"} <= set(events.kind)
    assert float(events.time[events.kind == "task_end"].iloc[0]) == pytest.approx(end["time"])
    # The frames after the end are in the session, and out of the metrics.
    metrics = participant_metrics([attempt], load_study_config().metrics)
    if metrics is not None:  # pairs need 10 frames tracked after initialisation
        _, (measured,) = metrics
        assert np.all(measured.rpe.timestamps <= end["timestamp"])


@pytest.mark.system
def test_ctrl_c_interrupts_the_session_with_its_files_final(study):
    root, env, source, people = study
    runner, attempt = run_until_frame(root, env, source, people[1])
    runner.send_signal(signal.SIGINT)
    _, err = runner.communicate(timeout=300)
    assert runner.returncode == 130, err[-3000:]
    run = check_the_device_stopped(attempt, float(read_events(attempt).query("kind == 'interrupted'").time.iloc[0]))
    assert run["status"] == "interrupted" and "task_end" not in run
    assert "interrupted" in set(read_events(attempt).kind)
