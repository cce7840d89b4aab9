"""The generator over real ZeroMQ sockets, with no audio: fed by ``seesys advisory replay`` (an estimate log at its
pace), fed garbage, and started on an endpoint that is taken."""

import itertools
import signal
import subprocess

import numpy as np
import pandas as pd
import pytest
import zmq
from testkit.audio import wait_started, wait_until

from advisory.process import advisory_command
from seesys.core.messages import ESTIMATE_TOPIC, Estimate, decode, encode
from seesys.io.transport import open_socket, subscriber


def live_rows(sandbox) -> pd.DataFrame:
    return sandbox.advisory().query("status == 'live'")


def replay_and_receive(sandbox, log, sent_log) -> tuple[list[Estimate], str]:
    """Run ``seesys advisory replay`` on ``log`` to its end; the estimates a subscriber received, and its output."""
    ctx = zmq.Context()
    sub = subscriber(ctx, sandbox.estimates_endpoint, "test estimates", [ESTIMATE_TOPIC])
    received: list[Estimate] = []
    replay = subprocess.Popen(
        advisory_command("replay", "--estimates", str(log), "--sent-log", str(sent_log)),
        env=sandbox.env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    while replay.poll() is None or sub.poll(0):
        if sub.poll(100):
            received.append(decode(sub.recv_multipart()))
    out, err = replay.communicate()
    sub.close()
    ctx.term()
    assert replay.returncode == 0, err
    return received, out


@pytest.mark.system
def test_replay_publishes_estimates_at_their_pace_and_the_generator_follows(make_sandbox):
    sandbox = make_sandbox(None)
    t = np.arange(0, 2, 1 / 30)
    errors = np.where(t < 1, 0.006, 0.02)
    log, sent_log = sandbox.root / "estimates.csv", sandbox.root / "sent.csv"
    pd.DataFrame({"timestamp": t + 50.0, "error_m": errors}).to_csv(log, index=False)
    sandbox.generator("none")  # silent: needs no audio device
    wait_started(sandbox, "generator")
    received, out = replay_and_receive(sandbox, log, sent_log)
    assert f"published {t.size} estimates" in out
    # All arrived, in order, as they were in the log.
    assert [m.frame_index for m in received] == list(range(t.size))
    assert np.allclose([m.timestamp for m in received], t + 50.0)
    assert np.allclose([m.error_m for m in received], errors)
    assert {m.device_id for m in received} == {sandbox.cfg.replay.replay_device_id}
    # Paced, not dumped: by the replay's own clock, no estimate went out before its time after the first.
    sent = pd.read_csv(sent_log)
    assert sent.frame_index.tolist() == list(range(t.size))
    assert np.array_equal(sent.timestamp.to_numpy(), t + 50.0)
    ahead_s = (sent.timestamp - sent.timestamp[0]) - (sent.sent_mono - sent.sent_mono[0])
    assert ahead_s.max() <= 1e-6, sent[ahead_s > 1e-6]
    assert sent.sent_mono.is_monotonic_increasing
    # 6 mm → 1 pulse; 20 mm → 3, through 2 while the moving average passes 8 mm.
    wait_until(lambda: (live_rows(sandbox).n_pulses == 3).any(), "the generator logging N = 3")
    sandbox.stop_all()
    live = live_rows(sandbox)
    assert live.n_pulses.iloc[0] == 1 and live.n_pulses.iloc[-1] == 3 and live.n_pulses.is_monotonic_increasing


@pytest.mark.system
def test_replay_refuses_a_sent_log_it_cannot_write(make_sandbox, tmp_path):
    sandbox = make_sandbox(None)
    log = sandbox.root / "estimates.csv"
    pd.DataFrame({"timestamp": [0.0, 0.1], "error_m": [0.006, 0.006]}).to_csv(log, index=False)
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    result = subprocess.run(
        advisory_command("replay", "--estimates", str(log), "--sent-log", str(blocker / "sent.csv")),
        env=sandbox.env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert f"seesys: error: cannot write the log {blocker / 'sent.csv'}" in result.stderr


def silent_generator_fed_by_this_test(make_sandbox):
    """A ``none`` generator and the estimates socket it listens to, once it has subscribed: (sandbox, ctx, pub)."""
    sandbox = make_sandbox(None)
    sandbox.generator("none")
    wait_started(sandbox, "generator")
    ctx = zmq.Context()
    # XPUB: a PUB that also reports subscriptions, so the test sends once the generator has subscribed.
    pub = open_socket(ctx, zmq.XPUB, sandbox.estimates_endpoint, "test estimates", bind=True)
    assert pub.poll(30_000), "the generator never subscribed to the estimates"
    assert pub.recv() == b"\x01" + ESTIMATE_TOPIC
    return sandbox, ctx, pub


@pytest.mark.system
def test_generator_drops_malformed_messages_and_keeps_going(make_sandbox):
    sandbox, ctx, pub = silent_generator_fed_by_this_test(make_sandbox)
    good = encode(Estimate("test-device", 0, 0.0, 0.006, "test"))
    for frames in ([ESTIMATE_TOPIC + b"x", b"not a message"], [good[0], good[1][:-3]], good):
        pub.send_multipart(frames)
    wait_until(lambda: (live_rows(sandbox).n_pulses == 1).any(), "the good estimate to reach the generator")
    pub.close()
    ctx.term()
    sandbox.stop_all()
    bad = sandbox.events().query("event == 'bad message'")
    assert len(bad) == 2 and "not a SEESys message" in bad.detail.iloc[0]


@pytest.mark.system
def test_generator_on_a_taken_hand_off_endpoint_is_a_clear_error(make_sandbox):
    # TCP: an ipc:// bind takes the socket file over from its owner instead of failing (which is also why a
    # generator restarted after a crash gets its endpoint back).
    ctx = zmq.Context()
    taken = ctx.socket(zmq.PUB)
    port = taken.bind_to_random_port("tcp://127.0.0.1")
    sandbox = make_sandbox(None, endpoint=f"tcp://127.0.0.1:{port}")
    try:
        result = subprocess.run(
            advisory_command("generator", "--condition", "seesys", "--out", str(sandbox.session)),
            env=sandbox.env,
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        taken.close()
        ctx.term()
    assert result.returncode == 2
    assert "seesys: error: cannot bind the advisory hand-off endpoint" in result.stderr


@pytest.mark.system
def test_run_none_starts_only_the_generator_and_needs_no_audio_device(make_sandbox):
    sandbox = make_sandbox(None, output_device="no-such-device")
    run = sandbox.start("run", "--condition", "none", "--out", str(sandbox.session), name="run")
    wait_started(sandbox, "generator")
    run.send_signal(signal.SIGTERM)
    assert run.wait(15) == 0
    processes = set(sandbox.events().process.str.split("[").str[0])
    assert processes == {"supervisor", "generator"}


@pytest.mark.system
def test_replay_sends_the_logged_frame_index_and_head(make_sandbox):
    sandbox = make_sandbox(None)
    t = np.arange(0, 0.5, 1 / 30)
    frames = 40 + 3 * np.arange(t.size)  # a device's estimates: every third frame, from frame 40
    log, sent_log = sandbox.root / "estimates.csv", sandbox.root / "sent.csv"
    pd.DataFrame(
        {"frame_index": frames, "timestamp": t + 50.0, "error_m": 0.006, "p_ge_0.004": 0.75, "p_ge_0.008": 0.25}
    ).to_csv(log, index=False)
    received, _ = replay_and_receive(sandbox, log, sent_log)
    assert [m.frame_index for m in received] == frames.tolist()
    # the log's head travels with every estimate, each probability with its threshold
    assert {tuple((h.threshold_m, h.probability) for h in m.head) for m in received} == {
        ((float(np.float32(0.004)), 0.75), (float(np.float32(0.008)), 0.25))
    }
    assert pd.read_csv(sent_log).frame_index.tolist() == frames.tolist()


@pytest.mark.system
def test_the_generator_plays_the_heads_class_when_estimates_carry_it_and_logs_which_rule(make_sandbox):
    """6 mm estimates (Equation 2: 1 pulse) whose head says ≥ 12 mm are logged with 3 pulses from the head; the
    same estimates without a head go back to Equation 2 of the estimate."""
    from seesys.core.messages import Exceedance

    sandbox, ctx, pub = silent_generator_fed_by_this_test(make_sandbox)
    head = tuple(Exceedance(t, 0.9) for t in (0.004, 0.008, 0.012))
    for k in range(10):
        pub.send_multipart(encode(Estimate("test-device", k, k / 30, 0.006, "test", head=head)))
    wait_until(lambda: (live_rows(sandbox).pulses_from == "head").any(), "a buffer from the head")
    frames = itertools.count(10)

    def estimate_rule_heard() -> bool:
        """Send the next estimate without a head (one per poll keeps the input fresh) and look for its buffer."""
        k = next(frames)
        pub.send_multipart(encode(Estimate("test-device", k, k / 30, 0.006, "test")))
        return (live_rows(sandbox).pulses_from == "estimate").any()

    wait_until(estimate_rule_heard, "a buffer from the estimate")
    pub.close()
    ctx.term()
    sandbox.stop_all()
    live = live_rows(sandbox)
    assert set(live[live.pulses_from == "head"].n_pulses) == {3}
    assert set(live[live.pulses_from == "estimate"].n_pulses) == {1}
    assert list(dict.fromkeys(live.pulses_from)) == ["head", "estimate"]
