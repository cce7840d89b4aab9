"""The observer, the live view and the summary of `seesys run` work on small records (`ViewSetup`, `RunState`,
`Observation`, `RunRecord`), not on the app: here they are given such records and a session folder whose logs were
written as the parts write them."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from testkit.sample import run_seesys

from advisory.config import load_advisory_config
from seesys.core.session_layout import (
    ADVISORY_COLUMNS,
    ADVISORY_CSV,
    ESTIMATE_COLUMNS,
    ESTIMATES_CSV,
    FRAMES_CSV,
    FRAMES_HEADER,
)
from seesys.io.logfiles import CsvLog
from seesys_app.config import load_app_config
from seesys_app.information import InformationClock
from seesys_app.observer import EstimatorObservation, Observation, RunObserver
from seesys_app.records import PartStatus, RunRecord, RunState, StreamDrops
from seesys_app.run_cli import final_line
from seesys_app.summary import broken_at_gaps, write_summary
from seesys_app.view import LiveView, Snapshot, ViewSetup, dropped_text, plain_line

ERRORS_M = (0.003, 0.005, 0.009)
PULSES = (0, 1, 2)


@pytest.fixture
def session(tmp_path: Path) -> Path:
    """Ten frames (the last lost), three estimates and three advisory buffers, as the device and advisory log them."""
    folder = tmp_path / "session"
    folder.mkdir()
    states = ["OK"] * 8 + ["OK_KLT", "LOST"]
    (folder / FRAMES_CSV).write_text(
        FRAMES_HEADER
        + "\n"
        + "".join(f"{i},{100 + i / 30:.6f},{state},{200 - i},12.5\n" for i, state in enumerate(states))
    )
    estimates = CsvLog(folder / ESTIMATES_CSV, ESTIMATE_COLUMNS)
    for k, error in enumerate(ERRORS_M):
        row = {
            "frame_index": 3 * k,
            "timestamp": 100 + k / 10,
            "error_m": error,
            "model_version": "m",
            "server_ms": 4.0,
            "received_unix": 1.0e9 + k,
            "tracking_ms": 10.0,
            "preprocess_ms": 3.0,
            "transmit_inference_ms": 6.0,
            "end_to_end_ms": 10.0 + k,
            "capture_to_estimate_ms": 20.0,
        }
        estimates.write(*(row[c] for c in ESTIMATE_COLUMNS))
    estimates.close()
    advisory = CsvLog(folder / ADVISORY_CSV, ADVISORY_COLUMNS)
    for k, pulses in enumerate(PULSES):
        row = {
            "wall_time": 1.0e9 + k,
            "time_mono": float(k),
            "condition": "seesys",
            "status": "ok",
            "trigger": "cadence",
            "input_value": ERRORS_M[k],
            "n_pulses": pulses,
            "played_pulses": pulses,
            "buffer_id": k,
            "arrival_mono": float(k),
            "play_at_mono": float(k),
            "pulses_from": "estimate",
        }
        advisory.write(*(row[c] for c in ADVISORY_COLUMNS))
    advisory.close()
    return folder


def test_the_view_draws_what_the_observer_read_from_the_logs(session: Path):
    setup = ViewSetup(
        session, "tum:somewhere", "seesys", load_app_config().view, 0.012, remote_estimator="10.0.0.2:5556"
    )
    view = LiveView(setup, Console(file=io.StringIO()))
    state = RunState(
        {"device": PartStatus(running=True), "generator": PartStatus(running=True, restarts=1)},
        StreamDrops(skipped_by_device=2, lost_in_transit=3, bad_messages=1),
    )
    observation = RunObserver(session, load_app_config().view, "device-0", None).look(state.parts)
    assert (observation.frames, observation.tracking_state, observation.estimates) == (10, "LOST", 3)
    assert observation.estimator == EstimatorObservation()  # a remote estimator is not asked
    s = view.collect(observation, state)
    assert (s.frames, s.state, s.estimates) == (10, "LOST", 3)
    assert s.latest_error_m == ERRORS_M[-1]
    assert s.pulses == list(PULSES)
    assert (s.skipped, s.lost, s.bad_messages) == (2, 3, 1)
    assert s.restarts == {"device": 0, "generator": 1}
    assert s.estimator == "remote 10.0.0.2:5556" and s.estimator_dropped is None
    assert s.latency_ms[0] == 11.0


def test_the_summary_is_written_from_a_run_record(session: Path):
    record = RunRecord(
        session,
        "tum:somewhere",
        "rgbd",
        True,
        "seesys",
        "local",
        "WAV only",
        load_advisory_config().equation2,
        1.0,
        None,
        {
            "device": PartStatus(running=False, exits=(0,)),
            "estimator": PartStatus(running=False, restarts=1, exits=(-9, 0)),
        },
        StreamDrops(1, 2, 3),
        estimator_dropped={"stale": 4, "shape_mismatch": 5},
        seconds_without_information=2.5,
        without_information_by_reason={"estimator restarting": 2.5},
    )
    output = load_app_config().output
    summary = write_summary(
        record, output, status="completed", error=None, started="a", ended="b", exits={"device": 0, "estimator": 0}
    )
    assert json.loads((session / output.summary).read_text()) == summary
    assert summary["frames"] == 10 and summary["estimates"] == 3 and summary["buffers"] == 3
    assert summary["tracked_fraction"] == pytest.approx(0.9)  # OK_KLT is tracked too
    assert summary["parts"]["estimator"] == {"restarts": 1, "exits": [-9, 0], "final_exit": 0}
    assert summary["drops"] == {
        "skipped_by_device": 1,
        "lost_in_transit": 2,
        "bad_messages": 3,
        "estimator": {"stale": 4, "shape_mismatch": 5},
    }
    assert summary["information"] == {"seconds_without": 2.5, "by_reason": {"estimator restarting": 2.5}}
    assert summary["buffers_by_pulses"] == {"0": 1, "1": 1, "2": 1}
    assert (session / output.plot).is_file()


def test_the_final_line_and_the_view_print_no_nan_or_none(session: Path):
    summary = {
        "frames": 10,
        "estimates": 0,
        "end_to_end_ms": {"p50": None, "p95": None, "p99": None},
        "buffers": 3,
        "audio": "WAV only",
        "error": None,
        "information": {"seconds_without": 0.0, "by_reason": {}},
    }
    line = final_line("completed", summary, session)
    assert line.startswith("completed: 10 frames, no estimates, 3 advisory buffers") and "None" not in line
    assert final_line("failed", {**summary, "error": "the estimator is gone"}, session) == (
        f"seesys: error: the estimator is gone (session {session})"
    )
    assert "nan" not in plain_line(Snapshot()) and "– fps" in plain_line(Snapshot())


def test_an_event_redraws_the_view_with_the_parts_as_they_are_now(session: Path):
    setup = ViewSetup(
        session, "tum:somewhere", "seesys", load_app_config().view, 0.012, remote_estimator="10.0.0.2:5556"
    )
    view = LiveView(setup, Console(file=io.StringIO(), force_terminal=True, width=150))
    restarting = RunState({"generator": PartStatus(running=False, restarting=True)})
    with view.shown():
        view.update(Observation(), restarting)
        view.note("generator: restarted", Observation(), RunState({"generator": PartStatus(running=True, restarts=1)}))
        assert view.snapshot.restarts == {"generator": 1}
        view.stopping("stopping: the device closes its files")
    screen = view.console.file.getvalue()  # the panel as it was left when the view closed
    last = screen[screen.rindex("seesys run") :]
    assert "stopping: the device closes its files" in last and "Ctrl-C stops" not in last
    assert "generator restarted 1×" in last


def test_the_estimate_line_breaks_where_estimates_stopped():
    t, v = broken_at_gaps(np.array([0.0, 0.2, 0.4, 5.0, 5.2]), np.array([1.0, 2.0, 3.0, 4.0, 5.0]), 1.0)
    assert np.isnan(t[3]) and np.isnan(v[3])
    assert np.array_equal(t[~np.isnan(t)], [0.0, 0.2, 0.4, 5.0, 5.2])
    assert len(broken_at_gaps(np.array([0.0, 0.5]), np.array([1.0, 1.0]), 1.0)[0]) == 2


@pytest.mark.system
def test_a_bad_source_is_refused_before_anything_starts(tmp_path):
    done = run_seesys(
        "run", "--source", f"tum:{tmp_path / 'missing'}", "--local", "--condition", "none", "--out", str(tmp_path / "s")
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "missing" in done.stderr, done.stderr
    assert not (tmp_path / "s").exists()


def test_seconds_without_information_count_beyond_the_allowances_by_reason():
    clock = InformationClock(stale_after_s=1.0, first_estimate_s=10.0)
    assert not clock.advance(100.0, "before the device")  # no frame yet: nothing counts
    clock.first_frame(100.0)
    assert not clock.advance(109.0, "waiting")
    assert clock.advance(112.0, "no estimate yet")  # 2 s beyond the first-estimate allowance
    clock.estimate(112.0)
    assert not clock.advance(113.0, "stale")
    assert clock.advance(114.0, "estimator restarting") and clock.advance(116.5, "estimator dropped stale 3")
    assert clock.seconds_without == pytest.approx(2.0 + 1.0 + 2.5)
    assert clock.by_reason == pytest.approx(
        {"no estimate yet": 2.0, "estimator restarting": 1.0, "estimator dropped stale 3": 2.5}
    )


def test_the_view_names_every_drop_reason_and_why_there_is_no_information(session: Path):
    assert dropped_text({"stale": 2, "queue_full": 0, "shape_mismatch": 7}) == "stale 2, shape_mismatch 7"
    assert dropped_text({"stale": 0}) == "0" and dropped_text(None) == "?"
    setup = ViewSetup(
        session, "tum:somewhere", "seesys", load_app_config().view, 0.012, remote_estimator="10.0.0.2:5556"
    )
    view = LiveView(setup, Console(file=io.StringIO()))
    s = view.collect(Observation(), RunState({"device": PartStatus(running=True)}, information="estimator restarting"))
    assert "information NONE: estimator restarting" in plain_line(s)
    degraded = {
        "frames": 10,
        "estimates": 3,
        "end_to_end_ms": {"p50": 11.0, "p95": 12.0, "p99": 12.0},
        "buffers": 3,
        "audio": "WAV only",
        "error": None,
        "information": {"seconds_without": 4.0, "by_reason": {"estimator restarting": 4.0}},
    }
    assert final_line("degraded", degraded, session).startswith(
        "degraded (4.0 s without information: estimator restarting 4.0 s): 10 frames, 3 estimates"
    )


def test_a_local_estimator_is_shown_down_while_it_restarts_and_starting_until_it_answers(session: Path):
    setup = ViewSetup(session, "tum:somewhere", "seesys", load_app_config().view, 0.012, remote_estimator=None)
    view = LiveView(setup, Console(file=io.StringIO()))
    restarting = RunState({"estimator": PartStatus(running=False, restarting=True)})
    assert view.collect(Observation(), restarting).estimator == "DOWN (restarting)"
    running = RunState({"estimator": PartStatus(running=True, restarts=1)})
    assert view.collect(Observation(estimator=EstimatorObservation(asked=True)), running).estimator == (
        "starting (not answering yet)"
    )
    up = Observation(estimator=EstimatorObservation(True, True, "deepsee-1", {"stale": 2}))
    s = view.collect(up, running)
    assert s.estimator == "up, deepsee-1" and s.estimator_dropped == {"stale": 2}
