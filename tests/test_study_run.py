"""A complete small study end to end: `seesys study new`, `study run` for one participant per condition on the
embedded sample (real ORB-SLAM3 and RTS monitor, estimates replayed by `seesys advisory replay`, the advisory on
a private JACK dummy server, motioncapture's mock backend), two runs killed with SIGKILL at random moments (one
resumed, one restarted), `study status` and `seesys analyze` (its statistics, which need two or more per condition,
are tested on a study of prepared sessions in test_analysis_study.py).

After each kill: the runner's children die with it, every log parses, the continuously written logs reach to
within a second of the kill, and the next run writes a new attempt without touching the killed one."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest
from testkit.polling import wait_for

from advisory.config import load_advisory_config
from advisory.sandbox import JACK_HOST_API, JackDummy, process_env
from seesys.io.config import write_config_dir
from seesys.io.trajectory_files import read_tum
from study.estimates import read_estimate_log
from study.metrics import read_frame_log
from study.sessions import read_events, read_run

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / "data" / "sample"
FRAMES = 60  # of the sample's 150: enough for 10-frame RPE pairs, little ORB-SLAM3 time
SEED = int(os.environ.get("SEESYS_KILL_SEED", random.SystemRandom().randrange(1 << 30)))

pytestmark = [pytest.mark.slam, pytest.mark.audio]


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    """Configs with private ipc endpoints and the JACK dummy server; the replayed estimate log."""
    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2)")
    root = Path(str(tmp_path_factory.mktemp("s")))
    cfg = load_advisory_config()
    times = [float(line.split()[0]) for line in (SAMPLE / "rgb.txt").read_text().splitlines() if line[:1] != "#"]
    errors = 0.006 + 0.005 * np.sin(np.arange(len(times)) / 8)
    pd.DataFrame({"timestamp": times, "error_m": errors}).to_csv(root / "estimates.csv", index=False)
    with JackDummy(cfg.audio.sample_rate, cfg.audio.blocksize) as jack:
        configs = write_config_dir(
            root / "configs",
            {
                "host_api": JACK_HOST_API,
                "endpoint": f"ipc://{root}/handoff",
                "estimates_endpoint": f"ipc://{root}/estimates",
                "features_endpoint": f"ipc://{root}/features",
            },
        )
        yield root, process_env(configs, jack)


def seesys(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "seesys", *args], capture_output=True, text=True, cwd=REPO, env=env, timeout=600
    )


def start_run(root: Path, env: dict, participant: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
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
            f"tum:{SAMPLE}",
            "--max-frames",
            str(FRAMES),
            "--replay-estimates",
            str(root / "estimates.csv"),
            *extra,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=env,
    )


def frames_logged(attempt: Path) -> int:
    try:
        return len((attempt / "frames.csv").read_text().splitlines()) - 1
    except OSError:
        return 0


def run_with_events(root: Path, env: dict, participant: str, attempt: Path, *extra: str) -> None:
    """A full session: 'initialised' at once, 'object 1' once the device has tracked 20 frames."""
    proc = start_run(root, env, participant, *extra)
    proc.stdin.write("i\n")
    proc.stdin.flush()
    wait_for(lambda: frames_logged(attempt) >= 20 or proc.poll() is not None, 300, "20 frames tracked", interval_s=0.05)
    proc.stdin.write("o\n")
    proc.stdin.flush()
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err[-3000:]
    assert "completed" in out


def described(process: psutil.Process) -> str:
    """A process's command line and what the kernel says of it: its state, the signals it blocks, ignores and
    catches, and where it sleeps."""
    try:
        status = [
            line
            for line in Path(f"/proc/{process.pid}/status").read_text().splitlines()
            if line.startswith(("State", "PPid", "Threads", "SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt"))
        ]
        wchan = Path(f"/proc/{process.pid}/wchan").read_text()
        return f"{process.pid} {process.cmdline()} {'; '.join(status)}; wchan {wchan}"
    except (OSError, psutil.Error) as e:
        return f"{process.pid}: {e}"


def kill_at_random(
    root: Path, env: dict, participant: str, attempt: Path, rng: random.Random, during_tracking: bool
) -> float:
    """SIGKILL the runner at a random moment (of its start-up, or while the device tracks); returns the time."""
    proc = start_run(root, env, participant)
    proc.stdin.write("i\nn before the kill\n")
    proc.stdin.flush()
    if during_tracking:
        wait_for(lambda: frames_logged(attempt) >= 5, 300, "5 frames tracked", interval_s=0.05)
        time.sleep(rng.uniform(0.0, 1.5))
    else:
        # Start-up: at the drawn moment or when the device logs its first frame, whichever comes first (the whole
        # session can be over within the drawn 8 s, and a runner killed after it completed leaves a finished run).
        deadline = time.monotonic() + rng.uniform(0.3, 8.0)
        wait_for(
            lambda: time.monotonic() >= deadline or frames_logged(attempt) >= 1,
            300,
            "the drawn moment or the first frame",
            interval_s=0.02,
        )
    children = psutil.Process(proc.pid).children(recursive=True)
    killed_at = time.time()
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    _, alive = psutil.wait_procs(children, timeout=60)
    assert not alive, "children outlived the killed runner:\n" + "\n".join(map(described, alive))
    return killed_at


def check_killed_attempt(attempt: Path, killed_at: float) -> None:
    """Every log parses; those written continuously reach to within a second of the kill. A runner killed
    before it made its attempt folder (Python still starting) leaves nothing to check."""
    if not attempt.exists():
        return
    if (attempt / "run.json").exists():
        assert json.loads((attempt / "run.json").read_text())["status"] == "running"  # read as incomplete
    assert read_run(attempt)["status"] == "incomplete"
    events = read_events(attempt)
    assert events.empty or events.kind.iloc[0] == "start"
    if (attempt / "frames.csv").exists():
        read_frame_log(attempt / "frames.csv")
        read_tum(attempt / "trajectory.tum")
        json.loads((attempt / "session.json").read_text())
    read_estimate_log(attempt)
    mocap = attempt / "mocap.tum"
    if mocap.exists() and len(read_tum(mocap)) and read_tum(mocap).timestamps[0] < killed_at - 1.0:
        assert read_tum(mocap).timestamps[-1] >= killed_at - 1.0
    advisory = attempt / "advisory.csv"
    if advisory.exists():
        rows = pd.read_csv(advisory)
        if len(rows) and rows.wall_time.iloc[0] < killed_at - 1.0:
            assert rows.wall_time.iloc[-1] >= killed_at - 1.0


@pytest.mark.system
def test_study_end_to_end_with_kills(sandbox):
    root, env = sandbox
    rng = random.Random(SEED)
    print(f"kill seed {SEED} (SEESYS_KILL_SEED reproduces it)")
    done = seesys(env, "study", "new", str(root / "study"), "--per-condition", "1")
    assert done.returncode == 0, done.stderr
    protocol = json.loads((root / "study" / "protocol.json").read_text())
    people = [p["id"] for p in protocol["participants"]]

    def task(p: str, n: int) -> Path:
        return root / "study" / "participants" / p / "task" / f"attempt-{n}"

    # P01: killed during start-up or tracking, then resumed: both attempts count.
    killed = kill_at_random(root, env, people[0], task(people[0], 1), rng, during_tracking=rng.random() < 0.5)
    check_killed_attempt(task(people[0], 1), killed)
    resumed = 2 if task(people[0], 1).exists() else 1
    before = {p.name: p.stat().st_size for p in task(people[0], 1).glob("*") if p.is_file()}
    run_with_events(root, env, people[0], task(people[0], resumed))
    assert {p.name: p.stat().st_size for p in task(people[0], 1).glob("*") if p.is_file()} == before or resumed == 1

    # P02: killed while tracking, then restarted: the killed attempt is kept but superseded.
    killed = kill_at_random(root, env, people[1], task(people[1], 1), rng, during_tracking=True)
    check_killed_attempt(task(people[1], 1), killed)
    run_with_events(root, env, people[1], task(people[1], 2), "--restart")
    assert json.loads((task(people[1], 1) / "run.json").read_text())["superseded"] is True

    for p in people[2:]:
        run_with_events(root, env, p, task(p, 1))
    again = seesys(env, "study", "run", str(root / "study"), "--participant", people[2], "--phase", "task")
    assert again.returncode == 2 and "--restart" in again.stderr  # a done phase is not silently re-recorded

    status = seesys(env, "study", "status", str(root / "study"))
    assert status.returncode == 0 and "task: 3 done" in status.stdout

    attempt = task(people[2], 1)
    assert len(read_estimate_log(attempt)) > 10  # the replay sends from the device's first frame, ready before it
    assert len(pd.read_csv(attempt / "replay_sent.csv")) >= len(read_estimate_log(attempt))
    assert len(read_tum(attempt / "mocap.tum")) > 10
    assert set(read_events(attempt).kind) >= {"start", "initialised", "object", "stop"}
    assert len(pd.read_csv(attempt / "advisory.csv")) > 0
    labelled = seesys(env, "dataset", "label", str(attempt), "--out", str(root / "labels.csv"))
    assert labelled.returncode == 0, labelled.stderr  # a study session is a labelled session like any other
    assert (pd.read_csv(root / "labels.csv").status == "labelled").sum() > FRAMES / 2

    analysis = seesys(env, "analyze", str(root / "study"))
    assert analysis.returncode == 0, analysis.stderr
    out = root / "study" / "analysis"
    table = pd.read_csv(out / "participants.csv")
    assert table.status.tolist() == ["done"] * 3
    assert table.loc[table.participant == people[0], "attempts"].item() == resumed
    assert table.rpe_mean_m.between(0, 0.05).all() and table.completeness.gt(0.5).all()
    report = (out / "report.md").read_text()
    for heading in (
        "No audio",
        "Audio (Rotation)",
        "Audio (SEESys)",
        "Tracking error (cm)",
        "Tracking completeness (%)",
        "(n = 1)",
        "fewer than two conditions with two or more",
    ):
        assert heading in report
    assert (out / "report.html").exists() and (out / "figures" / "trajectories_seesys.png").exists()
