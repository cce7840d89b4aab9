from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from advisory import config as advisory_config
from advisory.config import load_advisory_config
from seesys.io.config import ConfigError, ConfigSet, load_section, write_config_dir
from seesys.io.network import load_network_config
from slam_monitor import monitor_config
from slam_monitor.monitor_config import load_monitor_config


@dataclass(frozen=True)
class Inner:
    rate: float
    names: list[str]


@dataclass(frozen=True)
class Outer:
    port: int
    inner: Inner
    label: str | None


def write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "sec.toml").write_text(text)
    return tmp_path


def test_loads_nested_typed_values(tmp_path):
    d = write(tmp_path, 'port = 5\nlabel = "x"\n[inner]\nrate = 2\nnames = ["a", "b"]\n')
    cfg = load_section("sec", Outer, d)
    assert cfg == Outer(5, Inner(2.0, ["a", "b"]), "x")
    assert isinstance(cfg.inner.rate, float)


@pytest.mark.parametrize(
    "text, message",
    [
        ('port = 5\nlabel = "x"\nextra = 1\n[inner]\nrate = 2\nnames = []\n', "unknown key(s) extra"),
        ('label = "x"\n[inner]\nrate = 2\nnames = []\n', "missing key(s) port"),
        ('port = 5\nlabel = "x"\n[inner]\nnames = []\n', "sec.toml.inner: missing key(s) rate"),
        ('port = "5"\nlabel = "x"\n[inner]\nrate = 2\nnames = []\n', "sec.toml.port: expected an integer"),
        ('port = true\nlabel = "x"\n[inner]\nrate = 2\nnames = []\n', "expected an integer"),
        ('port = 5\nlabel = "x"\n[inner]\nrate = 2\nnames = [1]\n', "names[0]: expected str"),
        ("port = = 5\n", "not valid TOML"),
    ],
)
def test_rejects_bad_files_naming_the_problem(tmp_path, text, message):
    d = write(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_section("sec", Outer, d)
    assert message in str(e.value)


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_section("nope", Outer, tmp_path)


def test_shipped_network_config_loads():
    cfg = load_network_config()
    assert cfg.features_endpoint.startswith("tcp://")
    assert cfg.send_high_water_mark > 0


def test_no_two_shipped_endpoints_share_a_port():
    """Device, estimator service and advisory run side by side on one machine: every TCP endpoint the shipped
    configs bind or connect to must be its own (a service and an advisory on one port cannot both start)."""
    from seesys.io.config import config_dir, read_toml

    def endpoints(value, where):
        if isinstance(value, dict):
            for key, item in value.items():
                yield from endpoints(item, f"{where}.{key}")
        elif isinstance(value, str) and value.startswith("tcp://"):
            yield value.rsplit(":", 1)[1], where

    seen: dict[str, str] = {}
    for path in sorted(config_dir().glob("*.toml")):
        for port, where in endpoints(read_toml(path), path.stem):
            assert port not in seen, f"port {port} of {where} is also {seen[port]}"
            seen[port] = where
    assert len(seen) >= 6


def test_an_override_key_must_exist_and_name_one_file(tmp_path):
    with pytest.raises(KeyError, match="no such configuration key: no_such_key"):
        write_config_dir(tmp_path / "a", {"no_such_key": 1})
    # stall_timeout_s is a key of slam.toml and of simulate.toml: by name alone it would change one silently
    with pytest.raises(KeyError, match="stall_timeout_s is in simulate.toml, slam.toml: name it as simulate"):
        write_config_dir(tmp_path / "b", {"stall_timeout_s": 9.0})
    with pytest.raises(KeyError, match="no such configuration key: camera.stall_timeout_s"):
        write_config_dir(tmp_path / "c", {"camera.stall_timeout_s": 9.0})
    folder = write_config_dir(tmp_path / "d", {"slam.stall_timeout_s": 9.0, "slam_cpus": 1})
    written = ConfigSet.read(folder)
    assert written.data("slam")["supervisor"]["stall_timeout_s"] == 9.0
    assert written.data("simulate") == ConfigSet.read().data("simulate")
    assert written.data("ray")["slam_cpus"] == 1  # by name: one file has it


def test_a_typed_change_for_a_child_is_written_whole_and_read_back_unchanged_elsewhere(tmp_path):
    advisory, monitor = load_advisory_config(), load_monitor_config()
    changed = replace(advisory, timing=replace(advisory.timing, listen_to_device="lab-pc:tum:office"))
    folder = (
        ConfigSet.read()
        .replaced(advisory_config.SECTION, changed)
        .replaced(monitor_config.SECTION, replace(monitor, device_id="lab-pc:tum:office"))
        .write(tmp_path / "configs")
    )
    assert load_advisory_config(folder) == changed
    # The monitor's settings carry the shared windows of windows.toml, which monitor.toml must not hold.
    assert load_monitor_config(folder) == replace(monitor, device_id="lab-pc:tum:office")
    assert load_network_config(folder) == load_network_config()
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in ConfigSet.read().folder.glob("*.toml"))


def test_a_folder_is_parsed_once_until_one_of_its_files_changes(tmp_path):
    folder = write_config_dir(tmp_path / "configs", {"slam_cpus": 1})
    first = ConfigSet.read(folder)
    assert ConfigSet.read(folder) is first
    (folder / "ray.toml").write_text((folder / "ray.toml").read_text().replace("slam_cpus = 1", "slam_cpus = 2"))
    again = ConfigSet.read(folder)
    assert again is not first and again.data("ray")["slam_cpus"] == 2 and first.data("ray")["slam_cpus"] == 1


def test_a_missing_file_of_the_set_is_named(tmp_path):
    with pytest.raises(ConfigError, match=f"configuration file not found: {tmp_path}/advisory.toml"):
        load_advisory_config(tmp_path)
