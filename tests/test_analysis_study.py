"""``seesys analyze STUDY_DIR`` on a study folder whose sessions are made from a real ground-truth trajectory
(TUM fr1/xyz) with condition-dependent noise: participants' metrics, the incomplete and superseded attempts,
the report, figures and tidy tables. (The end-to-end test with ORB-SLAM3 is in test_study_run.py.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum, write_tum
from study.config import load_study_config
from study.protocol import make_protocol, write_protocol
from study.sessions import EVENTS_HEADER

REPO = Path(__file__).resolve().parent.parent
TRUTH = Path(__file__).parent / "data" / "trajectories" / "freiburg1_xyz-groundtruth.txt"
NOISE_M = {"none": 0.004, "rotation": 0.002, "seesys": 0.001}


def fake_attempt(
    folder: Path, noise_m: float, rng, status: str = "completed", pid: int = 0, superseded: bool = False
) -> None:
    """A session folder like `seesys study run` leaves: SLAM poses = truth + noise, a lost stretch, logs."""
    truth = read_tum(TRUTH)
    truth = truth.take(truth.timestamps < truth.timestamps[0] + 12)
    folder.mkdir(parents=True)
    write_tum(folder / "groundtruth.tum", truth)
    frames_t = np.arange(truth.timestamps[0] + 0.05, truth.timestamps[-1] - 0.05, 1 / 30)
    states = np.where(
        (np.arange(len(frames_t)) > 100) & (np.arange(len(frames_t)) < 100 + rng.integers(5, 40)), "LOST", "OK"
    ).astype(object)
    states[:5] = "NOT_INITIALIZED"
    pd.DataFrame(
        {
            "frame_index": np.arange(len(frames_t)),
            "timestamp": frames_t,
            "state": states,
            "tracked_points": 100,
            "track_ms": 20.0,
        }
    ).to_csv(folder / "frames.csv", index=False)
    tracked = frames_t[states == "OK"]
    idx = np.searchsorted(truth.timestamps, tracked).clip(0, len(truth) - 1)
    rot = truth.rotations[idx] * Rotation.from_rotvec(rng.normal(0, 0.002, (len(idx), 3)))
    write_tum(
        folder / "trajectory.tum",
        Poses.from_rotations(tracked, truth.positions[idx] + rng.normal(0, noise_m, (len(idx), 3)), rot),
    )
    wall = 1.8e9
    pd.DataFrame(
        {
            "receipt_time": wall + tracked - tracked[0],
            "device_id": "d",
            "frame_index": 0,
            "timestamp": tracked,
            "error_m": noise_m * 2,
            "model_version": "m",
        }
    ).to_csv(folder / "estimates.csv", index=False)
    pd.DataFrame({"wall_time": wall + np.arange(0, 10, 1 / 3), "n_pulses": rng.integers(0, 3, 30)}).to_csv(
        folder / "advisory.csv", index=False
    )
    (folder / "events.csv").write_text(
        f"{EVENTS_HEADER}\n{wall + 0.2},initialised,\n{wall + 6.0},object,1\n{wall + 9.0},object,2\n{wall + 9.5},no"
    )  # a row cut short by a kill
    (folder / "run.json").write_text(json.dumps({"status": status, "pid": pid, "superseded": superseded}))


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("study") / "s"
    protocol = make_protocol(load_study_config().protocol, participants_per_condition=3)
    write_protocol(root, protocol)
    rng = np.random.default_rng(11)
    for i, p in enumerate(protocol.participants):
        task = protocol.phase_folder(root, p.id, "task", p.conditions[0])
        if i == 0:
            continue  # pending: never ran
        if i == 1:  # killed while running (the pid is no process), then resumed
            fake_attempt(task / "attempt-1", NOISE_M[p.conditions[0]], rng, status="running", pid=2**22 + 7)
        if i == 2:  # restarted: the first attempt is kept on disk but superseded
            fake_attempt(task / "attempt-1", 0.5, rng, superseded=True)
        fake_attempt(task / f"attempt-{2 if i in (1, 2) else 1}", NOISE_M[p.conditions[0]], rng)
    done = subprocess.run(
        [sys.executable, "-m", "seesys", "analyze", str(root)], capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return root, protocol


@pytest.mark.system
def test_participants_table(study):
    root, protocol = study
    table = pd.read_csv(root / "analysis" / "participants.csv")
    assert list(table.participant) == [p.id for p in protocol.participants]
    assert table.status.tolist()[:3] == ["pending", "done", "done"]
    assert table.attempts.tolist()[:3] == [0, 2, 1]
    assert np.isnan(table.rpe_mean_m.iloc[0])
    # the superseded attempt's 0.5 m noise is not in participant 3's error
    assert table.rpe_mean_m.iloc[2] < 0.05
    means = table.groupby("condition").rpe_mean_m.mean()
    assert means["none"] > means["rotation"] > means["seesys"]
    assert table.completeness.between(0.8, 1.0).iloc[1:].all()
    # from 'initialised' to the last 'object' of each attempt (the row cut short by the kill is dropped); summed
    assert table.time_on_task_s.iloc[1] == pytest.approx(2 * 8.8)
    assert table.time_on_task_s.iloc[2:].to_numpy() == pytest.approx(8.8)


@pytest.mark.system
def test_report_and_figures(study):
    root, _ = study
    out = root / "analysis"
    report = (out / "report.md").read_text()
    assert "No audio" in report and "Audio (SEESys)" in report and "Tracking error (cm)" in report
    assert "Kruskal-Wallis" in report and "Games-Howell" in report
    for name in ("box_rpe_mean_m.png", "trajectories_seesys.png", "error_over_time_none.png"):
        assert (out / "figures" / name).stat().st_size > 5000
    assert "figures/trajectories_seesys.png" in (out / "report.html").read_text()
    pairs = pd.read_csv(out / "rpe_pairs.csv")
    assert set(pairs.condition) == set(NOISE_M)
    for name in ("descriptives.csv", "assumptions.csv", "tests.csv", "posthoc.csv"):
        assert len(pd.read_csv(out / name)) > 0


def test_a_study_without_data_leaves_no_analysis_folder(tmp_path):
    from analysis.config import load_analysis_config
    from analysis.report import analyse_study
    from seesys.core.errors import SeesysError

    root = tmp_path / "s"
    write_protocol(root, make_protocol(load_study_config().protocol, participants_per_condition=1))
    with pytest.raises(SeesysError, match="no participant has a trajectory"):
        analyse_study(root, None, load_analysis_config(), load_study_config().metrics)
    assert not (root / "analysis").exists()


@pytest.mark.system
def test_one_participant_per_condition_prints_no_nan(tmp_path):
    table = tmp_path / "participants.csv"
    pd.DataFrame({"participant": ["p1", "p2"], "condition": ["none", "seesys"], "rpe_mean_m": [0.02, 0.01]}).to_csv(
        table, index=False
    )
    done = subprocess.run(
        [sys.executable, "-m", "seesys", "analyze", "--table", str(table), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "none 2.00 ± – (n=1)" in done.stdout and "nan" not in done.stdout, done.stdout
