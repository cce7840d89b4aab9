"""The generator over real ZeroMQ sockets, with no audio: fed by ``seesys advisory replay`` (an estimate log at its
pace), fed garbage, and started on an endpoint that is taken."""

import signal
import subprocess
import time

import numpy as np
import pandas as pd
import zmq

from advisory.process import advisory_command
from audio_fixtures import make_sandbox, wait_started  # noqa: F401
from seesys.protocol.messages import ESTIMATE_TOPIC, Estimate, decode, encode


def test_replay_publishes_estimates_at_their_pace_and_the_generator_follows(make_sandbox):
    sandbox = make_sandbox(None)
    t = np.arange(0, 2, 1 / 30)
    log = sandbox.root / "estimates.csv"
    pd.DataFrame({"timestamp": t + 50.0, "error_m": np.where(t < 1, 0.006, 0.02)}).to_csv(log, index=False)
    sandbox.generator("none")  # silent: needs no audio device
    wait_started(sandbox, "generator")
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, ESTIMATE_TOPIC)
    sub.connect(sandbox.estimates_endpoint)
    received: list[tuple[float, Estimate]] = []
    replay = subprocess.Popen(advisory_command("replay", "--estimates", str(log)), env=sandbox.env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while replay.poll() is None or sub.poll(0):
        if sub.poll(100):
            received.append((time.monotonic(), decode(sub.recv_multipart())))
    out, err = replay.communicate()
    sub.close()
    ctx.term()
    assert replay.returncode == 0, err
    assert f"published {t.size} estimates" in out
    messages = [m for _, m in received]
    assert [m.frame_index for m in messages] == list(range(t.size))
    assert np.allclose([m.timestamp for m in messages], t + 50.0)
    assert {m.device_id for m in messages} == {sandbox.cfg.replay.replay_device_id}
    # Paced, not dumped: the last arrives at least the log's span after the first.
    assert received[-1][0] - received[0][0] >= t[-1] - t[0] - 0.01
    time.sleep(0.4)
    sandbox.stop_all()
    live = sandbox.advisory().query("status == 'live'")
    # 6 mm → 1 pulse; 20 mm → 3, through 2 while the moving average passes 8 mm.
    assert live.n_pulses.iloc[0] == 1 and live.n_pulses.iloc[-1] == 3 and live.n_pulses.is_monotonic_increasing


def test_generator_drops_malformed_messages_and_keeps_going(make_sandbox):
    sandbox = make_sandbox(None)
    sandbox.generator("none")
    wait_started(sandbox, "generator")
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(sandbox.estimates_endpoint)
    time.sleep(0.5)
    good = encode(Estimate("test-device", 0, 0.0, 0.006, "test"))
    for frames in ([ESTIMATE_TOPIC + b"x", b"not a message"], [good[0], good[1][:-3]], good):
        pub.send_multipart(frames)
    time.sleep(0.6)
    pub.close()
    ctx.term()
    sandbox.stop_all()
    bad = sandbox.events().query("event == 'bad message'")
    assert len(bad) == 2 and "not a SEESys message" in bad.detail.iloc[0]
    assert 1 in set(sandbox.advisory().n_pulses)  # the good estimate after the bad ones still counted


def test_generator_on_a_taken_hand_off_endpoint_is_a_clear_error(make_sandbox):
    # TCP: an ipc:// bind takes the socket file over from its owner instead of failing (which is also why a
    # generator restarted after a crash gets its endpoint back).
    ctx = zmq.Context()
    taken = ctx.socket(zmq.PUB)
    port = taken.bind_to_random_port("tcp://127.0.0.1")
    sandbox = make_sandbox(None, endpoint=f"tcp://127.0.0.1:{port}")
    try:
        result = subprocess.run(advisory_command("generator", "--condition", "seesys", "--out",
                                                 str(sandbox.session)), env=sandbox.env, capture_output=True,
                                text=True, timeout=60)
    finally:
        taken.close()
        ctx.term()
    assert result.returncode == 2
    assert "seesys: error: cannot bind the advisory hand-off endpoint" in result.stderr


def test_run_none_starts_only_the_generator_and_needs_no_audio_device(make_sandbox):
    sandbox = make_sandbox(None, output_device="no-such-device")
    run = sandbox.start("run", "--condition", "none", "--out", str(sandbox.session), name="run")
    wait_started(sandbox, "generator")
    run.send_signal(signal.SIGTERM)
    assert run.wait(15) == 0
    processes = set(sandbox.events().process.str.split("[").str[0])
    assert processes == {"supervisor", "generator"}
