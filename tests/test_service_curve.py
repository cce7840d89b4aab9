"""CurveZMQ end to end with the clients as they ship: a device (its feature publisher and estimate observer) and a
study logger take their keys from ``[curve]`` of network.toml. The allowed device is served and its estimates
reach it and the logger; a device whose key is not in the service's allow-list completes no handshake, so none of
its features is served and it receives no estimate."""

from __future__ import annotations

import dataclasses

import pandas as pd
import pytest
import zmq
from testkit.polling import wait_for
from testkit.service import ServiceProcess, ServiceSetup, device_frames

from estimator.service.config import load_service_config
from estimator.service.keys import make_key_pair
from estimator.service.sandbox import private_configs
from seesys.core.errors import ConfigError
from seesys.core.session_layout import ESTIMATES_CSV
from seesys.io.network import ClientCurveConfig, load_network_config
from slam_monitor.estimates import EstimateObserver
from slam_monitor.stream import FeaturePublisher
from study.estimates import ESTIMATES_CSV as STUDY_ESTIMATES_CSV
from study.watch import StreamWatcher


def observer_for(network, folder, device_id: str) -> EstimateObserver:
    folder.mkdir()
    return EstimateObserver(
        folder,
        device_id,
        network.features_endpoint,
        network.estimates_endpoint,
        network.client_options(network.estimates_endpoint),
    )


@pytest.mark.system
def test_with_curve_from_network_toml_only_the_allowed_device_is_served(tiny_model, tmp_path):
    keys = tmp_path / "keys"
    _, server_secret = make_key_pair(keys / "server", "server")
    server_public = server_secret.with_suffix(".key")
    allowed_public, allowed_secret = make_key_pair(keys / "clients", "device")
    _, stranger_secret = make_key_pair(keys / "strangers", "stranger")
    setup = ServiceSetup(
        server_secret_key=str(server_secret),
        allowed_clients=str(allowed_public.parent),
        server_public_key=str(server_public),
        client_secret_key=str(allowed_secret),
    )
    network = load_network_config(setup.config_dir)
    stranger_network = dataclasses.replace(
        network,
        features_endpoint=f"ipc://{setup.folder}/stranger-features",
        curve=ClientCurveConfig(str(server_public), str(stranger_secret)),
    )
    # The stranger connects before the service is up (ZeroMQ retries), so that its socket monitor is in place
    # before the handshake the service refuses.
    stranger = FeaturePublisher.for_network(stranger_network)
    refused = stranger.service_socket.get_monitor_socket(zmq.EVENT_HANDSHAKE_FAILED_AUTH)
    service = ServiceProcess(setup, tiny_model)
    device = watcher = None
    observers = []
    try:
        assert service.wait_ready()["curve"] is True
        observers.append(stranger_observer := observer_for(stranger_network, tmp_path / "stranger", "dev-x"))
        device = FeaturePublisher.for_network(network)
        observers.append(device_observer := observer_for(network, tmp_path / "device", "dev-ok"))
        watcher = StreamWatcher(network, tmp_path, "dev-ok")
        watcher.start()
        assert watcher.wait_ready(60)
        ours, theirs = device_frames("dev-ok", 80, seed=2), device_frames("dev-x", 80, seed=1)

        def stream_until_estimated():
            for frame, intruding in zip(ours, theirs):
                stranger.publish(dataclasses.replace(intruding, device_id="dev-ok"))  # even posing as dev-ok
                stranger.publish(intruding)
                device.publish(frame)
            return device_observer.received >= 2 and watcher.estimates >= 2

        wait_for(stream_until_estimated, what="estimates at the allowed device and the study logger")
        assert refused.poll(60_000), "the service did not refuse the stranger's handshake"
        for frame in theirs:  # again, now that its handshake was certainly refused
            stranger.publish(frame)
        seen = device_observer.received
        wait_for(lambda: stream_until_estimated() and device_observer.received > seen, what="more estimates")
        assert stranger_observer.received == 0
        assert pd.read_csv(tmp_path / "stranger" / ESTIMATES_CSV).empty
        observers.remove(device_observer)
        device_observer.close()  # no estimate may arrive between reading its log and its count
        logged = pd.read_csv(tmp_path / "device" / ESTIMATES_CSV)
        assert set(logged.frame_index) <= set(range(30, 80))
        assert len(logged) == device_observer.received
        assert list(service.status()["devices"]) == ["dev-ok"]
        assert watcher.estimates >= 2 and watcher.error is None
        assert (tmp_path / STUDY_ESTIMATES_CSV).exists()
    finally:
        refused.close()
        if watcher is not None:
            watcher.stop()
        for observer in observers:
            observer.close()
        for publisher in (device, stranger):
            if publisher is not None:
                publisher.close()
        service.stop()
        service.kill()
        setup.cleanup()


def test_curve_keys_come_in_pairs_on_both_sides(tmp_path):
    """A half-configured [curve] is refused when the configuration loads, naming what is missing."""
    client, _ = private_configs(tmp_path / "client", server_public_key="keys/server.key")
    with pytest.raises(ConfigError, match="client_secret_key"):
        load_network_config(client)
    server, _ = private_configs(tmp_path / "server", server_secret_key="keys/server.key_secret")
    with pytest.raises(ConfigError, match="allowed_clients"):
        load_service_config(server)
    plain = load_network_config(private_configs(tmp_path / "plain")[0])
    assert not plain.curve.enabled
    assert plain.client_options(plain.estimates_endpoint) == {}
