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
from testkit.deepsee import tiny_config, train_context

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.splits import read_splits
from estimator.deepsee.checkpoint import ModelMismatch, load_model, save_model
from estimator.deepsee.data import split_windows
from estimator.deepsee.inference import batch_tensors, predict
from estimator.deepsee.model import DeepSEE
from estimator.deepsee.rows import Variant, row
from estimator.deepsee.run_folder import CONFIG_JSON, LOSS_PNG, METRICS_CSV, MODEL_PT, RunFolder
from estimator.deepsee.stages import train_row
from seesys.core import rts_schema
from seesys.io.core_settings import load_window_config

pytestmark = pytest.mark.usefixtures("single_thread")

_context = train_context


def _data(tiny_dataset):
    return split_windows([tiny_dataset.root], read_splits(tiny_dataset.splits, [tiny_dataset.root]), 0)


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


@pytest.mark.system
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


@pytest.mark.system
def test_trained_model_beats_predicting_the_mean(trained, tiny_dataset):
    _, model_path = trained
    transform = LabelTransform(tiny_config().label_transform.k)
    model, _ = load_model(model_path, transform)
    test = _data(tiny_dataset)["test"]
    y = transform.forward(test.error_m)
    mse = np.mean((predict(model, test, 64, torch.device("cpu")) - y) ** 2)
    assert mse < 0.7 * np.var(y)


@pytest.mark.system
def test_resume_skips_finished_stages_and_gives_the_same_model(trained, tiny_dataset):
    out, model_path = trained
    before = pd.read_csv(out / METRICS_CSV)
    with Progress(disable=True) as progress:
        train_row(out, row("deepsee"), _data(tiny_dataset), _context(progress))
    assert len(pd.read_csv(out / METRICS_CSV)) == len(before)  # nothing trained again
    transform = LabelTransform(tiny_config().label_transform.k)
    first, _ = load_model(model_path, transform)
    test = _data(tiny_dataset)["test"]
    np.testing.assert_allclose(
        predict(first, test, 64, torch.device("cpu")),
        predict(load_model(model_path, transform)[0], test, 64, torch.device("cpu")),
    )


@pytest.mark.system
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
    np.testing.assert_allclose(
        resumed[resumed.stage == "d_finetune"].train_loss, metrics[metrics.stage == "d_finetune"].train_loss, rtol=1e-4
    )
    transform = LabelTransform(tiny_config().label_transform.k)
    test = _data(tiny_dataset)["test"]
    np.testing.assert_allclose(
        predict(load_model(copy / MODEL_PT, transform)[0], test, 64, torch.device("cpu")),
        predict(load_model(model_path, transform)[0], test, 64, torch.device("cpu")),
        atol=1e-4,
    )


@pytest.mark.system
def test_a_model_for_other_inputs_is_refused(trained, tmp_path):
    _, model_path = trained
    transform = LabelTransform(tiny_config().label_transform.k)
    model, payload = load_model(model_path, transform)
    other_windows = dataclasses.replace(load_window_config(), rts_length=20)
    with pytest.raises(ModelMismatch, match=r"windows.rts_length: model 30, here 20"):
        load_model(model_path, transform, other_windows)
    with pytest.raises(ModelMismatch, match="label transform"):
        load_model(model_path, LabelTransform(1000.0))
    record = payload["compatibility"]
    tampered = dict(payload, compatibility={**record, "rts_channels": [*record["rts_channels"], "sonar_range"]})
    torch.save(tampered, tmp_path / "other_schema.pt")
    with pytest.raises(ModelMismatch, match="RTS channels .*does not have: sonar_range"):
        load_model(tmp_path / "other_schema.pt", transform)
    (tmp_path / "junk.pt").write_text("not a model")
    with pytest.raises(ModelMismatch, match="not a DeepSEE model file"):
        load_model(tmp_path / "junk.pt", transform)


@pytest.mark.system
def test_checkpoint_reload_gives_identical_outputs(tiny_dataset, tmp_path):
    config = tiny_config()
    test = _data(tiny_dataset)["test"]
    for variant in (Variant(), Variant(use_psd=False), Variant(fusion="concat", drop_psd=("inlier",))):
        torch.manual_seed(1)
        model = DeepSEE(config.model, test.input_shape(), variant).eval()
        path = save_model(tmp_path / "m.pt", model, load_window_config(), LabelTransform(10000.0), {"note": "test"})
        again, payload = load_model(path, LabelTransform(10000.0))
        assert again.variant == variant and payload["training"] == {"note": "test"}
        np.testing.assert_array_equal(
            predict(model, test, 64, torch.device("cpu")), predict(again, test, 64, torch.device("cpu"))
        )


@pytest.mark.system
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


def test_the_geometry_ablation_hides_the_ten_geometry_channels_and_nothing_else():
    from estimator.artefact.transforms import rts_channel_mask
    from estimator.deepsee.rows import row
    from seesys.core import rts_schema

    mask = rts_channel_mask(row("wo_geometry").variant.drop_rts)
    hidden = [name for name, seen in zip(rts_schema.CHANNEL_NAMES, mask) if not seen]
    # v4's nine, after v3's nineteen, and v5's residual shear
    assert hidden == list(rts_schema.CHANNEL_NAMES[19:]) and len(hidden) == 10


def _random_windows(seed: int, count: int):
    from testkit.deepsee import PSD_SHAPE

    from estimator.deepsee.data import Windows
    from seesys.core import rts_schema

    rng = np.random.default_rng(seed)
    windows = load_window_config()
    rts = rng.normal(size=(count, windows.rts_length, rts_schema.NUM_CHANNELS)).astype(np.float32)
    psd = rng.integers(0, 256, size=(count, windows.psd_samples, *PSD_SHAPE, 3), dtype=np.uint8)
    meta = pd.DataFrame({"run": f"r{seed}", "frame_index": np.arange(count), "timestamp": np.arange(count) / 30})
    return Windows(rts, psd, np.full(count, 0.01), meta)


