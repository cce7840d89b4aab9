"""``seesys estimator serve`` as a real subprocess over real ZeroMQ sockets: bad input is counted while a valid
device is served exactly what the model computes, Curve admits only allowed clients, a worker started later takes
its share of devices and each device's estimates stay in order, stale windows are dropped and counted, and the
default endpoints are loopback."""

from __future__ import annotations

import dataclasses
import ipaddress
import signal
import subprocess
import sys
from urllib.parse import urlparse

import numpy as np
import pytest
from testkit.polling import wait_for
from testkit.service import Client, ServiceProcess, device_frames, expected_errors, serve_in_lockstep

from estimator.service.config import load_service_config
from estimator.service.keys import ClientKeys, make_key_pair
from estimator.service.model import ServedModel
from estimator.service.stages import STAGES
from seesys.core import messages
from seesys.core.errors import ConfigError
from seesys.core.windows import assemble_windows
from seesys.io.core_settings import load_window_config
from seesys.io.network import load_network_config


def bad_messages(count: int, max_bytes: int) -> tuple[list[list[bytes]], dict[str, int]]:
    """``count`` messages the service must refuse, a quarter of each kind, and how many of each kind."""
    rng = np.random.default_rng(7)
    valid = messages.encode(device_frames("bad-device", 1)[0])
    out: list[list[bytes]] = []
    kinds = {"malformed": 0, "wrong_version": 0, "oversized": 0}
    for k in range(count):
        kind = k % 4
        if kind == 0 and k % 8 == 4:  # a device id longer than an estimate can carry (the id is in the topic)
            out.append([messages.topic(messages.FEATURE_TOPIC, "d" * 256), valid[1]])
            kinds["malformed"] += 1
        elif kind == 0:  # random bytes, random number of parts
            out.append([rng.bytes(int(rng.integers(0, 200))) for _ in range(int(rng.integers(1, 4)))])
            kinds["malformed"] += 1
        elif kind == 1:  # a valid message cut short
            out.append([valid[0], valid[1][: int(rng.integers(0, len(valid[1])))]])
            kinds["malformed"] += 1
        elif kind == 2:  # another protocol version
            body = bytearray(valid[1])
            body[len(messages.MAGIC)] = messages.PROTOCOL_VERSION + 1 + int(rng.integers(0, 5))
            out.append([valid[0], bytes(body)])
            kinds["wrong_version"] += 1
        else:  # larger than the service accepts
            out.append([valid[0], valid[1] + bytes(max_bytes)])
            kinds["oversized"] += 1
    return out, kinds


def served_exactly(client: Client, model, frames: list) -> list:
    """``frames`` served in lockstep: an estimate for every window, each what the model computes for it."""
    estimates = serve_in_lockstep(client, frames)
    expected = expected_errors(model, frames)
    assert [e.frame_index for e in estimates] == sorted(expected)
    np.testing.assert_allclose([e.error_m for e in estimates], [expected[e.frame_index] for e in estimates], rtol=1e-4)
    return estimates


