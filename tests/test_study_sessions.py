"""Study sessions without ORB-SLAM3: the within-subjects condition order, a done phase is not re-recorded
without --restart, the runner's status line reads the logs as they are being written, and the attempt states."""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rich.console import Console
from testkit.ports import refused_port
from testkit.sample import SAMPLE

from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from seesys.io.children import RowCounter
from seesys.io.network import load_network_config
from seesys.io.trajectory_files import write_tum
from study.config import load_study_config
from study.metrics import read_frame_log
from study.mocap.logger import MOCAP_STATS
from study.operator import OperatorInput
from study.protocol import make_protocol, write_protocol
from study.runner import RunOptions, Session, choose_condition
from study.sessions import (
    INCOMPLETE,
    attempt_folders,
    next_attempt_folder,
    participant_metrics,
    phase_status,
    read_events,
    read_run,
)
from study.watch import StreamWatcher


@pytest.fixture
def within(tmp_path):
    protocol = make_protocol(load_study_config().protocol, participants_per_condition=1, design="within")
    write_protocol(tmp_path / "s", protocol)
    return tmp_path / "s", protocol


def complete(attempt, **extra):
    (attempt / "run.json").write_text(json.dumps({"status": "completed", **extra}))


def test_within_subjects_runs_the_next_condition_of_the_order(within):
    study, protocol = within
    person = protocol.participants[0]
    first, second = person.conditions[:2]
    assert choose_condition(protocol, study, person.id, "task", None) == first
    complete(next_attempt_folder(protocol.phase_folder(study, person.id, "task", first)))
    assert choose_condition(protocol, study, person.id, "task", None) == second
    with pytest.raises(SeesysError, match="not assigned"):
        choose_condition(make_protocol(load_study_config().protocol, 1), study, "P01", "task", "bogus")


def test_a_done_phase_needs_restart(within):
    study, protocol = within
    person = protocol.participants[0]
    for condition in person.conditions:
        complete(next_attempt_folder(protocol.phase_folder(study, person.id, "task", condition)))
    options = RunOptions(study, person.id, "task", condition=person.conditions[0])
    with pytest.raises(SeesysError, match="--restart"):
        Session(options, load_study_config(), OperatorInput(io.StringIO("")), Console(file=io.StringIO()))
    with pytest.raises(SeesysError, match="unknown phase"):
        Session(
            RunOptions(study, person.id, "warmup"),
            load_study_config(),
            OperatorInput(io.StringIO("")),
            Console(file=io.StringIO()),
        )


def test_attempt_states(tmp_path):
    phase = tmp_path / "task"
    assert phase_status(phase) == "pending"
    a1 = next_attempt_folder(phase)
    assert read_run(a1)["status"] == INCOMPLETE  # killed before run.json
    (a1 / "run.json").write_text(json.dumps({"status": "running", "pid": os.getpid()}))
    assert read_run(a1)["status"] == "running"  # its process lives
    (a1 / "run.json").write_text(json.dumps({"status": "running", "pid": 2**22 + 11}))
    assert phase_status(phase) == INCOMPLETE
    a2 = next_attempt_folder(phase)
    assert a2.name == "attempt-2"
    complete(a2)
    assert phase_status(phase) == "done"


def test_status_line_reads_the_growing_logs(within):
    study, protocol = within
    person = protocol.participants[0]
    session = Session(
        RunOptions(study, person.id, "task"),
        load_study_config(),
        OperatorInput(io.StringIO("")),
        Console(file=io.StringIO()),
    )
    session.attempt = next_attempt_folder(session.phase_folder)
    session.frames = RowCounter(session.attempt / "frames.csv")
    session.record_mocap = True
    (session.attempt / "frames.csv").write_text(
        "frame_index,timestamp,state,tracked_points,track_ms\n0,1.0,OK,300,20.0\n1,1.03,LOST,0,20.0\n2,1.06,O"
    )  # half a row
    (session.attempt / MOCAP_STATS).write_text(json.dumps({"rate_hz": 99.6, "last_pose_time": time.time()}))
    watcher = StreamWatcher(load_network_config(), session.attempt, "device")
    line = session._status_line(watcher).plain
    assert " 2 LOST " in line
    assert "mocap 100 Hz" in line
    assert "est –" in line and "drop 0+0" in line and len(line) <= 80
    (session.attempt / MOCAP_STATS).write_text(json.dumps({"rate_hz": 99.6, "last_pose_time": time.time() - 5}))
    assert "mocap NO BODY" in session._status_line(watcher).plain


