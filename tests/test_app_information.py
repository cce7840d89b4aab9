"""`seesys run` never sounds "all well" when it knows nothing, and stops when told: real ORB-SLAM3, the shipped
model in a local estimator, the advisory into a JACK dummy server (`--wav`), with stdout not a terminal.

- The estimator is killed with SIGKILL once estimates come, and not restarted (its restart delay is an hour): the
  advisory plays its "no information" cue, decoded from the WAV, and the run ends `degraded` with the seconds
  without information under "estimator restarting".
- SIGINT to `seesys run` mid-run: the device worker ends, `session.json` says `interrupted` and
  `monitor_stats.json` is written, the device's end recorded within 2 s of the app's.
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

import pandas as pd
import pytest
from testkit.audio import cue_tones
from testkit.polling import wait_for
from testkit.sample import REPO, stretched_sample

from advisory.config import load_advisory_config
from advisory.sandbox import JackDummy
from advisory.wav import read_wav
from estimator.service.sandbox import private_configs
from seesys.io.config import CONFIG_DIR_ENV

pytestmark = [pytest.mark.slam, pytest.mark.audio]


def _rows(path: Path) -> pd.DataFrame:
    try:
        return pd.read_csv(path)
    except (OSError, pd.errors.EmptyDataError):
        return pd.DataFrame()


STARTED: list[subprocess.Popen] = []


@pytest.fixture
def root():
    """A short temporary folder (ipc paths are at most 107 bytes); the app a test started is killed after it if it
    is still running (a failed test)."""
    if not JackDummy.available():
        pytest.skip("jackd is not installed (apt package jackd2)")
    folder = Path(tempfile.mkdtemp(prefix="sinf", dir="/tmp"))
    yield folder
    while STARTED:
        app = STARTED.pop()
        if app.poll() is None:
            app.kill()
            app.wait()
    shutil.rmtree(folder, ignore_errors=True)


def start_app(
    root: Path, stretch: int, restart_delay_s: float | None = None, **overrides: object
) -> tuple[subprocess.Popen, Path, Path]:
    if restart_delay_s is not None:  # the app's own (advisory.toml has a key of the same name)
        overrides["app.restart_delay_s"] = restart_delay_s
    config_dir, _ = private_configs(root, endpoint=f"ipc://{root}/handoff", stale_after_ms=60000.0, **overrides)
    out = root / "session"
    command = [
        sys.executable,
        "-m",
        "seesys",
        "run",
        "--source",
        f"tum:{stretched_sample(root / 'source', stretch)}",
        "--local",
        "--condition",
        "seesys",
        "--out",
        str(out),
        "--wav",
    ]
    log = (root / "app.log").open("w")
    app = subprocess.Popen(
        command, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, CONFIG_DIR_ENV: str(config_dir)}
    )
    STARTED.append(app)
    return app, out, config_dir


@pytest.mark.system
def test_a_killed_estimator_plays_the_no_information_cue_and_the_run_ends_degraded(root):
    app, out, config_dir = start_app(root, 3, restart_delay_s=3600.0, cue_every_s=1.0)
    wait_for(lambda: len(_rows(out / "estimates.csv")) >= 1 or app.poll() is not None, 300, "an estimate")
    started = _rows(out / "app_events.csv").query("part == 'estimator' and event == 'started'")
    os.kill(int(started.detail.iloc[0].split()[1]), signal.SIGKILL)
    assert app.wait(300) == 3, (root / "app.log").read_text()[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "degraded", summary
    assert summary["information"]["seconds_without"] > 0, summary
    assert summary["information"]["by_reason"].get("estimator restarting", 0) > 0, summary["information"]
    last = (root / "app.log").read_text().strip().splitlines()[-1]
    assert last.startswith("degraded (") and "estimator restarting" in last, last
    cfg = load_advisory_config(config_dir)
    advisory, playback = _rows(out / "advisory.csv"), _rows(out / "playback.csv")
    cues = advisory[advisory.trigger == "cue"]
    assert len(cues) >= 2 and (cues.status == "no_information").all(), (cues, _rows(out / "frames.csv").tail(3))
    assert (cues.time_mono.diff().dropna() >= cfg.no_information.cue_every_s - 1e-6).all(), cues
    # The WAV holds the cue's two tones where the player played each cue buffer, and nowhere else. A buffer starts
    # at its play_at and replaces the one playing, so a cue may be cut short, and then only its first tone need be
    # heard: by the stream's end; by a buffer off the cadence, which starts at once (the first estimate, arriving
    # during a cue); by the next buffer on time when the cue itself started late (a starved machine); and in the WAV
    # only, when the audio server skipped cycles (the capture holds what the callback wrote, and playback.csv's DAC
    # times the timeline). A cue that started on time is never cut by a buffer on the cadence.
    samples, rate = read_wav(out / "advisory.wav")
    heard = cue_tones(samples, rate, cfg.no_information)
    starts = sorted(playback.stream_sample.astype(int).tolist()) + [len(samples)]
    played = playback[playback.trigger == "cue"].stream_sample.astype(int).tolist()
    cue = cfg.no_information
    gap = int(round((cue.cue_tone_s + cue.cue_gap_s) * rate))
    end_of = {start: min(s for s in starts if s > start) for start in played}
    tolerance = rate // 100
    tone_length = int(cue.cue_tone_s * rate)
    whole = [start for start in played if start + gap + tone_length <= end_of[start]]
    assert len(whole) >= 2, (len(samples), played, end_of)
    rows = playback.sort_values("stream_sample").reset_index(drop=True)
    cadence_s, cue_s, slack_s = cfg.timing.cadence_s, 2 * cue.cue_tone_s + cue.cue_gap_s, tolerance / rate
    assert (rows.dac_mono >= rows.play_at_mono - slack_s).all(), rows  # no buffer starts before its time
    for i in rows.index[(rows.trigger == "cue") & ~rows.stream_sample.astype(int).isin(whole)]:
        if i + 1 == len(rows):
            continue  # the last buffer: the stream stopped
        this, after = rows.iloc[i], rows.iloc[i + 1]
        skipped = (after.dac_mono - this.dac_mono) - (after.stream_sample - this.stream_sample) / rate > slack_s
        late = this.dac_mono - this.play_at_mono > cadence_s - cue_s - slack_s
        off_cadence = this.play_at_mono + cadence_s - after.play_at_mono > slack_s
        assert skipped or late or off_cadence, rows.iloc[i : i + 2].to_dict("records")
    for start in played:
        for tone in (start, start + gap):
            if tone + tone_length <= end_of[start]:
                assert any(abs(h - tone) <= tolerance for h in heard), (tone, heard, played, end_of)
    for h in heard:
        assert any(abs(h - s) <= tolerance or abs(h - s - gap) <= tolerance for s in played), (h, played)


@pytest.mark.system
def test_sigint_ends_the_device_with_its_files_final(root):
    app, out, _ = start_app(root, 6)
    wait_for(lambda: len(_rows(out / "frames.csv")) >= 20 or app.poll() is not None, 300, "20 frames tracked")
    app.send_signal(signal.SIGINT)
    assert app.wait(120) == 130, (root / "app.log").read_text()[-3000:]
    manifest = json.loads((out / "session.json").read_text())
    assert manifest["status"] == "interrupted", manifest
    assert (out / "monitor_stats.json").is_file()
    events = _rows(out / "app_events.csv")
    interrupted = float(events.query("event == 'interrupted'").wall_time.iloc[0])
    device_end = datetime.fromisoformat(manifest["end_time"]).timestamp()
    assert device_end - interrupted < 2.0, (device_end - interrupted, manifest)
    assert events.query("part == 'app' and event == 'stopped'").detail.iloc[0] == "interrupted"
    # Until the first estimate the status lines say there is none (the advisory plays its cue meanwhile).
    lines = [line for line in (root / "app.log").read_text().splitlines() if "| information " in line]
    before = [line for line in lines if "| estimate – |" in line]
    assert before and all("information NONE: " in line for line in before), before[:3]