@pytest.mark.system
def test_the_encoder_cache_is_reused_only_for_the_same_encoders_and_windows(tmp_path):
    """Stage (c)'s cache of the frozen encoders' outputs: the same windows and encoders read it back without encoding
    again; other windows of the same count, or encoders trained again, are encoded afresh."""
    from estimator.deepsee.stages import _cached_encodings, _Views

    as_is = _Views(1)
    first, other = _random_windows(1, 40), _random_windows(2, 40)
    with Progress(disable=True) as progress:
        ctx = _context(progress)
        model = DeepSEE(ctx.config.model, first.input_shape())
        run = RunFolder(tmp_path / "run", {"test": "cache"}, torch.device("cpu"))
        calls = []
        encode = model.encode
        model.encode = lambda *a: calls.append(1) or encode(*a)

        def fresh(windows):
            with torch.no_grad():
                model.eval()
                r, p = encode(*batch_tensors(windows, np.arange(len(windows)), torch.device("cpu"), True))
                model.train()
            return r.numpy().astype(np.float16), p.numpy().astype(np.float16)

        r1 = np.array(_cached_encodings(run, model, first, "train", ctx, as_is)[0][0])
        encoded = len(calls)
        assert encoded > 0
        again = _cached_encodings(run, model, first, "train", ctx, as_is)
        assert len(calls) == encoded  # read back, not encoded again
        np.testing.assert_array_equal(again[0][0], r1)
        r2, p2 = (np.array(a[0]) for a in _cached_encodings(run, model, other, "train", ctx, as_is))
        assert len(calls) > encoded
        np.testing.assert_allclose(r2, fresh(other)[0], atol=1e-3)
        np.testing.assert_allclose(p2, fresh(other)[1], atol=1e-3)
        assert not np.allclose(np.asarray(r2, np.float32), np.asarray(r1, np.float32))
        with torch.no_grad():  # the encoders trained again (e.g. another pretrained run folder)
            for parameter in model.rts_encoder.parameters():
                parameter.add_(0.05)
        r3 = np.array(_cached_encodings(run, model, other, "train", ctx, as_is)[0][0])
        np.testing.assert_allclose(r3, fresh(other)[0], atol=1e-3)
        assert not np.allclose(np.asarray(r3, np.float32), np.asarray(r2, np.float32))


@pytest.mark.system
def test_augmentation_reaches_every_training_stage(tmp_path, monkeypatch):
    """The PSD reconstruction (a), TS2Vec (b), the frozen-encoder stage (c) through its cache of augmented draws, and
    stage (d) all train on augmented windows; validation sees the windows as they are."""
    import sys

    from estimator.deepsee import stages
    from estimator.deepsee.augment import Augmenter

    callers = []

    class Recording(Augmenter):
        def __call__(self, rts, psd, generator):
            callers.append(sys._getframe(1).f_code.co_qualname)
            return super().__call__(rts, psd, generator)

    monkeypatch.setattr(stages, "Augmenter", Recording)
    with Progress(disable=True) as progress:
        ctx = _context(progress)
        train_row(
            tmp_path / "run",
            row("deepsee"),
            {"train": _random_windows(1, 48), "validation": _random_windows(2, 16)},
            ctx,
        )
    assert {"_psd_ssl.<locals>.step", "_rts_ssl.<locals>.step", "_cached_encodings", "supervised.<locals>.step"} <= set(
        callers
    ), set(callers)
    views = ctx.config.augmentation.frozen_stage_views
    cached = np.load(tmp_path / "run" / "state" / "cache_train_rts.npy")
    assert views > 1 and cached.shape[:2] == (views, 48)
    assert not np.array_equal(cached[0], cached[1])  # each view another draw
    assert np.load(tmp_path / "run" / "state" / "cache_validation_rts.npy").shape[0] == 1  # as it is


@pytest.mark.parametrize(
    ("row_name", "dropped"),
    [
        ("random_forest_wo_geometry", lambda c: c.category in rts_schema.GEOMETRY_CATEGORIES),
        ("random_forest_wo_shear", lambda c: c.name == "residual_shear"),
    ],
)
def test_a_forest_ablation_takes_only_the_channels_it_keeps(tiny_dataset, tmp_path, row_name, dropped):
    from estimator.artefact.compatibility import rts_columns
    from estimator.deepsee.predictors import load_predictor

    data = _data(tiny_dataset)
    with Progress(disable=True) as progress:
        path = train_row(tmp_path / "forest", row(row_name), data, _context(progress))
    predictor = load_predictor(
        path, LabelTransform(tiny_config().label_transform.k), 64, torch.device("cpu"), load_window_config()
    )
    hidden = [c.name for c in rts_schema.CHANNELS if dropped(c)]
    assert hidden and len(hidden) < rts_schema.NUM_CHANNELS
    assert [rts_schema.CHANNEL_NAMES[c] for c in rts_columns(predictor.record)] == [
        name for name in rts_schema.CHANNEL_NAMES if name not in hidden
    ]
    # Its estimates do not move when the hidden channels do.
    test = data["test"]
    changed = test.rts.copy()
    changed[..., [rts_schema.index_of(name) for name in hidden]] += 3.0
    np.testing.assert_array_equal(predictor.estimates(test).metres, predictor.estimates(test.with_rts(changed)).metres)