def test_row_counter_counts_complete_rows_incrementally(tmp_path):
    log = tmp_path / "frames.csv"
    count = RowCounter(log)
    assert count() == 0
    log.write_text("header\n1\n2")
    assert count() == 1
    with log.open("a") as f:
        f.write("\n3\n")
    assert count() == 3


def test_end_of_session_calibration_writes_the_ground_truth(within, tmp_path):
    """A session whose source had no ground truth: the runner calibrates the logged mocap into groundtruth.tum;
    a mocap body that never moves (motioncapture's mock) leaves the reason in run.json's words instead."""
    from testkit.mocap import OFFSET_S, write_simulated_session

    study, protocol = within
    session = Session(
        RunOptions(study, protocol.participants[0].id, "task"),
        load_study_config(),
        OperatorInput(io.StringIO("")),
        Console(file=io.StringIO()),
    )
    session.record_mocap = True
    (tmp_path / "moving").mkdir()
    session.attempt = write_simulated_session(tmp_path / "moving")
    assert session._calibrate() == "groundtruth.tum written from the mocap"
    report = json.loads((session.attempt / "calibration.json").read_text())
    assert abs(report["clock"]["offset_s"] - OFFSET_S) < 0.002
    assert session._calibrate() == "the source's ground truth kept"

    (tmp_path / "still").mkdir()
    session.attempt = write_simulated_session(tmp_path / "still")
    (session.attempt / "mocap.tum").write_text(
        "# t x y z qx qy qz qw\n" + "".join(f"{1000 + i / 100:.2f} 0.1 0.2 1.5 0 0 0 1\n" for i in range(3000))
    )
    outcome = session._calibrate()
    assert outcome.startswith("failed: a trajectory does not rotate") and "seesys study calibrate" in outcome
    assert not (session.attempt / "groundtruth.tum").exists()


def test_a_stopped_attempt_did_the_phase_and_an_interrupted_one_did_not(tmp_path):
    phase = tmp_path / "task"
    (next_attempt_folder(phase) / "run.json").write_text(json.dumps({"status": "interrupted"}))
    assert phase_status(phase) == INCOMPLETE
    (next_attempt_folder(phase) / "run.json").write_text(json.dumps({"status": "stopped"}))
    assert phase_status(phase) == "done"


def _recorded_attempt(folder, task_end_frame: int | None, frames: int = 240):
    """An attempt whose trajectory follows the ground truth until frame 120, then jitters by centimetres and loses
    tracking from frame 180: what a device logs after the operator ended the task, the camera put down."""
    rng = np.random.default_rng(3)
    folder.mkdir(parents=True)
    t = 1000.0 + np.arange(frames) / 30
    truth = np.column_stack([0.2 * np.sin(np.arange(frames) / 40), 0.001 * np.arange(frames), np.zeros(frames)])
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1))
    states = np.array(["OK"] * frames, dtype=object)
    states[180:] = "LOST"
    estimate = truth + rng.normal(scale=0.0005, size=truth.shape)
    estimate[120:] += rng.normal(scale=0.03, size=(frames - 120, 3))
    tracked = states == "OK"
    write_tum(folder / "groundtruth.tum", Poses(t, truth, quats))
    write_tum(folder / "trajectory.tum", Poses(t[tracked], estimate[tracked], quats[tracked]))
    pd.DataFrame(
        {"frame_index": np.arange(frames), "timestamp": t, "state": states, "tracked_points": 300, "track_ms": 20.0}
    ).to_csv(folder / "frames.csv", index=False)
    run = {"status": "completed"}
    if task_end_frame is not None:
        run = {
            "status": "stopped",
            "task_end": {"time": 0.0, "frame_index": task_end_frame, "timestamp": float(t[task_end_frame])},
        }
    (folder / "run.json").write_text(json.dumps(run))
    return folder, t


def test_the_metrics_use_the_task_span_only(tmp_path):
    """Frames logged after the operator ended the task (run.json's task_end) stay in the session but leave its
    metrics: the same as if the device had stopped at the task's end."""
    cfg = load_study_config().metrics
    stopped, t = _recorded_attempt(tmp_path / "stopped", task_end_frame=119)
    ran_on, _ = _recorded_attempt(tmp_path / "ran_on", task_end_frame=None)
    metrics, per_attempt = participant_metrics([stopped], cfg)
    assert metrics.completeness == 1.0 and metrics.tracking_losses == 0
    assert metrics.rpe_max_m < 0.005 and per_attempt[0].rpe.timestamps.max() <= t[119]
    assert metrics.time_on_task_s == pytest.approx(t[119] - t[0])
    whole, _ = participant_metrics([ran_on], cfg)
    assert whole.completeness < 0.9 and whole.rpe_max_m > 0.02  # what the frames after the end would have added
    frames = read_frame_log(stopped / "frames.csv")
    assert len(frames) == 240  # the frames after the end are kept in the session
    (stopped / "run.json").write_text(
        json.dumps({"status": "stopped", "task_end": {"time": 0.0, "frame_index": None, "timestamp": None}})
    )
    nothing, _ = participant_metrics([stopped], cfg)
    assert nothing.pairs == 0  # ended before the device logged a frame: no frame was in the task


