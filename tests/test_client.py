"""The estimate client and its example, against a real ``seesys estimator serve`` fed the sample's feature stream."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from testkit.polling import wait_for
from testkit.sample import SAMPLE, run_seesys
from testkit.service import Client, ServiceProcess, ServiceSetup, serve_in_lockstep

from estimator.service.simulate import looped
from seesys.client import EstimateClient
from seesys.core import messages
from seesys.core.messages import Estimate
from seesys.io.config import CONFIG_DIR_ENV, write_config_dir
from seesys.io.resources import resolve
from seesys.io.rts_log import read_feature_frames

REPO = Path(__file__).resolve().parents[1]
DEVICE = "anchor-device"


def test_the_client_yields_typed_records_with_equation2_classes_and_skips_what_it_cannot_decode(tmp_path):
    import zmq

    endpoint = f"ipc://{tmp_path}/estimates"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(endpoint)
    try:
        with EstimateClient(DEVICE, endpoint=endpoint, stream_session=5) as client:
            # a PUB drops what it sends before the subscription arrives: send until the first record comes through
            wait_for(
                lambda: (
                    pub.send_multipart(messages.encode(Estimate(DEVICE, 1, 10.0, 0.001, "m1", 2.0, 5)))
                    or client.receive(0.05)
                ),
                what="the first estimate",
            )
            pub.send_multipart([messages.topic(messages.ESTIMATE_TOPIC, DEVICE), b"garbage"])
            pub.send_multipart(messages.encode(Estimate("other-device", 5, 10.1, 0.5, "m1", 2.0, 5)))
            pub.send_multipart(messages.encode(Estimate(DEVICE, 6, 10.1, 0.5, "m1", 2.0, 6)))  # another stream session
            covariance = np.diag([4e-6, 1e-6, 9e-6])
            pub.send_multipart(messages.encode(Estimate(DEVICE, 7, 10.2, 0.009, "m1", 3.5, 5, (), covariance)))
            record = client.receive(60)
            np.testing.assert_allclose(record.translation_covariance, covariance, rtol=1e-3)
            assert (record.device_id, record.frame_index, record.timestamp, record.error_m) == (DEVICE, 7, 10.2, 0.009)
            assert (record.error_class, record.model_version, record.server_ms) == (2, "m1", 3.5)  # 250/m * 9 mm
            assert record.stream_session == 5 and client.foreign == 1
            assert 0 <= record.age_s < 60 and client.rejected == 1
            assert record.scaled_translation_covariance is None  # no estimate of frame 7 − Δ
            first = record.translation_covariance
            # Frame 17's label pair starts at frame 7, whose estimate came: the covariance scaled to the estimate.
            assert client.delta_frames == 10
            later = np.diag([1e-6, 2e-6, 2e-6])
            pub.send_multipart(messages.encode(Estimate(DEVICE, 17, 10.5, 0.006, "m1", 3.5, 5, (), later)))
            record = client.receive(60)
            stream_later = record.translation_covariance  # float16's resolution, as the stream carries it
            pair = first + stream_later
            np.testing.assert_allclose(record.scaled_translation_covariance, stream_later * 0.006**2 / np.trace(pair))
            assert np.trace(record.scaled_translation_covariance) < 0.006**2  # the pair's σ is the estimate
            assert client.receive(0.05) is None
    finally:
        pub.close()
        ctx.term()


def lines(path):
    return path.read_text().splitlines() if path.exists() else []


@pytest.mark.slam
@pytest.mark.system
def test_the_anchor_placer_defers_while_the_class_is_high_and_survives_a_service_restart(tmp_path):
    session = tmp_path / "session"
    result = run_seesys("monitor", "run", "--source", f"tum:{SAMPLE}", "--mode", "rgbd", "--out", str(session))
    assert result.returncode == 0, result.stderr
    frames = list(read_feature_frames(session, DEVICE))
    model = resolve("data/models/deepsee.onnx")
    setup = ServiceSetup()
    service = example = None
    client = Client(setup, [messages.topic(messages.ESTIMATE_TOPIC, DEVICE)])
    try:
        service = ServiceProcess(setup, model)
        service.wait_ready()
        first = {e.frame_index: e.error_m for e in serve_in_lockstep(client, frames)}
        errors = sorted(first.values())
        assert len(set(errors)) >= 2, errors
        # Equation 2 with thresholds between the sample's estimates: class 0 below the middle, 3 from it up.
        threshold = (errors[len(errors) // 2 - 1] + errors[len(errors) // 2]) / 2
        low = sum(e < threshold for e in errors)
        configs = write_config_dir(
            tmp_path / "example-configs",
            {
                "estimates_endpoint": setup.endpoints["estimates"],
                "alpha_m": threshold / 2,
                "beta_m": threshold,
                "pulses_per_metre": 1 / threshold,
            },
        )
        service.stop(signal.SIGKILL)

        # The example starts while no service runs, and must get its estimates from the restarted one. It wants
        # one anchor more than a pass has good estimates, so it sees the bad ones of a pass before it is done.
        output = tmp_path / "example.out"
        with open(output, "w") as out:
            example = subprocess.Popen(
                [
                    sys.executable,
                    str(REPO / "examples" / "anchor_placer.py"),
                    "--device",
                    DEVICE,
                    "--anchors",
                    str(low + 1),
                    "--max-age-s",
                    "60",
                ],
                env={**os.environ, CONFIG_DIR_ENV: str(configs)},
                stdout=out,
                stderr=subprocess.STDOUT,
                cwd=tmp_path,
            )
        wait_for(
            lambda: any("listening" in line for line in lines(output)) or example.poll() is not None,
            what="the example to start",
        )
        service = ServiceProcess(setup, model)
        service.wait_ready()
        n = len(frames)
        # the same estimates as the example's: the service publishes each once to every subscriber
        served = {e.frame_index: e.error_m for e in serve_in_lockstep(client, looped(frames, 3 * n, DEVICE, 30.0))}
        assert example.wait(120) == 0, output.read_text()
    finally:
        if example is not None and example.poll() is None:
            example.kill()
        if service is not None:
            service.kill()
        client.close()
        setup.cleanup()

    printed = [line for line in lines(output) if line.startswith("frame ")]
    actions = []
    for line in printed:
        head, action = line.split(": ", 1)
        words = head.split()
        frame, error_class = int(words[1]), int(words[6])
        expected_class = 3 if served[frame] >= threshold else 0
        assert error_class == expected_class, line
        assert action == (
            "deferred" if error_class >= 2 else f"placed anchor {sum(a != 'deferred' for a in actions) + 1}"
        )
        actions.append(action)
    # it reacted to the class going down: a placement right after a deferral
    assert any(a == "deferred" and b.startswith("placed") for a, b in zip(actions, actions[1:])), printed
    assert lines(output)[-1].startswith(f"placed {low + 1} anchors")
