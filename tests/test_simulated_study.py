"""The closed-loop simulated study: a reduced study end to end (simulate, resume, analyze), the loop's causality, and
the operator's response, on the real renderer, ORB-SLAM3, monitor, shipped model and advisory rules."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from testkit.polling import wait_for
from testkit.sample import REPO

from advisory.advice import Advice
from advisory.conditions import Condition
from advisory.config import load_advisory_config
from advisory.scheduler import Reading
from estimator.service.broker import default_model
from estimator.service.config import load_service_config
from seesys.core.errors import ConfigError
from seesys.io.config import CONFIG_DIR_ENV, write_config_dir
from seesys.io.core_settings import load_label_config
from seesys.io.session_labels import label_session
from seesys.io.trajectory_files import read_tum
from seesys_app.cli import main
from seesys_app.simulate import study as simulated_study
from seesys_app.simulate.config import load_simulate_config
from seesys_app.simulate.operator import Goal, SimulatedOperator, draw_traits
from seesys_app.simulate.scan_task import build_scan_task
from seesys_app.simulate.session import OPERATOR_JSON, Participant, simulate_session
from seesys_app.simulate.study import Job, pending_jobs, prepare_study, run_study
from seesys_app.simulate.yoking import partner_of
from study.protocol import read_protocol
from study.sessions import RUN_JSON, attempt_folders
from synth.config import load_synth_config

SHORT = ["--objects", "1", "--max-task-s", "2.5"]


def _operator(cfg, number: int, seed: int) -> SimulatedOperator:
    synth = load_synth_config()
    task = build_scan_task(
        synth.preset(cfg.task.environment),
        synth.sensor,
        cfg.task,
        cfg.operator.scan_distance_m[1],
        cfg.operator.scan_arc_deg[1],
    )
    traits = draw_traits(np.random.default_rng([1, number]), cfg.operator, cfg.response)
    traits = dataclasses.replace(traits, compliance=1.0)
    goals = [Goal(o.aim, o.viewpoint(traits.scan_distance_m)) for o in task.objects]
    start = np.append(goals[0].stand + task.objects[0].facing, goals[0].aim[2] + 0.15)
    return SimulatedOperator(
        traits,
        goals,
        start,
        cfg.task.settle_s,
        60.0,
        getattr(synth.motion, traits.motion_group),
        cfg.operator,
        cfg.response,
        seed,
    )


@pytest.mark.system
def test_an_operator_moves_as_in_silence_until_it_reacts_to_a_warning_and_slows_down_after():
    cfg = load_simulate_config()
    quiet, warned = _operator(cfg, 1, 7), _operator(cfg, 1, 7)
    warned.hear(5.0, 2)  # two pulses from 5 s on, a buffer every 1/3 s
    for k in range(1, 30):
        warned.hear(5.0 + k / 3, 2)
    for op in (quiet, warned):
        op.advance(20.0)
    react = 5.0 + warned.traits.reaction_delay_s
    a, b = quiet.trajectory(), warned.trajectory()
    before = a.times < react - 1e-6
    assert np.array_equal(a.positions[before], b.positions[before])
    after = (a.times > react + 0.5) & (a.times < 15.0)
    assert np.abs(a.positions[after] - b.positions[after]).max() > 0.05

    def speed(t) -> float:
        inside = (t.times > react + 1.0) & (t.times < 14.0)
        return float(np.linalg.norm(np.diff(t.positions[inside], axis=0), axis=1).sum())

    assert speed(b) < 0.85 * speed(a)
    assert warned.warnings_heeded == 1


def test_settings_that_cannot_work_are_refused_by_name(tmp_path):
    folder = write_config_dir(tmp_path / "c", {"reaction_delay_s": [0.05, 0.3]})
    with pytest.raises(ConfigError, match="reaction_delay_s"):
        load_simulate_config(folder)
    folder = write_config_dir(tmp_path / "d", {"simulate.design": "crossover"})
    with pytest.raises(ConfigError, match="crossover"):
        load_simulate_config(folder)


def test_the_sessions_a_yoked_one_waits_for_are_queued_first_so_partners_never_run_last_alone(tmp_path):
    cfg = load_simulate_config()
    cfg = dataclasses.replace(cfg, study=dataclasses.replace(cfg.study, participants_per_condition=3))
    protocol = prepare_study(tmp_path / "study", cfg, default_model(load_service_config(), None))
    jobs, total = pending_jobs(tmp_path / "study", protocol)
    assert total == len(jobs) == 15
    assert [(job.participant.id, job.participant.condition) for job in jobs[:3]] == [
        ("P01", "seesys"),
        ("P02", "seesys"),
        ("P03", "seesys"),
    ]
    assert [job.participant.id for job in jobs[3:]] == sorted(job.participant.id for job in jobs[3:])
    queued = [job.folder for job in jobs]
    assert all(queued.index(job.after) < queued.index(job.folder) for job in jobs if job.after is not None)
    assert sum(job.after is not None for job in jobs) == 3


@pytest.fixture(scope="module")
def reduced_study(tmp_path_factory):
    """The default arms (none, motion, yoked, oracle, seesys), within subjects, 2 simulated participants, one object,
    at most 2.5 s each: 10 sessions. Equation 2 from 2 mm at 1,000 pulses a metre: these short renders' error is
    about 3 mm, which the served model reads, so that some windows warn (at the default 4 mm none would)."""
    root = tmp_path_factory.mktemp("simulated")
    configs = write_config_dir(root / "configs", {"alpha_m": 0.002, "pulses_per_metre": 1000.0})
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(CONFIG_DIR_ENV, str(configs))
        assert main(["study", "simulate", "--out", str(root / "study"), "--participants", "2", *SHORT]) == 0
    return root / "study"


@pytest.mark.system
def test_a_reduced_study_runs_end_to_end_and_analyses_as_a_real_one(reduced_study, capsys):
    protocol = read_protocol(reduced_study)
    arms = {"none", "motion", "yoked", "oracle", "seesys"}
    assert protocol.phases == ["task"] and len(protocol.participants) == 2 and protocol.design == "within"
    assert all(set(person.conditions) == arms for person in protocol.participants)
    for person, condition in ((p, c) for p in protocol.participants for c in p.conditions):
        attempt = attempt_folders(protocol.phase_folder(reduced_study, person.id, "task", condition))[-1]
        run = json.loads((attempt / RUN_JSON).read_text())
        assert run["status"] == "completed" and run["simulated"] and run["frames"] > 60
        frames = pd.read_csv(attempt / "frames.csv")
        assert (frames.state == "OK").mean() > 0.9
        assert len(read_tum(attempt / "groundtruth.tum")) == run["frames"]
        assert len(read_tum(attempt / "trajectory.tum")) > 60
        events = pd.read_csv(attempt / "events.csv")
        assert "initialised" in set(events.kind)
        assert json.loads((attempt / OPERATOR_JSON).read_text())["participant"] == person.id
        estimates = pd.read_csv(attempt / "estimates.csv")
        assert len(estimates) > 5
        # Causal: an estimate is of a frame already tracked, and arrives after that frame.
        tracked = frames.set_index("frame_index")
        assert (tracked.loc[estimates.frame_index, "state"] == "OK").all()
        assert (estimates.receipt_time > estimates.timestamp).all()
        advisory = pd.read_csv(attempt / "advisory.csv")
        live = advisory.dropna(subset=["arrival_mono"])
        assert (live.arrival_mono <= live.wall_time + 1e-9).all()
        assert set(advisory.condition) == {condition}
        if condition == "none":
            assert (advisory.played_pulses == 0).all()
    capsys.readouterr()
    assert main(["analyze", str(reduced_study)]) == 0
    out = reduced_study / "analysis"
    table = pd.read_csv(out / "participants.csv")
    assert table.rpe_mean_m.notna().all() and table.mean_speed_mps.between(0.05, 2.0).all()
    assert table.error_per_metre.notna().all() and table.warning_share.between(0, 1).all()
    changes = pd.read_csv(out / "changes.csv")
    assert {("seesys", arm) for arm in arms - {"seesys"}} <= set(zip(changes.condition, changes.against))
    shares = pd.read_csv(out / "oracle_share.csv")
    assert "error_per_metre" in set(shares.variable)
    report = (out / "report.md").read_text()
    assert "Relative change of the means" in report and "Mean speed" in report and "oracle's gain" in report
    assert (out / "figures" / "tradeoff_time_on_task_s_rpe_mean_m.png").stat().st_size > 0


def _attempt(study, protocol, person, condition):
    return attempt_folders(protocol.phase_folder(study, person, "task", condition))[-1]


@pytest.mark.system
def test_a_yoked_session_waits_for_its_partner_and_plays_exactly_its_pulses_at_the_same_times(reduced_study):
    protocol = read_protocol(reduced_study)
    for person in protocol.participants:
        partner = partner_of(protocol, person.id)
        assert partner != person.id
        yoked = _attempt(reduced_study, protocol, person.id, "yoked")
        source = _attempt(reduced_study, protocol, partner, "seesys")
        start = {a: json.loads((a / RUN_JSON).read_text())["advice_start"] for a in (yoked, source)}
        played = pd.read_csv(yoked / "advisory.csv")
        replayed = played[played.pulses_from == "replayed"]
        # It waited for its partner's session: started once that one had ended.
        ran = {a: json.loads((a / RUN_JSON).read_text()) for a in (yoked, source)}
        assert ran[yoked]["started"] >= ran[source]["ended"]
        original = pd.read_csv(source / "advisory.csv")
        # Every buffer of the partner, while the yoked session lasted, at the same offset with the same pulses.
        original = original[original.time_mono - start[source] <= played.time_mono.max() - start[yoked]]
        np.testing.assert_allclose(
            replayed.time_mono.to_numpy() - start[yoked], original.time_mono.to_numpy() - start[source], atol=1e-9
        )
        assert replayed.played_pulses.tolist() == original.played_pulses.tolist()
        assert replayed.input_value.isna().all()  # nothing of this session's estimates or truth


@pytest.mark.system
def test_the_oracle_hears_the_labels_true_error_of_each_window_end_and_nothing_else(reduced_study):
    """Replaying Equation 2 on the label of each window-end frame (from the session's own trajectory and ground
    truth files), at the estimator's arrival times, through the same advice step gives the oracle's buffers."""
    cfg = load_advisory_config(reduced_study.parent / "configs")  # the study's Equation 2 (the fixture's)
    protocol = read_protocol(reduced_study)
    for person in protocol.participants:
        attempt = _attempt(reduced_study, protocol, person.id, "oracle")
        labels = label_session(attempt, False, load_label_config())
        frames = pd.read_csv(attempt / "frames.csv")
        assert len(labels.error_m) == len(frames)
        truth = dict(zip(frames.frame_index, labels.error_m))
        estimates = pd.read_csv(attempt / "estimates.csv")
        advice = Advice(Condition.ORACLE, cfg, json.loads((attempt / RUN_JSON).read_text())["advice_start"], 0.1)
        buffers = []
        arrivals = dict(zip(estimates.frame_index, estimates.receipt_time))
        for index, stamp in zip(frames.frame_index, frames.timestamp):
            error = truth.get(index, np.nan)
            if index in arrivals and np.isfinite(error):
                buffers += advice.take(arrivals[index], Reading(float(error)))
            buffers += advice.until(stamp)
        logged = pd.read_csv(attempt / "advisory.csv")
        assert len(buffers) == len(logged) and len(buffers) > 3
        assert [b.decision.n_pulses for b in buffers] == logged.n_pulses.tolist()
        # the trajectory file holds the poses to the micrometre
        np.testing.assert_allclose([b.decision.value for b in buffers], logged.input_value, rtol=1e-4, atol=1e-6)


@pytest.mark.system
def test_every_arm_moves_as_the_silent_one_until_its_first_warning_is_heard(reduced_study):
    """Within subjects, a participant's operator is the same in every arm: its ground truth is that of its silent
    session until the first buffer of the arm that played pulses sounds and the operator can react."""
    protocol = read_protocol(reduced_study)
    for person in protocol.participants:
        silent = read_tum(_attempt(reduced_study, protocol, person.id, "none") / "groundtruth.tum")
        traits = json.loads((_attempt(reduced_study, protocol, person.id, "none") / OPERATOR_JSON).read_text())
        for arm in ("motion", "yoked", "oracle", "seesys"):
            attempt = _attempt(reduced_study, protocol, person.id, arm)
            advisory = pd.read_csv(attempt / "advisory.csv")
            warned = advisory.loc[advisory.played_pulses > 0, "play_at_mono"]
            heard = float(warned.min()) + traits["reaction_delay_s"] if len(warned) else np.inf
            moved = read_tum(attempt / "groundtruth.tum")
            n = min(len(moved), len(silent))
            before = moved.timestamps[:n] < heard
            assert before.sum() > 10
            np.testing.assert_allclose(moved.positions[:n][before], silent.positions[:n][before], atol=1e-9)


@pytest.mark.system
def test_running_the_study_again_resumes_and_other_settings_are_refused(reduced_study, capsys):
    before = sorted(p for p in reduced_study.rglob("attempt-*"))
    assert main(["study", "simulate", "--out", str(reduced_study), "--participants", "2", *SHORT]) == 0
    assert sorted(p for p in reduced_study.rglob("attempt-*")) == before
    assert "10 of 10 sessions done" in capsys.readouterr().out
    assert (
        main(
            [
                "study",
                "simulate",
                "--out",
                str(reduced_study),
                "--participants",
                "2",
                "--objects",
                "2",
                "--max-task-s",
                "2.5",
            ]
        )
        == 2
    )
    assert "task.objects" in capsys.readouterr().err


@pytest.mark.system
def test_the_same_operator_moves_differently_after_a_warning_than_in_silence(tmp_path, monkeypatch):
    """The loop is closed: pulses the advisory played (all windows warn: alpha is set very low) change the
    participant's motion from the moment it reacts, and not before."""
    configs = write_config_dir(
        tmp_path / "configs",
        {"alpha_m": 0.0002, "pulses_per_metre": 10000.0, "compliance": [1.0, 1.0], "pulses_from": "estimate"},
    )
    monkeypatch.setenv(CONFIG_DIR_ENV, str(configs))
    cfg = load_simulate_config(configs)
    cfg = dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, objects=2, max_task_s=3.5))
    model = default_model(load_service_config(configs), None)
    runs = {
        c: simulate_session(cfg, Participant("P01", 1, c), tmp_path / c, model, configs) for c in ("none", "seesys")
    }
    quiet, warned = (read_tum(runs[c].folder / "groundtruth.tum") for c in ("none", "seesys"))
    advisory = pd.read_csv(runs["seesys"].folder / "advisory.csv")
    first = float(advisory.loc[advisory.played_pulses > 0, "play_at_mono"].min())
    delay = json.loads((runs["seesys"].folder / OPERATOR_JSON).read_text())["reaction_delay_s"]
    n = min(len(quiet), len(warned))
    moved = np.linalg.norm(quiet.positions[:n] - warned.positions[:n], axis=1)
    t = quiet.timestamps[:n]
    assert moved[t < first + delay - 0.05].max() < 1e-9
    assert first + delay + 0.5 < t[-1]
    assert moved[t > first + delay + 0.5].max() > 0.01


