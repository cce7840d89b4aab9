"""One per-frame chain: a simulated session's feature stream, served by the estimator service process over ZeroMQ
(its worker's window step), gives the very estimates the simulated study's loop made in-process with the same window
step, each with its frame's predicted translation covariance, and those estimates, through the advice step the
live generator runs, give the session's advisory log buffer for buffer."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from testkit.service import Client, ServiceProcess, ServiceSetup, serve_in_lockstep

from advisory.advice import Advice
from advisory.conditions import Condition, estimate_reading
from advisory.config import load_advisory_config
from estimator.service.broker import default_model
from estimator.service.config import load_service_config
from seesys.core import messages
from seesys.core.messages import Estimate
from seesys.io.rts_log import read_feature_frames
from seesys_app.simulate.config import load_simulate_config
from seesys_app.simulate.session import DEVICE_ID, Participant, simulate_session
from study.sessions import RUN_JSON


@pytest.mark.system
def test_the_service_and_the_simulated_loop_run_one_chain_from_features_to_pulses(tmp_path):
    cfg = load_simulate_config()
    cfg = dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, objects=1, max_task_s=3.0))
    model = default_model(load_service_config(), None)
    session = tmp_path / "session"
    simulate_session(cfg, Participant("P01", 1, "seesys"), session, model)
    made = pd.read_csv(session / "estimates.csv")
    assert len(made) > 5

    # The session's logged feature stream through the service process: the estimates of the same window ends.
    frames = [dataclasses.replace(f, stream_session=7) for f in read_feature_frames(session, DEVICE_ID)]
    setup = ServiceSetup()
    client = Client(setup, [messages.topic(messages.ESTIMATE_TOPIC, DEVICE_ID)])
    service = ServiceProcess(setup, model)
    try:
        service.wait_ready()
        served = serve_in_lockstep(client, frames)
    finally:
        client.close()
        service.kill()
        setup.cleanup()
    by_frame = {e.frame_index: e for e in served}
    assert sorted(by_frame) == made.frame_index.tolist()
    np.testing.assert_allclose([by_frame[i].error_m for i in made.frame_index], made.error_m, rtol=1e-5)
    # each estimate carries its frame's predicted translation covariance (pose_covariance.csv), at the wire's resolution
    logged = {f.frame_index: f.translation_covariance for f in frames}
    for i in made.frame_index:
        assert logged[i] is not None
        np.testing.assert_array_equal(by_frame[i].translation_covariance, messages.covariance_resolution(logged[i]))

    # The served estimates, arriving when the loop's did, through the generator's advice step: the session's buffers.
    advisory_cfg = load_advisory_config()
    start = json.loads((session / RUN_JSON).read_text())["advice_start"]
    advice = Advice(Condition.SEESYS, advisory_cfg, start, cfg.loop.audio_latency_s)
    reading = estimate_reading(advisory_cfg)
    arrivals = dict(zip(made.frame_index, made.receipt_time))
    buffers = []
    for frame in frames:
        estimate = by_frame.get(frame.frame_index)
        if estimate is not None:
            heard = Estimate(DEVICE_ID, estimate.frame_index, frame.timestamp, estimate.error_m, "", head=estimate.head)
            buffers += advice.take(arrivals[frame.frame_index], reading(heard))
        buffers += advice.until(frame.timestamp)
    logged = pd.read_csv(session / "advisory.csv")
    assert len(buffers) == len(logged)
    assert [b.decision.n_pulses for b in buffers] == logged.n_pulses.tolist()
    assert [b.trigger for b in buffers] == logged.trigger.tolist()
    np.testing.assert_allclose([b.decision.time for b in buffers], logged.time_mono, atol=1e-9)