@pytest.fixture
def no_sound_card(monkeypatch):
    """Configs with private ipc endpoints, an output device no machine has and the mocap at a closed port: an
    audible condition must fall back to a JACK dummy server, and the mocap logger fails while starting."""
    from advisory.sandbox import JackDummy
    from estimator.service.sandbox import private_configs
    from seesys.io.config import CONFIG_DIR_ENV

    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2)")
    root = Path(tempfile.mkdtemp(prefix="snc", dir="/tmp"))  # ipc paths are at most 107 bytes
    with refused_port() as closed_port:
        configs, _ = private_configs(
            root,
            endpoint=f"ipc://{root}/handoff",
            output_device="no-such-sound-card",
            backend="vicon",
            hostname="127.0.0.1",
            port=closed_port,
            connect_timeout_s=2.0,
        )
        monkeypatch.setenv(CONFIG_DIR_ENV, str(configs))
        yield root
    shutil.rmtree(root, ignore_errors=True)


@pytest.mark.system
def test_a_failed_start_is_no_attempt_and_no_sound_card_means_a_jack_dummy(no_sound_card):
    """`study run` in the seesys condition on a machine without the configured sound card starts the JACK dummy
    server `seesys run` starts; a start that fails (here the mocap logger) leaves its folder set aside, unnumbered,
    and the next run is attempt-1."""
    protocol = make_protocol(load_study_config().protocol, participants_per_condition=1)
    study = no_sound_card / "study"
    write_protocol(study, protocol)
    person = next(p for p in protocol.participants if p.conditions == ["seesys"])
    console = io.StringIO()
    session = Session(
        RunOptions(study, person.id, "task", source=f"tum:{SAMPLE}", record_mocap=True),
        load_study_config(),
        OperatorInput(io.StringIO("")),
        Console(file=console),
    )
    with pytest.raises(SeesysError) as e:
        session.run()
    message = str(e.value)
    assert "mocap" in message and "failed start, not counted as an attempt" in message and "\n" not in message
    phase = session.phase_folder
    assert attempt_folders(phase) == [] and phase_status(phase) == "pending"
    (aside,) = list(phase.iterdir())
    assert aside.name.startswith("failed-start-") and str(aside) in message
    run = json.loads((aside / "run.json").read_text())
    assert run["status"] == "failed" and run["failed_start"] is True and str(aside / "logs") in run["start_error"]
    assert run["audio"].startswith("JACK dummy server") and "no audio output" in console.getvalue()
    assert read_events(aside).kind.tolist()[-1] == "stop"
    assert "JACK Audio Connection Kit" in (aside / "configs" / "advisory.toml").read_text()
    assert next_attempt_folder(phase).name == "attempt-1"


@pytest.mark.system
def test_a_device_that_ignores_sigint_is_terminated_after_the_timeout(tmp_path):
    """What keeps `q` from hanging on a device that does not end (a live camera that never stops delivering):
    SIGINT, then, after the timeout, SIGTERM."""
    import subprocess
    import sys

    from seesys.io.children import Child

    code = "import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); signal.pause()"
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True)
    assert process.stdout.readline().strip() == "ready"
    device = Child("device", process, tmp_path / "device.log")
    assert device.interrupt(0.5) == -15 and not device.running  # SIGTERM ended it


def test_a_collapsed_replay_log_is_refused_before_anything_starts(within, tmp_path):
    study, protocol = within
    log = tmp_path / "est.csv"
    log.write_text("timestamp,error_m\n" + "1.3050311e+09,0.01\n" * 10)
    with pytest.raises(SeesysError, match="lost their precision"):
        Session(
            RunOptions(study, protocol.participants[0].id, "task", replay_estimates=log),
            load_study_config(),
            OperatorInput(io.StringIO("")),
            Console(file=io.StringIO()),
        )
    assert not list(study.rglob("attempt-*"))
