"""The model's compatibility record: complete (RTS schema, windows and their missing-row rule, label transform and
Δ, the device settings: SLAM modes, frame rate, ORB features, PSD geometry and near_depth), stored in the
checkpoint and the ONNX metadata of the shipped model with the values it was trained with, and every difference
refused by name: a model against this installation's configs, a device's settings against the model's."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from estimator.artefact.compatibility import ModelMismatch, ModelSetup, check_compatible, compatibility
from estimator.artefact.onnx_model import COMPATIBILITY_KEY
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.config import load_estimator_config
from estimator.service.model import ServedModel
from seesys.core import rts_schema
from seesys.core.device_settings import DeviceSettings, settings_differences
from seesys.core.labels import MONO_ALIGNMENT
from seesys.io.config import CONFIG_DIR_ENV, write_config_dir
from seesys.io.core_settings import load_device_settings, load_window_config
from seesys.io.resources import resolve

# The RTS channels of the shipped model: schema v3's.
SHIPPED_CHANNELS = 19
# What the shipped model was trained with (docs/table3/README.md: the defaults of configs/*.toml then and now):
# camera normalisation v1 with the ideal camera as its reference.
SHIPPED_DEVICE = {
    "slam_modes": ["rgbd"],
    "fps": 30,
    "orb_features": 1000,
    "psd_patch_px": 10,
    "psd_expansion": 2,
    "near_depth": 0.5,
    "camera_normalisation": 1,
    "reference_camera": {"width": 640, "height": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5},
}


def test_the_shipped_model_carries_the_full_record_in_both_files():
    import onnx
    import torch

    transform = LabelTransform(load_estimator_config().label_transform.k)
    # Every channel of RTS schema v3 (the first 19 of today's v4, taken from its rows by name), and the ordinal head
    # at Equation 2's boundaries.
    head = (0.004, 0.008, 0.012)
    channels = rts_schema.CHANNEL_NAMES[:SHIPPED_CHANNELS]
    expected = {
        **compatibility(
            load_window_config(), transform, ModelSetup(10, SHIPPED_DEVICE), channels, head_thresholds_m=head
        ),
        "rts_schema_version": 3,
    }
    assert expected["rts_fingerprint"] == 0x8490F111  # v3's
    assert {**compatibility(load_window_config(), transform, None, channels, head), "rts_schema_version": 3} == expected
    assert expected["windows"]["max_missing_rts"] == 0
    meta = {p.key: p.value for p in onnx.load(str(resolve("data/models/deepsee.onnx"))).metadata_props}
    assert json.loads(meta[COMPATIBILITY_KEY]) == expected
    payload = torch.load(resolve("data/models/deepsee.pt"), map_location="cpu", weights_only=False)
    assert payload["compatibility"] == expected
    served = ServedModel.load(resolve("data/models/deepsee.onnx"), load_window_config())
    assert served.device_record == SHIPPED_DEVICE
    assert list(served._model.rts_columns) == list(range(SHIPPED_CHANNELS))


@pytest.mark.system
def test_a_model_made_for_other_settings_is_refused_naming_each_field(tiny_model):
    windows = load_window_config()
    here = ModelSetup.configured()
    moved = ModelSetup(here.delta_frames, {**here.device, "near_depth": 1.0})
    with pytest.raises(ModelMismatch, match=r"device\.near_depth: model 0\.5, here 1\.0") as refused:
        ServedModel.load(tiny_model, windows, setup=moved)
    assert "orb_features" not in str(refused.value)  # only what differs
    with pytest.raises(ModelMismatch, match=r"label\.delta_frames: model 10, here 5"):
        ServedModel.load(tiny_model, windows, setup=ModelSetup(5, here.device))
    with pytest.raises(ModelMismatch, match=r"windows\.max_missing_rts: model 0, here 3"):
        ServedModel.load(tiny_model, dataclasses.replace(windows, max_missing_rts=3))


def test_a_monocular_model_made_under_another_label_definition_is_refused_by_name():
    """A model trained on monocular sessions records the monocular label's alignment; one made under another (or
    before the name was recorded: the sliding-window label) is refused naming it. An RGB-D model's record does not
    carry it and is not asked for it (its label never changed)."""
    windows = load_window_config()
    transform = LabelTransform(load_estimator_config().label_transform.k)
    here = ModelSetup.configured()
    mono = compatibility(
        windows, transform, ModelSetup(here.delta_frames, {**here.device, "slam_modes": ["mono", "rgbd"]})
    )
    assert mono["label"] == {"delta_frames": here.delta_frames, "mono_alignment": MONO_ALIGNMENT}
    check_compatible(mono, "the mono model", windows, transform)
    rgbd = compatibility(windows, transform, ModelSetup(here.delta_frames, SHIPPED_DEVICE))
    assert rgbd["label"] == {"delta_frames": here.delta_frames}
    check_compatible(rgbd, "the RGB-D model", windows, transform)

    other = {**mono, "label": {**mono["label"], "mono_alignment": "sim3-window-90"}}
    with pytest.raises(
        ModelMismatch,
        match=r"the mono model was made for other inputs: label\.mono_alignment: "
        r'model "sim3-window-90", here "sim3-per-stretch"\. It cannot',
    ):
        check_compatible(other, "the mono model", windows, transform)
    before = {**mono, "label": {"delta_frames": here.delta_frames}}
    with pytest.raises(
        ModelMismatch,
        match=r'label\.mono_alignment: model "sim3-sliding-window", here '
        r'"sim3-per-stretch"',
    ):
        check_compatible(before, "the mono model", windows, transform)


@pytest.mark.system
def test_serve_refuses_a_model_whose_near_depth_differs_from_monitor_toml(tiny_model, tmp_path):
    config_dir = write_config_dir(tmp_path / "configs", {"near_depth": 1.0})
    run = subprocess.run(
        [sys.executable, "-m", "seesys", "estimator", "serve", "--model", str(tiny_model)],
        env={**os.environ, CONFIG_DIR_ENV: str(config_dir)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode != 0
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "device.near_depth: model 0.5, here 1.0" in lines[0], run.stderr


def test_a_device_is_compared_with_the_model_setting_by_setting():
    model = SHIPPED_DEVICE
    device = load_device_settings("rgbd", 29.97)
    assert device == DeviceSettings("rgbd", 30, 1000, 10, 2, 0.5, 1)
    assert settings_differences(model, device) == []
    assert settings_differences(model, dataclasses.replace(device, slam_mode="mono")) == [
        "slam_mode: device mono, model rgbd"
    ]
    assert settings_differences(model, dataclasses.replace(device, fps=15, orb_features=1500)) == [
        "fps: device 15, model 30",
        "orb_features: device 1500, model 1000",
    ]
    assert settings_differences(model, dataclasses.replace(device, camera_normalisation=0)) == [
        "camera_normalisation: device 0, model 1"
    ]


def test_a_logged_session_replays_with_the_settings_its_device_stated(tmp_path):
    """rts.json records the device settings, so a session replayed from its logs states them as the device did (a
    session logged without them replays without, and the service refuses its frames)."""
    import numpy as np

    from seesys.core.messages import FeatureFrame
    from seesys.core.tracking_state import TrackingState
    from seesys.io.rts_log import PSD_DIR, RTS_CSV, PsdLogWriter, RtsCsvWriter, read_feature_frames

    settings = load_device_settings("rgbd", 30.0)
    for folder, stated in ((tmp_path / "with", settings), (tmp_path / "without", None)):
        folder.mkdir()
        writer, psds = RtsCsvWriter(folder / RTS_CSV, stated), PsdLogWriter(folder / PSD_DIR, 10)
        writer.write(FeatureFrame("d", 0, 1.0, TrackingState.OK, np.zeros(16, np.float32)))
        writer.close()
        psds.close()
        assert [f.settings for f in read_feature_frames(folder, "d")] == [stated]
