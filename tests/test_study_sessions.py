"""Study sessions without ORB-SLAM3: the within-subjects condition order, a done phase is not re-recorded
without --restart, the runner's status line reads the logs as they are being written, and the attempt states."""

from __future__ import annotations

import io
import json
import os
import time

import pytest
from rich.console import Console

from seesys.core.errors import SeesysError
from seesys.io.children import RowCounter
from seesys.io.network import load_network_config
from study.config import load_study_config
from study.mocap.logger import MOCAP_STATS
from study.operator import OperatorInput
from study.protocol import make_protocol, write_protocol
from study.runner import RunOptions, Session, choose_condition
from study.sessions import INCOMPLETE, next_attempt_folder, phase_status, read_run
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
        Session(RunOptions(study, person.id, "warmup"), load_study_config(), OperatorInput(io.StringIO("")),
                Console(file=io.StringIO()))


def test_attempt_states(tmp_path):
    phase = tmp_path / "task"
    assert phase_status(phase) == "pending"
    a1 = next_attempt_folder(phase)
    assert read_run(a1)["status"] == INCOMPLETE  # killed before run.json
    (a1 / "run.json").write_text(json.dumps({"status": "running", "pid": os.getpid()}))
    assert read_run(a1)["status"] == "running"  # its process lives
    (a1 / "run.json").write_text(json.dumps({"status": "running", "pid": 2 ** 22 + 11}))
    assert phase_status(phase) == INCOMPLETE
    a2 = next_attempt_folder(phase)
    assert a2.name == "attempt-2"
    complete(a2)
    assert phase_status(phase) == "done"


def test_status_line_reads_the_growing_logs(within):
    study, protocol = within
    person = protocol.participants[0]
    session = Session(RunOptions(study, person.id, "task"), load_study_config(), OperatorInput(io.StringIO("")),
                      Console(file=io.StringIO()))
    session.attempt = next_attempt_folder(session.phase_folder)
    session.frames = RowCounter(session.attempt / "frames.csv")
    session.record_mocap = True
    (session.attempt / "frames.csv").write_text("frame_index,timestamp,state,tracked_points,track_ms\n"
                                                "0,1.0,OK,300,20.0\n1,1.03,LOST,0,20.0\n2,1.06,O")  # half a row
    (session.attempt / MOCAP_STATS).write_text(json.dumps({"rate_hz": 99.6, "last_pose_time": time.time()}))
    watcher = StreamWatcher(load_network_config(), session.attempt)
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
    from test_study_mocap import OFFSET_S, simulated_session

    study, protocol = within
    session = Session(RunOptions(study, protocol.participants[0].id, "task"), load_study_config(),
                      OperatorInput(io.StringIO("")), Console(file=io.StringIO()))
    session.record_mocap = True
    (tmp_path / "moving").mkdir()
    session.attempt = simulated_session.__wrapped__(tmp_path / "moving")
    assert session._calibrate() == "groundtruth.tum written from the mocap"
    report = json.loads((session.attempt / "calibration.json").read_text())
    assert abs(report["clock"]["offset_s"] - OFFSET_S) < 0.002
    assert session._calibrate() == "the source's ground truth kept"

    (tmp_path / "still").mkdir()
    session.attempt = simulated_session.__wrapped__(tmp_path / "still")
    (session.attempt / "mocap.tum").write_text("# t x y z qx qy qz qw\n" + "".join(
        f"{1000 + i / 100:.2f} 0.1 0.2 1.5 0 0 0 1\n" for i in range(3000)))
    outcome = session._calibrate()
    assert outcome.startswith("failed: a trajectory does not rotate") and "seesys study calibrate" in outcome
    assert not (session.attempt / "groundtruth.tum").exists()