@pytest.mark.system
def test_ten_thousand_bad_messages_are_counted_then_a_valid_device_is_served_exactly(setup_factory, tiny_model):
    setup = setup_factory()
    service = ServiceProcess(setup, tiny_model)
    try:
        service.wait_ready()
        max_bytes = load_service_config(setup.config_dir).max_message_bytes
        flood, kinds = bad_messages(10_000, max_bytes)
        client = Client(setup, [messages.topic(messages.ESTIMATE_TOPIC, "dev-1")])
        probe = messages.encode(device_frames("probe", 1)[0])
        # PUB connects asynchronously: a valid probe frame is repeated until the service has seen one.
        wait_for(
            lambda: client.pub.send_multipart(probe) or "probe" in (service.status() or {}).get("devices", {}),
            what="the client to connect",
        )
        for parts in flood:
            client.pub.send_multipart(parts)
        status = wait_for(
            lambda: (s := service.status()) and sum(s["rejected"].values()) == 10_000 and s,
            what="every bad message to be counted",
        )
        assert status["rejected"] == kinds
        assert list(status["devices"]) == ["probe"]  # nothing refused reached a worker

        frames = device_frames("dev-1", 120, seed=3)
        estimates = served_exactly(client, tiny_model, frames)
        assert all(
            e.device_id == "dev-1"
            and e.model_version.startswith("tiny-")
            and e.server_ms >= 0
            and e.timestamp == frames[e.frame_index].timestamp
            and e.head == ()
            for e in estimates
        )
        status = service.status()
        assert status["devices"]["dev-1"]["estimates"] >= len(estimates)
        assert status["devices"]["dev-1"]["server_ms"]["p99"] is not None
        stages_ms = status["stages_ms"]  # where each estimate's time went, stage by stage, in path order
        assert list(stages_ms) == list(STAGES)
        assert all(stages_ms[s]["p50"] >= 0 for s in STAGES if s != "hops") and stages_ms["inference"]["p50"] > 0
        # Each stage is a part of every estimate's total, so none of its percentiles exceeds the total's.
        assert all(stages_ms[s]["p99"] <= stages_ms["server"]["p99"] + 1e-3 for s in STAGES)
        shown = subprocess.run(
            [sys.executable, "-m", "seesys", "estimator", "status"],
            env=setup.env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert shown.returncode == 0, shown.stderr
        assert f"oversized {kinds['oversized']}, wrong_version {kinds['wrong_version']}" in shown.stdout
        assert any(line.startswith("dev-1 ") and "local-0" in line for line in shown.stdout.splitlines())
        assert "where the time goes, p50 ms: ingest " in shown.stdout
        client.close()
        assert service.stop(signal.SIGTERM) == 0
        assert "stopped: 2 device(s)" in service.output()  # the probe and dev-1
    finally:
        service.kill()


@pytest.mark.system
def test_with_curve_a_client_not_allowed_gets_nothing_and_is_not_served(setup_factory, tiny_model, tmp_path):
    keys = tmp_path / "keys"
    _, server_secret = make_key_pair(keys / "server", "server")
    allowed_public, allowed_secret = make_key_pair(keys / "clients", "device")
    _, stranger_secret = make_key_pair(keys / "strangers", "stranger")
    setup = setup_factory(server_secret_key=str(server_secret), allowed_clients=str(allowed_public.parent))
    server_public = server_secret.with_suffix(".key")
    service = ServiceProcess(setup, tiny_model)
    try:
        assert service.wait_ready()["curve"] is True
        stranger = Client(
            setup,
            [messages.ESTIMATE_TOPIC],  # every device's estimates
            ClientKeys(stranger_secret, server_public).socket_options(),
        )
        plain = Client(setup, [messages.ESTIMATE_TOPIC])  # no Curve at all
        device = Client(
            setup,
            [messages.topic(messages.ESTIMATE_TOPIC, "dev-ok")],
            ClientKeys(allowed_secret, server_public).socket_options(),
        )
        for frame in device_frames("intruder", 80, seed=1):
            stranger.send(frame)
            plain.send(frame)
        estimates = serve_in_lockstep(device, device_frames("dev-ok", 80, seed=2))
        assert [e.frame_index for e in estimates] == list(range(30, 80, load_window_config().end_stride))
        for frame in device_frames("intruder", 80, seed=1):  # again, now that the service certainly runs
            stranger.send(frame)
            plain.send(frame)
        serve_in_lockstep(device, device_frames("dev-ok", 80, seed=2)[:31])  # a restart of dev-ok, served
        assert stranger.receive(0) is None and plain.receive(0) is None
        assert list(service.status()["devices"]) == ["dev-ok"]
        for client in (stranger, plain, device):
            client.close()
    finally:
        service.stop()
        service.kill()


def join_worker(service: ServiceProcess, model) -> subprocess.Popen:
    """``seesys estimator worker --name extra`` started beside the running ``service``, once the service lists it."""
    extra = subprocess.Popen(
        [sys.executable, "-m", "seesys", "estimator", "worker", "--model", str(model), "--name", "extra"],
        env=service.setup.env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for(lambda: "extra" in [w["name"] for w in service.status()["workers"]], what="the second worker to join")
    return extra


@pytest.mark.system
def test_a_worker_started_later_takes_devices_and_each_devices_order_is_kept(setup_factory, tiny_model):
    """``serve`` with one worker, then ``seesys estimator worker`` started beside it: new devices are shared
    between the two, and each device's estimates arrive in frame order."""
    setup = setup_factory()
    service = ServiceProcess(setup, tiny_model, "--workers", "1")
    extra = None
    try:
        service.wait_ready()
        extra = join_worker(service, tiny_model)
        names = [f"dev-{k}" for k in range(6)]
        client = Client(setup, [messages.ESTIMATE_TOPIC])
        serve_in_lockstep(client, device_frames("probe", 31))  # both connections are up
        streams = {name: device_frames(name, 150, seed=k) for k, name in enumerate(names)}
        for i in range(150):  # interleaved, as fast as the client can send
            for name in names:
                client.send(streams[name][i])
        seen: dict[str, list[int]] = {name: [] for name in names}
        last_end = max(i for i in range(150) if load_window_config().is_psd_frame(i))

        def all_received():
            while (estimate := client.receive(100)) is not None:
                if estimate.device_id in seen:
                    seen[estimate.device_id].append(estimate.frame_index)
            return all(s and s[-1] == last_end for s in seen.values())

        wait_for(all_received, what="the last estimate of every device")
        for name, indices in seen.items():
            assert indices == sorted(set(indices)), f"{name}: out of order {indices}"
        # The burst outruns the workers: a window superseded by a newer one of its device before it was served is
        # dropped and counted as stale. Every window is accounted for, served or counted.
        windows = len(range(30, 150, load_window_config().end_stride))

        def accounted():
            devices = service.status()["devices"]
            return all(len(seen[n]) + devices[n]["dropped"]["stale"] == windows for n in names)

        wait_for(accounted, what="every window served or counted as stale")
        status = service.status()
        per_worker = sorted(len(w["devices"]) for w in status["workers"])
        assert per_worker == [3, 4]  # six devices and the probe
        client.close()
        assert service.stop(signal.SIGINT) == 0
        assert extra.wait(60) == 0  # the broker told it to stop
    finally:
        service.kill()
        if extra is not None and extra.poll() is None:
            extra.kill()


@pytest.mark.system
def test_with_no_worker_process_the_broker_serves_exactly_and_a_worker_started_later_takes_devices(
    setup_factory, tiny_model
):
    """``serve --workers 0``: the broker runs the model itself, serves what the model computes with every stage timed,
    lists itself as the one worker (in the service's own process), refuses a device of other settings
    as a worker does; a worker started beside it takes the next new device and each device's order is kept."""
    setup = setup_factory()
    service = ServiceProcess(setup, tiny_model, "--workers", "0")
    extra = None
    try:
        status = service.wait_ready()
        assert [(w["name"], w["pid"]) for w in status["workers"]] == [("in-broker", service.process.pid)]
        client = Client(setup, [messages.ESTIMATE_TOPIC])
        frames = device_frames("dev-0", 120, seed=5)
        served_exactly(client, tiny_model, frames)
        settings = dataclasses.replace(frames[0].settings, orb_features=frames[0].settings.orb_features + 1)
        for frame in device_frames("dev-other", 61, seed=6, settings=settings):
            client.send(frame)
        refused = wait_for(
            lambda: (s := service.status()) and s["devices"].get("dev-other", {}).get("settings_refused") and s,
            what="the device of other settings to be refused",
        )
        assert refused["devices"]["dev-other"]["dropped"]["settings_mismatch"] >= 1
        assert refused["devices"]["dev-other"]["estimates"] == 0
        assert list(refused["stages_ms"]) == list(STAGES) and refused["stages_ms"]["inference"]["p50"] > 0

        extra = join_worker(service, tiny_model)
        served_exactly(client, tiny_model, device_frames("dev-1", 120, seed=7))
        workers = {w["name"]: w["devices"] for w in service.status()["workers"]}
        assert workers == {"in-broker": ["dev-0", "dev-other"], "extra": ["dev-1"]}
        client.close()
        assert service.stop(signal.SIGTERM) == 0
        assert extra.wait(60) == 0  # the broker told it to stop
        assert "in the broker's process" in service.output()
    finally:
        service.kill()
        if extra is not None and extra.poll() is None:
            extra.kill()


def test_no_worker_process_is_a_setting_and_fewer_is_refused_naming_it():
    config = load_service_config()
    assert dataclasses.replace(config, workers=0).workers == 0  # the broker runs the model
    with pytest.raises(ConfigError, match="service.toml: workers must be at least 0, got -1"):
        dataclasses.replace(config, workers=-1)


def test_default_endpoints_are_loopback():
    config, network = load_service_config(), load_network_config()
    endpoints = [
        network.ingest_endpoint,
        config.worker_endpoint,
        config.status_endpoint,
        network.estimates_endpoint,
        network.features_endpoint,
    ]
    for endpoint in endpoints:
        host = urlparse(endpoint).hostname
        assert ipaddress.ip_address(host).is_loopback, endpoint
    assert config.curve.enabled is False


@pytest.mark.system
def test_stale_windows_are_dropped_and_counted_never_served(setup_factory, tiny_model):
    """With a limit nothing can meet, every window is dropped at the worker and counted; none is served late."""
    setup = setup_factory(stale_after_ms=0.0)
    service = ServiceProcess(setup, tiny_model)
    try:
        service.wait_ready()
        client = Client(setup, [messages.ESTIMATE_TOPIC])
        frames = device_frames("dev-s", 200, seed=4)
        ends = len(range(30, 200, load_window_config().end_stride))

        def counted():
            for frame in frames:  # again until the connection is up and all of them were seen
                client.send(frame)
            device = service.status()["devices"].get("dev-s")
            return device and device["dropped"]["stale"] >= ends

        wait_for(counted, what="stale windows to be counted")
        assert client.receive(0) is None
        assert service.status()["devices"]["dev-s"]["estimates"] == 0
        client.close()
    finally:
        service.stop()
        service.kill()


def test_keys_refuses_to_overwrite(tmp_path):
    from seesys.core.errors import SeesysError

    make_key_pair(tmp_path, "server")
    with pytest.raises(SeesysError, match="already exists"):
        make_key_pair(tmp_path, "server")


@pytest.mark.system
def test_the_served_model_fits_any_end_stride_but_not_another_window(tiny_model):
    """The estimate rate (end_stride) is not part of what a model was made for; the window's content is."""
    from estimator.deepsee.checkpoint import ModelMismatch

    windows = load_window_config()
    for stride in (1, 5, 10):
        model = ServedModel.load(tiny_model, dataclasses.replace(windows, end_stride=stride))
        assert model.psd_shape == (windows.psd_samples, 96, 128, 3)
    with pytest.raises(ModelMismatch, match="windows"):
        ServedModel.load(tiny_model, dataclasses.replace(windows, psd_stride=20))


@pytest.mark.system
def test_a_model_with_a_head_serves_its_thresholds_and_probabilities_with_every_estimate(
    setup_factory, tiny_head_model
):
    setup = setup_factory()
    service = ServiceProcess(setup, tiny_head_model)
    try:
        service.wait_ready()
        client = Client(setup, [messages.topic(messages.ESTIMATE_TOPIC, "dev-1")])
        frames = device_frames("dev-1", 60, seed=5)
        estimates = serve_in_lockstep(client, frames)
        client.close()
        model = ServedModel.load(tiny_head_model, load_window_config())
        assert model.thresholds_m == (0.004, 0.008, 0.012)
        expected = {
            w.frame_index: model.estimate_batch([w]).probabilities[0]
            for w in assemble_windows(frames, load_window_config())
        }
        assert len(estimates) > 3
        for e in estimates:
            assert [h.threshold_m for h in e.head] == [float(np.float32(t)) for t in model.thresholds_m]
            np.testing.assert_allclose([h.probability for h in e.head], expected[e.frame_index], atol=1e-5)
        assert service.stop(signal.SIGTERM) == 0
    finally:
        service.kill()
        setup.cleanup()
