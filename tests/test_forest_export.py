"""The random forest as a served ONNX model: the graph's window statistics and trees give scikit-learn's estimates,
the file carries the forest's record, and the service serves it like any exported model."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from sklearn.ensemble import RandomForestRegressor
from testkit.sample import run_seesys

from estimator.artefact.compatibility import ModelMismatch, compatibility
from estimator.artefact.onnx_model import FOREST_KIND, OnnxModel, RecordedTraining, recorded_training
from estimator.artefact.transforms import LabelTransform, prepare_rts
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.forest import window_statistics
from estimator.deepsee.forest_export import (
    FOREST_PARITY_TOLERANCE,
    export_forest_onnx,
    forest_parity,
    psd_shape_of,
)
from estimator.deepsee.predictors import read_forest
from estimator.service.model import ServedModel
from seesys.core import rts_schema
from seesys.core.windows import NO_PSD, WindowSample
from seesys.io.core_settings import load_window_config

WINDOWS = load_window_config()
TRANSFORM = LabelTransform(load_estimator_config().label_transform.k)


def _raw_windows(count: int, seed: int) -> np.ndarray:
    """Raw RTS windows (count, T, C) around each channel's scale, a tenth of the values missing (NaN)."""
    rng = np.random.default_rng(seed)
    raw = rng.lognormal(0.0, 1.0, (count, WINDOWS.rts_length, rts_schema.NUM_CHANNELS)).astype(np.float32)
    raw[rng.random(raw.shape) < 0.1] = np.nan
    return raw


def _record(trees: int = 8) -> dict:
    rts = prepare_rts(_raw_windows(400, 1))
    target = rts[:, -1, 0] * 2 + rts[:, :, 5].mean(axis=1) + np.random.default_rng(2).normal(0, 0.1, len(rts))
    forest = RandomForestRegressor(n_estimators=trees, min_samples_leaf=5, random_state=0)
    forest.fit(window_statistics(rts), target)
    return {"forest": forest, "compatibility": compatibility(WINDOWS, TRANSFORM), "training": {"cameras": ["ideal"]}}


def test_the_exported_forest_gives_scikit_learns_estimates_and_is_served_like_any_model(tmp_path):
    record = _record()
    shape = psd_shape_of(record["compatibility"], WINDOWS.psd_samples)
    path = export_forest_onnx(record, tmp_path / "forest.onnx", WINDOWS.rts_length, shape, ["ideal"])
    model = OnnxModel(path, TRANSFORM, WINDOWS)
    assert (model.shape.rts_length, model.shape.channels) == (WINDOWS.rts_length, rts_schema.NUM_CHANNELS)
    assert (model.shape.psd_samples, model.shape.psd_height, model.shape.psd_width) == shape
    assert (
        model.record == record["compatibility"]
        and recorded_training(path) == RecordedTraining(FOREST_KIND, ["ideal"])
        and not model.thresholds_m
    )
    assert forest_parity(record["forest"], model) < FOREST_PARITY_TOLERANCE
    # Through the service's model: raw rows with missing values, normalised as every model's are.
    served = ServedModel.load(path, WINDOWS)
    raw = _raw_windows(5, 3)
    psd = np.zeros((*shape, 3), np.uint8)
    rows = np.arange(WINDOWS.rts_length)
    samples = [WindowSample("d", k, 0.0, raw[k], rows, psd, np.zeros(0), 0) for k in range(len(raw))]
    assert all(served.accepts(s) for s in samples)
    expected = TRANSFORM.inverse(record["forest"].predict(window_statistics(prepare_rts(raw))))
    np.testing.assert_allclose(served.estimate(samples), expected, rtol=1e-4)
    # It reads no PSD: windows formed without any (the service's, for this model) give the same estimates.
    assert not served.reads_psd
    bare = [dataclasses.replace(s, psd=NO_PSD) for s in samples]
    assert all(served.accepts(s) for s in bare)
    np.testing.assert_array_equal(served.estimate(bare), served.estimate(samples))


def test_a_forest_file_that_is_not_one_or_does_not_fit_its_record_is_refused(tmp_path):
    record = _record(trees=2)
    record["compatibility"] = {**record["compatibility"], "rts_channels": rts_schema.CHANNEL_NAMES[:3]}
    with pytest.raises(ValueError, match=r"takes \d+ features, not the 5 statistics of its 3 channels"):
        export_forest_onnx(record, tmp_path / "f.onnx", WINDOWS.rts_length, (4, 8, 8))
    garbage = tmp_path / "model.pkl"
    garbage.write_bytes(b"not a pickle")
    with pytest.raises(ModelMismatch, match="is not a random-forest model file"):
        read_forest(garbage, WINDOWS, TRANSFORM)
    garbage.write_bytes(pickle.dumps({"something": 1}))
    with pytest.raises(ModelMismatch, match="no forest and compatibility record"):
        read_forest(garbage, WINDOWS, TRANSFORM)


@pytest.mark.system
def test_seesys_estimator_export_writes_a_forest_and_checks_it_against_scikit_learn(tmp_path):
    (tmp_path / "model.pkl").write_bytes(pickle.dumps(_record(trees=3)))
    result = run_seesys("estimator", "export", str(tmp_path / "model.pkl"), "--out", str(tmp_path / "forest.onnx"))
    assert result.returncode == 0, result.stderr
    assert "parity with scikit-learn" in result.stdout and recorded_training(
        tmp_path / "forest.onnx"
    ) == RecordedTraining(FOREST_KIND, ["ideal"])