@pytest.mark.system
def test_sigterm_stops_every_session_with_its_files_final(tmp_path):
    """Started as a shell script's background job (SIGINT ignored), stopped by SIGTERM once both sessions track:
    each session ends `interrupted` with its logs whole, the command exits 130, and both sessions are still to do."""
    study = tmp_path / "study"
    command = [
        sys.executable,
        "-m",
        "seesys",
        "study",
        "simulate",
        "--out",
        str(study),
        "--participants",
        "1",
        "--conditions",
        "none,seesys",
        "--design",
        "between",
        "--objects",
        "3",
        "--max-task-s",
        "60",
    ]
    process = subprocess.Popen(
        command,
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )

    def tracking() -> list[Path]:
        frames = list(study.glob("participants/*/task/attempt-1/frames.csv"))
        return frames if len(frames) == 2 and all(len(f.read_text().splitlines()) > 10 for f in frames) else []

    wait_for(tracking, what="both sessions tracking")
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    for attempt in study.glob("participants/*/task/attempt-1"):
        run = json.loads((attempt / RUN_JSON).read_text())
        assert run["status"] == "interrupted" and run["frames"] >= 10
        frames = pd.read_csv(attempt / "frames.csv")
        assert len(frames) == run["frames"] and len(read_tum(attempt / "groundtruth.tum")) == run["frames"]
        assert json.loads((attempt / "session.json").read_text())["status"] == "interrupted"
        assert pd.read_csv(attempt / "events.csv").kind.iloc[-1] == "stop"
    jobs, total = pending_jobs(study, read_protocol(study))
    assert total == 2 and len(jobs) == 2


