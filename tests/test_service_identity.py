"""Who a stream belongs to and why a device gets no estimate: a second device with an id already in use is refused
and counted while the first is served untouched, a restarted device takes its id over once the first stream went
silent, every drop reason is named in the broker's status and in ``seesys estimator status`` (a camera of another
resolution, settings unlike the model's, windows with missing rows), non-finite RTS values are counted, and a
worker whose clock is a second off still serves."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from testkit.polling import wait_for
from testkit.service import Client, ServiceSetup, device_frames, expected_errors, running_service, serve_in_lockstep

from estimator.service.model import ServedModel
from seesys.core import messages, rts_schema
from seesys.io.core_settings import load_device_settings, load_window_config


def shown_status(setup: ServiceSetup) -> str:
    shown = subprocess.run(
        [sys.executable, "-m", "seesys", "estimator", "status"],
        env=setup.env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert shown.returncode == 0, shown.stderr
    return shown.stdout


def device_line(text: str, device: str) -> str:
    return next(line for line in text.splitlines() if line.startswith(f"{device} "))


@pytest.mark.system
def test_a_second_device_with_the_same_id_is_refused_and_the_first_is_served_untouched(setup_factory, tiny_model):
    setup = setup_factory(id_takeover_after_s=600.0)
    with running_service(setup, tiny_model) as service:
        topic = [messages.topic(messages.ESTIMATE_TOPIC, "dev-same")]
        first, second = Client(setup, topic), Client(setup, topic)
        mine = device_frames("dev-same", 150, seed=1, stream_session=0x1111)
        other = device_frames("dev-same", 150, seed=2, stream_session=0x2222)
        estimates = serve_in_lockstep(first, mine[:31])  # the id is bound to the first stream

        def refused():
            second.send(other[0])
            return service.status()["devices"]["dev-same"]["dropped"]["id_in_use"] > 0

        wait_for(refused, what="the second stream to reach the service")
        windows = load_window_config()
        for i in range(31, 150):  # both devices stream the same id, frame by frame interleaved
            first.send(mine[i])
            second.send(other[i])
            if windows.is_psd_frame(i):
                estimate = wait_for(lambda: first.receive(200), what=f"the estimate of frame {i}")
                assert estimate.frame_index == i
                estimates.append(estimate)
        expected = expected_errors(tiny_model, mine)
        assert [e.frame_index for e in estimates] == sorted(expected)
        np.testing.assert_allclose(
            [e.error_m for e in estimates], [expected[e.frame_index] for e in estimates], rtol=1e-4
        )
        assert {e.stream_session for e in estimates} == {0x1111}
        assert all(e.stream_session == 0x1111 for e in iter(lambda: second.receive(0), None))
        device = service.status()["devices"]["dev-same"]
        assert device["dropped"]["id_in_use"] >= 119 and device["stream_session"] == "1111"
        assert device["takeovers"] == 0
        assert "id_in_use" in device_line(shown_status(setup), "dev-same")
        first.close()
        second.close()
        wait_for(
            lambda: (
                "frames of stream session 2222 refused: the id is in use by stream session 1111" in service.output()
            ),
            what="the refusal in the service's log",
        )


@pytest.mark.system
def test_a_restarted_device_takes_its_id_over_once_the_first_stream_is_silent(setup_factory, tiny_model):
    setup = setup_factory(id_takeover_after_s=1.0)
    with running_service(setup, tiny_model) as service:
        topic = [messages.topic(messages.ESTIMATE_TOPIC, "dev-restart")]
        before = Client(setup, topic)
        serve_in_lockstep(before, device_frames("dev-restart", 31, seed=1, stream_session=1))
        before.close()  # the first run ends; the next one draws a new stream session
        after = Client(setup, topic)
        estimates = serve_in_lockstep(after, device_frames("dev-restart", 61, seed=3, stream_session=2))
        assert {e.stream_session for e in estimates} == {2}
        device = service.status()["devices"]["dev-restart"]
        assert device["takeovers"] == 1 and device["stream_session"] == "2"
        after.close()
        assert "stream session 2 takes the id over from stream session 1" in service.output()


@pytest.mark.system
def test_every_drop_reason_is_named_in_status_and_nonfinite_values_are_counted(setup_factory, tiny_model):
    """An 848×480 camera (another PSD shape), a device whose near_depth differs from the model's, a stream with a
    missing frame (the window rule allows no missing row) and RTS rows with a NaN and an inf channel."""
    setup = setup_factory()
    with running_service(setup, tiny_model) as service:
        client = Client(setup, [messages.ESTIMATE_TOPIC])
        windows = load_window_config()
        nan_frames = []
        for frame in device_frames("dev-nan", 61, seed=5):
            rts = frame.rts.copy()
            rts[rts_schema.index_of("var_mp_depth")] = np.nan
            rts[rts_schema.index_of("avg_mp_depth")] = np.inf
            nan_frames.append(dataclasses.replace(frame, rts=rts))
        served = serve_in_lockstep(client, nan_frames)  # also: the connection is up
        assert [e.frame_index for e in served] == [30, 35, 40, 45, 50, 55, 60]
        wide = device_frames("dev-848", 80, psd_shape=(96, 170, 3))
        far = device_frames(
            "dev-far", 80, settings=dataclasses.replace(load_device_settings("rgbd", 30.0), near_depth=1.0)
        )
        gaps = [f for f in device_frames("dev-gap", 80) if f.frame_index != 42]
        for frame in wide + far + gaps:
            client.send(frame)
        ends = len(range(windows.history, 80, windows.end_stride))  # window ends with their history in reach

        def counted():
            devices = service.status()["devices"]
            return (
                len(devices) == 4
                and devices["dev-848"]["dropped"]["shape_mismatch"] == ends
                # each frame that ends a window, which states the device settings with its PSD
                and devices["dev-far"]["dropped"]["settings_mismatch"] == sum(f.psd is not None for f in far)
                # the gap's frames come last: all six of its refusals, not the first (a starved worker is slow)
                and devices["dev-gap"]["dropped"]["missing_rts"] >= 6
                and devices["dev-nan"]["nonfinite"] >= 2 * windows.rts_length * len(served)
            )

        wait_for(counted, what="every drop to be counted")
        devices = service.status()["devices"]
        # Frame 42 is in the RTS windows ending at 45 ... 70: six refused for a missing row, the rest served.
        assert devices["dev-gap"]["dropped"]["missing_rts"] == 6
        assert devices["dev-nan"]["nonfinite"] % (2 * windows.rts_length) == 0  # two channels of every row
        assert devices["dev-far"]["settings_refused"] == "near_depth: device 1, model 0.5"
        assert devices["dev-848"]["estimates"] == devices["dev-far"]["estimates"] == 0
        for device in devices.values():  # every reason by name, for the app's view too
            assert {
                "shape_mismatch",
                "settings_mismatch",
                "missing_rts",
                "missing_psd",
                "stale",
                "queue_full",
                "no_worker",
                "out_of_order",
                "id_in_use",
            } <= set(device["dropped"])
        text = shown_status(setup)
        assert f"shape_mismatch {ends}" in device_line(text, "dev-848")
        assert f"settings_mismatch {sum(f.psd is not None for f in far)}" in device_line(text, "dev-far")
        assert "missing_rts 6" in device_line(text, "dev-gap")
        assert "dev-far: frames refused, settings differ from the model's: near_depth: device 1, model 0.5" in text
        assert f"dev-nan: {devices['dev-nan']['nonfinite']} RTS values not finite" in text
        client.close()
        assert (
            "device 'dev-far' (stream session 0): frames refused, its settings differ from the model's: "
            "near_depth: device 1, model 0.5" in service.output()
        )


@pytest.mark.parametrize(("offset_s", "stale_after_ms", "served"), [(1.0, 900.0, True), (-1.0, 0.0, False)])
def test_a_worker_whose_clock_is_a_second_off_judges_staleness_on_its_own_clock(
    setup_factory, tiny_model, offset_s, stale_after_ms, served
):
    """A broker and a worker whose wall clocks differ by a second: a worker ahead still serves every window within
    the limit, and a worker behind still drops what is older than the limit (0 ms: every window)."""
    from estimator.service.broker import Broker
    from estimator.service.config import load_service_config
    from estimator.service.worker import Worker
    from seesys.io.network import load_network_config

    setup = setup_factory(stale_after_ms=stale_after_ms)
    config, network = load_service_config(setup.config_dir), load_network_config(setup.config_dir)
    windows = load_window_config(setup.config_dir)
    broker = Broker(config, network)
    worker = Worker(
        broker.endpoints["workers"],
        ServedModel.load(tiny_model, windows),
        windows,
        config,
        "skewed",
        clock=lambda: time.time() + offset_s,
    )
    threads = [threading.Thread(target=worker.run, daemon=True)]
    threads[0].start()
    client = None
    try:
        assert broker.wait_for_workers(1, 120)
        broker.open()
        threads.append(threading.Thread(target=broker.run, daemon=True))
        threads[1].start()
        client = Client(setup, [messages.ESTIMATE_TOPIC])
        frames = device_frames("dev-clock", 61, seed=6)
        if served:
            estimates = serve_in_lockstep(client, frames)
            assert [e.frame_index for e in estimates] == [30, 35, 40, 45, 50, 55, 60]
        else:
            from estimator.service.status import query_status

            def all_stale():
                for frame in frames:
                    client.send(frame)
                device = query_status(setup.endpoints["status"], 5000)["devices"].get("dev-clock")
                return device and device["dropped"]["stale"] >= 7

            wait_for(all_stale, what="every window to be dropped as stale")
            assert client.receive(0) is None
    finally:
        worker.stop()
        broker.stop()
        for thread in threads:
            thread.join(60)
        if client is not None:
            client.close()
        broker.close()
