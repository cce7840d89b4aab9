import os

import pytest

from seesys.core.camera import Intrinsics
from slam_monitor.orbslam_settings import (
    REQUIRED_KEYS,
    SettingsError,
    SlamMode,
    build_settings,
    load_slam_config,
    validate_settings_file,
    vocabulary_path,
    write_settings,
)

INTRINSICS = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


@pytest.fixture
def generated(tmp_path):
    def make(mode, intrinsics=INTRINSICS):
        return write_settings(
            tmp_path / f"{mode.value}.yaml", build_settings(intrinsics, 30.0, mode, load_slam_config())
        )

    return make


@pytest.mark.parametrize("mode", list(SlamMode))
def test_generated_settings_pass_validation_and_carry_the_config(generated, mode):
    path = generated(mode)
    validate_settings_file(path, mode, INTRINSICS)
    text = path.read_text()
    assert text.startswith("%YAML:1.0\n")
    assert 'File.version: "1.0"' in text
    assert "ORBextractor.nFeatures: 1000" in text
    assert ("Stereo.ThDepth: 20.0" in text) == (mode is SlamMode.RGBD)
    assert ("RGBD.DepthMapFactor: 1.0" in text) == (mode is SlamMode.RGBD)  # sources deliver metres


def test_distortion_is_written(tmp_path):
    k = Intrinsics(752, 480, 458.6, 457.3, 367.2, 248.4, (-0.28, 0.07, 0.0002, 0.00002, 0.01))
    settings = build_settings(k, 20.0, SlamMode.MONO, load_slam_config())
    assert settings["Camera1.k1"] == -0.28 and settings["Camera1.k3"] == 0.01 and settings["Camera.fps"] == 20


@pytest.mark.parametrize("key", REQUIRED_KEYS[SlamMode.RGBD])
def test_every_required_key_is_checked(generated, key):
    path = generated(SlamMode.RGBD)
    path.write_text("".join(line + "\n" for line in path.read_text().splitlines() if not line.startswith(key + ":")))
    with pytest.raises(SettingsError, match=f"lack the required key {key} "):
        validate_settings_file(path, SlamMode.RGBD, INTRINSICS)


def test_mono_does_not_need_rgbd_keys(generated):
    validate_settings_file(generated(SlamMode.MONO), SlamMode.MONO, INTRINSICS)
    with pytest.raises(SettingsError, match="Stereo.b|RGBD.DepthMapFactor|Stereo.ThDepth"):
        validate_settings_file(generated(SlamMode.MONO), SlamMode.RGBD, INTRINSICS)


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('File.version: "1.0"', 'File.version: "0.9"', "File.version is '0.9'"),
        ('Camera.type: "PinHole"', 'Camera.type: "KannalaBrandt8"', "not supported"),
        ("Camera.width: 640", "Camera.width: 752", "for 752x480 images, but the source delivers 640x480"),
        ("Camera1.fx: 525.0", 'Camera1.fx: "big"', "Camera1.fx must be a number"),
        ("Camera.fps: 30", "Camera.fps: [30", "cannot be parsed"),
    ],
)
def test_bad_values_are_named(generated, old, new, message):
    path = generated(SlamMode.RGBD)
    path.write_text(path.read_text().replace(old, new))
    with pytest.raises(SettingsError, match=message):
        validate_settings_file(path, SlamMode.RGBD, INTRINSICS)


def test_missing_file(tmp_path):
    with pytest.raises(SettingsError, match="settings file not found"):
        validate_settings_file(tmp_path / "none.yaml", SlamMode.MONO, INTRINSICS)


def test_vocabulary_path_resolves_against_repo_and_env(monkeypatch, tmp_path):
    config = load_slam_config()
    monkeypatch.delenv("PYORBSLAM3_VOCAB", raising=False)
    assert vocabulary_path(config).is_file()
    assert vocabulary_path(config).is_absolute()
    monkeypatch.setenv("PYORBSLAM3_VOCAB", os.fspath(tmp_path / "ORBvoc.txt"))
    assert vocabulary_path(config) == tmp_path / "ORBvoc.txt"
