"""DeepSEE's model, label transform, training stages, checkpoints and baselines on the tiny dataset."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pandas as pd
import pytest
import torch
from rich.progress import Progress
from test_deepsee_sessions import single_thread, tiny_config, tiny_dataset, train_context, trained_runs  # noqa: F401 (pytest fixtures among them)

from estimator.deepsee.checkpoint import ModelMismatch, load_model, save_model
from estimator.deepsee.data import read_splits, split_windows
from estimator.deepsee.inference import predict
from estimator.deepsee.model import DeepSEE
from estimator.deepsee.rows import Variant, row
from estimator.deepsee.run_folder import CONFIG_JSON, LOSS_PNG, METRICS_CSV, MODEL_PT, RunFolder
from estimator.deepsee.stages import train_row
from estimator.deepsee.transforms import LabelTransform
from seesys.io.core_settings import load_window_config

_context = train_context


def _data(tiny_dataset):
    return split_windows([tiny_dataset.root], read_splits(tiny_dataset.splits), 0)


@pytest.fixture
def trained(trained_runs):
    """DeepSEE trained through all four stages on the tiny dataset: its run folder and model file."""
    out = trained_runs / "round_0" / "deepsee"
    return out, out / MODEL_PT


def test_label_transform_round_trips():
    transform = LabelTransform(10000.0)
    errors = np.array([0.0, 1e-4, 1e-3, 0.0123, 0.5, 3.0])
    np.testing.assert_allclose(transform.inverse(transform.forward(errors)), errors, rtol=1e-12, atol=1e-15)
    assert transform.forward(0.001) == pytest.approx(np.log(11.0))
    assert transform.inverse(-1.0) == 0.0  # below zero on the transformed scale is no error at all


def test_training_runs_every_stage_and_the_losses_fall(trained):
    out, model_path = trained
    metrics = pd.read_csv(out / METRICS_CSV)
    assert list(dict.fromkeys(metrics.stage)) == ["a_psd_ssl", "b_rts_ssl", "c_supervised_frozen", "d_finetune"]
    for stage in ("a_psd_ssl", "c_supervised_frozen"):
        rows = metrics[metrics.stage == stage]
        # epoch 0 validates the starting weights; training epochs follow
        assert rows.epoch.iloc[0] == 0 and np.isnan(rows.train_loss.iloc[0]) and np.isfinite(rows.val_loss.iloc[0])
        losses = rows.train_loss.to_numpy()[1:]
        assert losses[-1] < 0.8 * losses[0], (stage, losses)
    assert (out / LOSS_PNG).stat().st_size > 1000 and model_path == out / MODEL_PT
    config = json.loads((out / CONFIG_JSON).read_text())
    assert config["row"] == "deepsee" and config["schedule"]["supervised_frozen"]["epochs"] == 8
    assert json.loads((out / "hardware.json").read_text())[0]["device"] == "cpu"


def test_trained_model_beats_predicting_the_mean(trained, tiny_dataset):
    _, model_path = trained
    transform = LabelTransform(tiny_config().label_transform.k)
    model, _ = load_model(model_path, transform)
    test = _data(tiny_dataset)["test"]
    y = transform.forward(test.error_m)
    mse = np.mean((predict(model, test, 64, torch.device("cpu")) - y) ** 2)
    assert mse < 0.7 * np.var(y)


def test_resume_skips_finished_stages_and_gives_the_same_model(trained, tiny_dataset):
    out, model_path = trained
    before = pd.read_csv(out / METRICS_CSV)
    with Progress(disable=True) as progress:
        train_row(out, row("deepsee"), _data(tiny_dataset), _context(progress))
    assert len(pd.read_csv(out / METRICS_CSV)) == len(before)  # nothing trained again
    transform = LabelTransform(tiny_config().label_transform.k)
    first, _ = load_model(model_path, transform)
    test = _data(tiny_dataset)["test"]
    np.testing.assert_allclose(predict(first, test, 64, torch.device("cpu")),
                               predict(load_model(model_path, transform)[0], test, 64, torch.device("cpu")))


def test_an_interrupted_stage_resumes_from_its_last_epoch(trained, tiny_dataset, tmp_path, monkeypatch):
    """A run killed after the first epoch of stage (d) continues from that epoch's checkpoint and ends with the
    model of the uninterrupted run."""
    out, model_path = trained
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    metrics = pd.read_csv(copy / METRICS_CSV)
    for name in ("d_finetune.pt", "d_finetune.best.pt"):
        (copy / "state" / name).unlink()
    (copy / MODEL_PT).unlink()
    (copy / METRICS_CSV).write_text(metrics[metrics.stage != "d_finetune"].to_csv(index=False))
    record = RunFolder.record

    def record_then_die(self, entry):
        record(self, entry)
        if entry.stage == "d_finetune" and entry.epoch >= 1:
            raise KeyboardInterrupt  # killed right after the first training epoch's checkpoint was written

    monkeypatch.setattr(RunFolder, "record", record_then_die)
    with Progress(disable=True) as progress, pytest.raises(KeyboardInterrupt):
        train_row(copy, row("deepsee"), _data(tiny_dataset), _context(progress))
    monkeypatch.setattr(RunFolder, "record", record)
    with Progress(disable=True) as progress:
        train_row(copy, row("deepsee"), _data(tiny_dataset), _context(progress))
    resumed = pd.read_csv(copy / METRICS_CSV)
    np.testing.assert_allclose(resumed[resumed.stage == "d_finetune"].train_loss,
                               metrics[metrics.stage == "d_finetune"].train_loss, rtol=1e-4)
    transform = LabelTransform(tiny_config().label_transform.k)
    test = _data(tiny_dataset)["test"]
    np.testing.assert_allclose(predict(load_model(copy / MODEL_PT, transform)[0], test, 64, torch.device("cpu")),
                               predict(load_model(model_path, transform)[0], test, 64, torch.device("cpu")),
                               atol=1e-4)


def test_a_model_for_other_inputs_is_refused(trained, tmp_path):
    _, model_path = trained
    transform = LabelTransform(tiny_config().label_transform.k)
    model, payload = load_model(model_path, transform)
    other_windows = dataclasses.replace(load_window_config(), rts_length=20)
    with pytest.raises(ModelMismatch, match=r"windows .*rts_length.: 30.*here .*rts_length.: 20"):
        load_model(model_path, transform, other_windows)
    with pytest.raises(ModelMismatch, match="label transform"):
        load_model(model_path, LabelTransform(1000.0))
    tampered = dict(payload, compatibility={**payload["compatibility"], "rts_schema_version": 0})
    torch.save(tampered, tmp_path / "old_schema.pt")
    with pytest.raises(ModelMismatch, match="RTS schema v0"):
        load_model(tmp_path / "old_schema.pt", transform)
    (tmp_path / "junk.pt").write_text("not a model")
    with pytest.raises(ModelMismatch, match="not a DeepSEE model file"):
        load_model(tmp_path / "junk.pt", transform)


def test_checkpoint_reload_gives_identical_outputs(tiny_dataset, tmp_path):
    config = tiny_config()
    test = _data(tiny_dataset)["test"]
    for variant in (Variant(), Variant(use_psd=False), Variant(fusion="concat", drop_psd=("inlier",))):
        torch.manual_seed(1)
        model = DeepSEE(config.model, test.input_shape(), variant).eval()
        path = save_model(tmp_path / "m.pt", model, load_window_config(), LabelTransform(10000.0), {"note": "test"})
        again, payload = load_model(path, LabelTransform(10000.0))
        assert again.variant == variant and payload["training"] == {"note": "test"}
        np.testing.assert_array_equal(predict(model, test, 64, torch.device("cpu")),
                                      predict(again, test, 64, torch.device("cpu")))


def test_ablation_masks_hide_what_they_drop(tiny_dataset):
    config = tiny_config()
    test = _data(tiny_dataset)["test"]
    torch.manual_seed(0)
    model = DeepSEE(config.model, test.input_shape(), Variant(drop_rts=("tracking",), drop_psd=("inlier",))).eval()
    rts = torch.from_numpy(test.rts[:4].copy())
    psd = torch.from_numpy(np.stack([test.psd_at(i) for i in range(4)]))
    base = model(rts, psd)
    from seesys.core import rts_schema

    changed_rts = rts.clone()
    changed_rts[..., rts_schema.index_of("matched_inliers")] += 5.0
    changed_psd = psd.clone()
    changed_psd[..., 1] = 255 - changed_psd[..., 1]
    torch.testing.assert_close(model(changed_rts, changed_psd), base)
    changed_rts[..., rts_schema.index_of("contrast")] += 1.0
    assert not torch.allclose(model(changed_rts, changed_psd), base)
