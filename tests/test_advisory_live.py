"""The two advisory processes on a real sounddevice stream under a JACK dummy server (paced in real time), fed
real Estimate and FeatureFrame messages over real ZeroMQ sockets; the player tees what its callback wrote."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from testkit.audio import (
    Publisher,
    estimate_message,
    pulse_onsets,
    pulses_per_buffer,
    rotation_frame,
    run_lengths,
    wait_started,
    wait_until,
)
from testkit.polling import wait_for

from advisory.player import DEVICE_LOST_EXIT
from advisory.process import advisory_command
from advisory.sandbox import JackDummy
from advisory.scheduler import LIVE, NO_INFORMATION, TICK
from seesys.core.equation2 import error_pulses

pytestmark = pytest.mark.audio


def heard(sandbox, capture="capture.wav", rows=None):
    """The pulse counts of the buffers that played whole, after checking the capture buffer by buffer (each buffer
    starts at its ``playback.csv`` ``stream_sample``; see ``pulses_per_buffer``)."""
    x, rate = sandbox.capture(capture)
    rows = sandbox.playback() if rows is None else rows
    return pulses_per_buffer(x, rate, rows.stream_sample, rows.played_pulses, sandbox.cfg.equation2)


def start_both(sandbox, condition="seesys"):
    player = sandbox.player()
    wait_started(sandbox, "player")
    generator = sandbox.generator(condition)
    wait_started(sandbox, "generator")
    return player, generator


def hold(sandbox, status: str, n: int, count: int = 3) -> None:
    """Keep the current input until the player has started ``count`` tick buffers that the generator made from
    now on with ``status`` and N = ``n`` (what the rule gave). Each step of a test's input lasts as long as the
    logs need, not a fixed time, so a busy machine makes the test slower, never wrong."""
    made = sandbox.advisory()
    after = int(made.buffer_id.max()) if len(made) else -1

    def started() -> int:
        advisory = sandbox.advisory()
        wanted = advisory[
            (advisory.buffer_id > after)
            & (advisory.status == status)
            & (advisory.n_pulses == n)
            & (advisory.trigger == TICK)
        ]
        return int(sandbox.playback().buffer_id.isin(wanted.buffer_id).sum())

    wait_until(lambda: started() >= count, f"{count} {status} tick buffers with N = {n} played")


@pytest.mark.system
def test_pulses_follow_the_estimate_and_go_silent_when_it_stops(jack, make_sandbox):
    sandbox = make_sandbox(jack, stale_after_s=0.6, no_information_cue=False)  # Equation 2 alone (cue: below)
    start_both(sandbox)
    with Publisher(sandbox.estimates_endpoint, estimate_message) as pub:
        for value, status, n in (
            (0.002, LIVE, 0),
            (0.006, LIVE, 1),
            (0.010, LIVE, 2),
            (0.020, LIVE, 3),
            (None, NO_INFORMATION, 0),
            (0.006, LIVE, 1),
        ):
            pub.value = value
            hold(sandbox, status, n)
    sandbox.stop_all()

    sizes = heard(sandbox)
    # N follows Equation 2 on the moving average: nothing at 2 mm, then 1, 2, 3 pulses per buffer; silence while
    # the estimates stop (after the last value stood in for 0.6 s); 1 again when they come back. Of the three
    # tick buffers of a step only the last can be cut short by the change that ends the step.
    assert run_lengths(sizes) == [0, 1, 2, 3, 0, 1], sizes
    assert min(sizes.count(n) for n in (1, 2, 3)) >= 2

    advisory, playback, events = sandbox.advisory(), sandbox.playback(), sandbox.events()
    assert advisory.buffer_id.tolist() == list(range(len(advisory)))  # every buffer logged
    assert set(advisory.condition) == {"seesys"}
    live = advisory[advisory.status == LIVE]
    eq, buffer_s = sandbox.cfg.equation2, sandbox.cfg.timing.buffer_s
    assert live.n_pulses.tolist() == [error_pulses(e, eq, buffer_s) for e in live.input_value]
    assert (advisory[advisory.status == NO_INFORMATION].n_pulses == 0).all()
    changes = list(events[events.event.str.startswith("input")].event)
    changes = changes[changes.index("input live") :]  # before the first estimate it may already be no_information
    assert changes == ["input live", "input no_information", "input live"]
    # The player started every buffer it received within a block of the time it was scheduled for.
    late_ms = (playback.dac_mono - playback.play_at_mono) * 1000
    assert (late_ms.abs() < 1000 * sandbox.cfg.audio.blocksize / sandbox.cfg.audio.sample_rate).mean() > 0.9
    intervals = np.diff(playback.dac_mono)[(playback.trigger.iloc[1:] == TICK).to_numpy()]
    assert np.median(intervals) == pytest.approx(1 / 3, abs=0.001)


@pytest.mark.system
def test_rotation_condition_counts_pulses_from_the_angular_speed(jack, make_sandbox):
    sandbox = make_sandbox(jack)
    start_both(sandbox, "rotation")
    with Publisher(sandbox.features_endpoint, rotation_frame) as pub:
        for speed, n in ((80.0, 0), (120.0, 1), (170.0, 2), (400.0, 3)):
            pub.value = speed
            hold(sandbox, LIVE, n)
    sandbox.stop_all()
    sizes = heard(sandbox)
    assert run_lengths(sizes) == [0, 1, 2, 3], sizes  # 80 °/s: none; 120: 1; 170: 2; 400: capped at 3
    advisory = sandbox.advisory()
    live = advisory[advisory.status == LIVE]
    assert set(advisory.condition) == {"rotation"}
    assert live.input_value.max() == pytest.approx(400.0, rel=1e-3)


@pytest.mark.system
def test_none_condition_is_silent_but_logs_what_it_would_have_played(jack, make_sandbox):
    sandbox = make_sandbox(jack)
    start_both(sandbox, "none")
    with Publisher(sandbox.estimates_endpoint, estimate_message) as pub:
        pub.value = 0.010
        hold(sandbox, LIVE, 2)  # what the rule gives; the buffers played hold no pulse
    sandbox.stop_all()
    x, rate = sandbox.capture()
    playback = sandbox.playback()
    assert x.size > playback.stream_sample.max() and len(pulse_onsets(x, rate)) == 0
    assert set(heard(sandbox)) == {0}
    advisory = sandbox.advisory()
    assert (advisory.played_pulses == 0).all() and (advisory[advisory.status == LIVE].n_pulses == 2).all()
    assert (advisory.status == LIVE).sum() >= 3


@pytest.mark.system
def test_each_process_survives_the_others_restart(jack, make_sandbox):
    sandbox = make_sandbox(jack)
    player, generator = start_both(sandbox)

    def live_rows_since(row: int) -> int:
        return int((sandbox.advisory().iloc[row:].status == LIVE).sum())

    def played_since(row: int) -> int:
        return int((sandbox.playback().iloc[row:].played_pulses == 2).sum())

    with Publisher(sandbox.estimates_endpoint, estimate_message) as pub:
        pub.value = 0.010  # N = 2
        wait_until(lambda: played_since(0) >= 4, "buffers played before the generator is killed")
        generator.kill()  # no goodbye: SIGKILL
        generator.wait()
        killed_mono = time.monotonic()
        # The stimulus is an absence: no generator for longer than the last buffer it sent (scheduled at most
        # schedule_latency_s after the kill) plus a period, so that the player has to go silent.
        timing, audio = sandbox.cfg.timing, sandbox.cfg.audio
        time.sleep(audio.schedule_latency_s + timing.buffer_s + timing.cadence_s)
        rows = len(sandbox.advisory())
        sandbox.generator()
        wait_started(sandbox, "generator", count=2)
        played = len(sandbox.playback())
        wait_until(lambda: played_since(played) >= 4, "buffers of the restarted generator played")
        assert player.poll() is None  # the player lived through the generator's absence
        player.kill()
        player.wait()
        assert live_rows_since(rows) >= 4
        rows = len(sandbox.advisory())
        wait_until(lambda: live_rows_since(rows) >= 3, "the generator going on without a player")
        sandbox.player(capture="capture2.wav", name="player2")
        wait_started(sandbox, "player", count=2)
        played = len(sandbox.playback())
        wait_until(lambda: played_since(played) >= 4, "buffers played by the restarted player")
    sandbox.stop_all()
    playback = sandbox.playback()
    # The second player's rows follow the first's; its stream samples count from 0 again.
    restart = np.flatnonzero(np.diff(playback.stream_sample.to_numpy()) < 0) + 1
    assert len(restart) == 1
    first, second = playback.iloc[: restart[0]], playback.iloc[restart[0] :]
    # While the generator was down the player played only what the last buffer of the killed generator holds, then
    # silence (heard() checks each buffer's stretch up to the next one: a buffer played again would show).
    before, after = first[first.time_mono < killed_mono], first[first.time_mono >= killed_mono]
    assert len(before) >= 4 and len(after) >= 4
    assert after.dac_mono.min() - before.dac_mono.max() > sandbox.cfg.timing.buffer_s
    sizes = heard(sandbox, rows=first)
    assert set(sizes) <= {0, 2} and sizes.count(2) >= 6, sizes
    sizes2 = heard(sandbox, "capture2.wav", rows=second)
    assert set(sizes2) <= {0, 2} and sizes2.count(2) >= 3, sizes2  # the restarted player plays the generator


@pytest.mark.system
def test_supervisor_restarts_a_killed_process_and_stops_cleanly(jack, make_sandbox):
    sandbox = make_sandbox(jack, **{"advisory.restart_delay_s": 0.3})
    run = sandbox.start("run", "--condition", "seesys", "--out", str(sandbox.session), name="run")
    wait_started(sandbox, "player")
    wait_started(sandbox, "generator")
    events = sandbox.events()
    player_pid = int(events[events.process.str.startswith("player[")].process.iloc[0][7:-1])
    os.kill(player_pid, signal.SIGKILL)
    wait_started(sandbox, "player", count=2)
    events = sandbox.events()
    assert "player exited" in set(events.event) and "player restarted" in set(events.event)
    run.send_signal(signal.SIGTERM)
    assert run.wait(15) == 0
    events = sandbox.events()
    stopped = set(events[events.event == "stopped"].process.str.split("[").str[0])
    assert stopped == {"generator", "player", "supervisor"}


@pytest.mark.system
def test_lost_audio_device_is_logged_and_ends_the_player(make_sandbox):
    if not JackDummy.available():
        pytest.skip("jackd is not installed")
    with JackDummy(48000, 256) as server:
        sandbox = make_sandbox(server)
        player = sandbox.player()
        wait_started(sandbox, "player")
    # The server is gone: the stream stops by itself.
    assert player.wait(30) == DEVICE_LOST_EXIT
    events = sandbox.events()
    assert "audio device lost" in set(events.event)


@pytest.mark.system
def test_stalled_audio_server_is_logged_as_a_lost_device(make_sandbox):
    if not JackDummy.available():
        pytest.skip("jackd is not installed")
    with JackDummy(48000, 256) as server:
        sandbox = make_sandbox(server, stall_after_s=0.5)
        player = sandbox.player()
        wait_started(sandbox, "player")
        os.kill(server.pid, signal.SIGSTOP)  # the server stops running cycles; the stream still says active
        try:
            assert player.wait(30) == DEVICE_LOST_EXIT
        finally:
            os.kill(server.pid, signal.SIGCONT)
    lost = sandbox.events().query("event == 'audio device lost'")
    assert len(lost) == 1 and "no callback for" in lost.detail.iloc[0]


@pytest.mark.system
def test_missing_audio_device_is_a_clear_error_at_start(make_sandbox, tmp_path):
    # An ALSA null PCM as the only device (no sound card, no JACK): a named device that does not exist fails at
    # once with a one-line message listing what there is.
    (tmp_path / "alsa").mkdir()
    (tmp_path / "alsa" / "asoundrc").write_text("pcm.!default {\n    type null\n}\n")
    sandbox = make_sandbox(None, output_device="headphones")
    sandbox.env["XDG_CONFIG_HOME"] = str(tmp_path)
    sandbox.env["JACK_DEFAULT_SERVER"] = "no-such-server"
    for args in (
        ["player", "--out", str(sandbox.session)],
        ["run", "--condition", "seesys", "--out", str(sandbox.session)],
    ):
        result = subprocess.run(advisory_command(*args), env=sandbox.env, capture_output=True, text=True, timeout=60)
        assert result.returncode == 2, result.stderr
        assert "seesys: error: audio output device 'headphones' not found" in result.stderr
        assert "'default'" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.system
def test_a_jack_server_does_not_outlive_a_killed_parent():
    """A parent killed with SIGKILL cannot stop its JACK dummy server; the kernel does, so no server keeps one of
    the pool's names (four leaked servers would leave no name for the next run)."""
    if not JackDummy.available():
        pytest.skip("jackd is not installed")
    code = (
        "import time; from advisory.sandbox import JackDummy; server = JackDummy(48000, 256); server.start(); "
        "print(server.pid, flush=True); time.sleep(120)"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    jackd = int(parent.stdout.readline())
    parent.kill()
    parent.wait()

    def gone() -> bool:
        try:
            os.kill(jackd, 0)
        except ProcessLookupError:
            return True
        return False

    wait_for(gone, 30, f"jackd {jackd} to exit after its parent was killed")