@pytest.mark.system
def test_a_session_that_reports_no_frame_is_killed_as_hung_and_the_study_says_so(tmp_path):
    """A stall timeout far shorter than a session's start-up (its first report comes after a simulated second: 30
    rendered and tracked frames) stands in for ORB-SLAM3 hanging: every session is killed, its attempt says why, and
    the study ends with status 1 naming each one."""
    configs = write_config_dir(tmp_path / "configs", {"simulate.stall_timeout_s": 0.2, "retries": 0})
    study = tmp_path / "study"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "study",
            "simulate",
            "--out",
            str(study),
            "--participants",
            "1",
            "--conditions",
            "none,seesys",
            "--design",
            "between",
            *SHORT,
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, CONFIG_DIR_ENV: str(configs)},
    )
    assert done.returncode == 1, done.stderr
    said = " ".join(done.stdout.split())
    assert "0 of 2 sessions done" in said
    assert said.count("failed: P01 none: no frame") == said.count("failed: P02 seesys: no frame") == 1
    for attempt in study.glob("participants/*/task/attempt-1"):
        run = json.loads((attempt / RUN_JSON).read_text())
        assert run["status"] == "failed" and "hung" in run["error"]


def _two_sessions():
    """One participant in each of none and seesys, one object, at most 2.5 s: the settings and the model."""
    cfg = load_simulate_config()
    cfg = dataclasses.replace(
        cfg,
        study=dataclasses.replace(
            cfg.study, participants_per_condition=1, conditions=["none", "seesys"], design="between"
        ),
        task=dataclasses.replace(cfg.task, objects=1, max_task_s=2.5),
    )
    return cfg, default_model(load_service_config(), None)


@pytest.mark.system
def test_a_session_refused_with_a_seesys_error_is_not_retried_and_its_partner_fails_too(tmp_path, monkeypatch):
    """A session of a participant the protocol does not have: its child exits with status 2 (a SEESys error) and
    is not started again although retries are left; the study names the error, and fails the session that waited
    for it without starting it."""
    study = tmp_path / "study"

    def stranger_first(folder, protocol):
        (first, _), total = pending_jobs(folder, protocol)
        stranger = Job(Participant("P09", 9, "seesys"), protocol.phase_folder(folder, "P09", "task", "seesys"))
        return [stranger, dataclasses.replace(first, after=stranger.folder)], total

    monkeypatch.setattr(simulated_study, "pending_jobs", stranger_first)
    cfg, model = _two_sessions()
    assert cfg.study.retries > 0
    outcome = run_study(study, cfg, model)
    assert outcome.done == 0
    assert outcome.failed == [
        "P09 seesys: no participant 'P09' in the protocol (P01, P02)",
        "P01 none: its partner's session failed",
    ]
    assert (study / "logs" / "P09-seesys.log").read_text().count("seesys: error:") == 1
    assert not (study / "participants" / "P09").exists()
    assert not (study / "logs" / "P01-none.log").exists()


@pytest.mark.system
def test_the_motion_calibration_of_a_studys_seesys_sessions_matches_their_pulse_shares(reduced_study, tmp_path):
    """calibrate-motion on the reduced study's two seesys sessions: ascending thresholds whose replayed motion rule
    gives N >= 1 about as often as SEESys did on the same ticks, and a record naming the sessions."""
    out = tmp_path / "calibration.json"
    assert main(["study", "calibrate-motion", str(reduced_study), "--latency-s", "0.03", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    thresholds = record["thresholds_m_s"]
    assert 1 <= len(thresholds) <= 3 and thresholds[0] > 0 and all(a < b for a, b in zip(thresholds, thresholds[1:]))
    assert len(record["sessions"]) == 2 and all("task-seesys" in s for s in record["sessions"])
    assert abs(record["motion_tick_shares"][0] - record["seesys_tick_shares"][0]) <= 0.2
