"""DeepSEE's ordinal head: Equation 2's class boundaries, monotone probabilities, its training, the record, the ONNX
export and the predictor; the shipped model's head in both its files."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
import torch
from testkit.deepsee import PSD_SHAPE, tiny_config

from estimator.artefact.compatibility import InputShape
from estimator.artefact.onnx_model import OnnxModel
from estimator.artefact.transforms import LabelTransform
from estimator.dataset.splits import read_splits
from estimator.deepsee.checkpoint import load_model, save_model
from estimator.deepsee.data import split_windows
from estimator.deepsee.export import PARITY_TOLERANCE, export_onnx, parity
from estimator.deepsee.inference import predict_outputs
from estimator.deepsee.metrics import equation2_head, score
from estimator.deepsee.model import DeepSEE
from estimator.deepsee.ordinal import bce, exceeded, head_thresholds
from estimator.deepsee.predictors import load_predictor
from seesys.core import rts_schema
from seesys.core.equation2 import PulseSettings
from seesys.core.exceedance import class_boundaries_m, head_class, same_thresholds
from seesys.io.core_settings import load_pulse_settings, load_window_config
from seesys.io.resources import resolve

pytestmark = pytest.mark.usefixtures("single_thread")

TRANSFORM = LabelTransform(10000.0)
BOUNDS = (0.004, 0.008, 0.012)


def _pulses(**equation2) -> PulseSettings:
    pulses = load_pulse_settings()
    return dataclasses.replace(pulses, equation2=dataclasses.replace(pulses.equation2, **equation2))


@pytest.mark.parametrize(
    "settings, expected",
    [
        ({}, BOUNDS),
        ({"alpha_m": 0.002}, BOUNDS),  # floor(250 * e) is still 0 below 4 mm
        ({"alpha_m": 0.005}, (0.005, 0.008, 0.012)),
        ({"beta_m": 0.010}, (0.004, 0.008, 0.010)),
        ({"pulses_per_metre": 300.0}, (0.004, 0.006666667, 0.01)),  # 2 / 300 rounded up to the 1 nm resolution
    ],
)
def test_class_boundaries_are_where_equation_2_adds_a_pulse(settings, expected):
    pulses = _pulses(**settings)
    bounds = class_boundaries_m(pulses)
    assert bounds == pytest.approx(expected, abs=1e-12)
    step = pulses.equation2.error_resolution_m
    for n, bound in enumerate(bounds, start=1):
        assert pulses.pulses(bound) >= n > pulses.pulses(bound - step)


def test_the_head_class_counts_the_exceeded_thresholds_and_thresholds_match_in_float32():
    assert list(head_class(np.array([[0.2, 0.1, 0.0], [0.5, 0.4, 0.1], [0.9, 0.7, 0.5], [1.0, 0.6, 0.49]]))) == [
        0,
        1,
        3,
        2,
    ]
    assert same_thresholds(np.float32(BOUNDS).tolist(), BOUNDS)
    assert not same_thresholds((0.004, 0.008), BOUNDS) and not same_thresholds((0.004, 0.009, 0.012), BOUNDS)


def _tiny_model(thresholds=BOUNDS, seed=0) -> DeepSEE:
    torch.manual_seed(seed)
    shape = InputShape(
        load_window_config().rts_length, rts_schema.NUM_CHANNELS, load_window_config().psd_samples, *PSD_SHAPE
    )
    return DeepSEE(tiny_config().model, shape, thresholds_m=thresholds).eval()


def test_the_heads_probabilities_are_monotone_whatever_the_weights():
    model = _tiny_model()
    with torch.no_grad():
        for p in model.ordinal.parameters():
            p.normal_(0, 1.0)  # random weights: offsets of every sign before the softplus
        rts = torch.randn(64, model.shape.rts_length, model.shape.channels) * 3
        psd = torch.randint(0, 256, (64, model.shape.psd_samples, *PSD_SHAPE, 3), dtype=torch.uint8)
        y, logits = model(rts, psd)
    probabilities = torch.sigmoid(logits)
    assert y.shape == (64,) and probabilities.shape == (64, 3)
    assert (probabilities[:, :-1] >= probabilities[:, 1:]).all()
    assert probabilities.std(dim=0).min() > 0  # not constant: the test would pass for a dead head


def test_thresholds_follow_the_config_and_a_model_without_a_head_stays_one(tmp_path):
    config = tiny_config()
    assert head_thresholds(config) == class_boundaries_m(load_pulse_settings()) == BOUNDS
    off = dataclasses.replace(config, ordinal_head=dataclasses.replace(config.ordinal_head, enabled=False))
    assert head_thresholds(off) == ()
    plain = _tiny_model(thresholds=())
    path = save_model(tmp_path / "plain.pt", plain, load_window_config(), TRANSFORM, {})
    payload = torch.load(path, weights_only=False)
    assert "ordinal_head" not in payload["compatibility"] and "ordinal_thresholds_m" not in payload["model"]
    assert not isinstance(load_model(path, TRANSFORM)[0](*_inputs(plain, 2)), tuple)
    headed = save_model(tmp_path / "head.pt", _tiny_model(), load_window_config(), TRANSFORM, {})
    assert torch.load(headed, weights_only=False)["compatibility"]["ordinal_head"] == {"thresholds_m": list(BOUNDS)}
    assert load_model(headed, TRANSFORM)[0].thresholds_m == BOUNDS


def _inputs(model: DeepSEE, batch: int):
    g = torch.Generator().manual_seed(3)
    return (
        torch.randn(batch, model.shape.rts_length, model.shape.channels, generator=g),
        torch.randint(0, 256, (batch, model.shape.psd_samples, *PSD_SHAPE, 3), dtype=torch.uint8, generator=g),
    )


@pytest.mark.system
def test_training_lowers_the_heads_bce(trained_runs, tiny_dataset):
    """The trained DeepSEE's head (stages (c) and (d) on MSE + λ·BCE) against the same model untrained and against the
    test windows' own base rates as a constant (a yardstick no initialisation can flatter)."""
    trained, _ = load_model(trained_runs / "round_0" / "deepsee" / "model.pt", TRANSFORM)
    assert trained.thresholds_m == BOUNDS
    test = split_windows([tiny_dataset.root], read_splits(tiny_dataset.splits, [tiny_dataset.root]), 0)["test"]
    targets = exceeded(test.error_m, BOUNDS)
    assert 0 < targets[:, 0].mean() < 1  # both sides of 4 mm among the test windows
    torch.manual_seed(0)  # the untrained model's weights: not whatever the tests before left in the generator
    untrained = DeepSEE(trained.config, trained.shape, trained.variant, BOUNDS)
    cpu = torch.device("cpu")
    before = bce(predict_outputs(untrained, test, 64, cpu)[1], targets)
    after = bce(predict_outputs(trained, test, 64, cpu)[1], targets)
    constant = bce(np.tile(targets.mean(axis=0), (len(targets), 1)), targets)
    assert after < min(before, constant), (before, constant, after)
    ablation = load_model(trained_runs / "round_0" / "wo_psd" / "model.pt", TRANSFORM)[0]
    assert ablation.thresholds_m == BOUNDS  # the ablations are DeepSEE too
    lstm = load_predictor(trained_runs / "round_0" / "lstm" / "model.pt", TRANSFORM, 64)
    assert lstm.thresholds_m == () and lstm.estimates(test).probabilities is None


@pytest.mark.system
def test_onnx_export_has_the_probabilities_and_matches_pytorch(trained_runs, tiny_dataset, tmp_path):
    path = trained_runs / "round_0" / "deepsee" / "model.pt"
    model, payload = load_model(path, TRANSFORM)
    exported = export_onnx(model, tmp_path / "head.onnx", load_window_config(), TRANSFORM, payload["compatibility"])
    onnx_model = OnnxModel(exported, TRANSFORM)
    assert onnx_model.thresholds_m == BOUNDS
    assert [o.name for o in onnx_model.session.get_outputs()] == ["y", "probabilities"]
    assert parity(model, onnx_model) <= PARITY_TOLERANCE
    # The parity check covers the probabilities: another head's weights are a difference.
    other = load_model(path, TRANSFORM)[0]
    with torch.no_grad():
        other.ordinal.first.bias += 0.5
    assert parity(other, onnx_model) > 0.01
    test = split_windows([tiny_dataset.root], read_splits(tiny_dataset.splits, [tiny_dataset.root]), 0)["test"]
    from_torch = load_predictor(path, TRANSFORM, 64).estimates(test)
    from_onnx = load_predictor(exported, TRANSFORM, 64).estimates(test)
    assert from_onnx.probabilities.shape == (len(test), 3)
    np.testing.assert_allclose(from_onnx.probabilities, from_torch.probabilities, atol=1e-4)
    np.testing.assert_allclose(from_onnx.metres, from_torch.metres, rtol=1e-3, atol=1e-7)


def test_the_shipped_model_has_the_head_in_both_files_and_they_agree():
    """data/models/deepsee.pt and .onnx carry the ordinal head at Equation 2's boundaries: the same thresholds in
    both records, the probabilities as the graph's second output (monotone over the thresholds), and the checkpoint
    (what finetune starts from) gives the exported graph's outputs on every RTS channel it takes."""
    from estimator.deepsee.export import example_inputs

    payload = torch.load(resolve("data/models/deepsee.pt"), map_location="cpu", weights_only=False)
    assert tuple(payload["model"]["ordinal_thresholds_m"]) == BOUNDS
    assert tuple(payload["compatibility"]["ordinal_head"]["thresholds_m"]) == BOUNDS
    onnx_model = OnnxModel(resolve("data/models/deepsee.onnx"), TRANSFORM)
    assert onnx_model.thresholds_m == BOUNDS
    assert [o.name for o in onnx_model.session.get_outputs()] == ["y", "probabilities"]
    assert load_predictor(resolve("data/models/deepsee.onnx"), TRANSFORM, 64).thresholds_m == BOUNDS
    model, _ = load_model(resolve("data/models/deepsee.pt"), TRANSFORM)
    channels = payload["compatibility"][
        "rts_channels"
    ]  # the schema's channels when it was trained (a prefix of today's)
    assert model.rts_mask.shape == (onnx_model.shape.channels,) == (len(channels),)
    assert tuple(channels) == rts_schema.CHANNEL_NAMES[: len(channels)]
    assert parity(model, onnx_model) <= PARITY_TOLERANCE
    rts, psd = example_inputs(onnx_model.shape, 3)
    y, probabilities = onnx_model.outputs(rts.numpy(), psd.numpy())
    assert y.shape == (3,) and probabilities.shape == (3, len(BOUNDS))
    assert (np.diff(probabilities, axis=1) <= 1e-6).all()  # P(e ≥ 4 mm) ≥ P(e ≥ 8 mm) ≥ P(e ≥ 12 mm)


def test_scores_judge_the_heads_class_beside_the_estimates():
    """Two runs of 1/3 s bins: the head's class is that of its probabilities averaged over a bin."""
    pulses = load_pulse_settings()
    t = np.array([0.0, 0.1, 0.2, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2])  # bins of 0.33 s: 3 windows each
    meta = pd.DataFrame({"run": ["a"] * 12, "timestamp": t})
    true_m = np.repeat([0.002, 0.006, 0.010, 0.020], 3)
    estimate_m = 0.007 + 1e-6 * np.arange(12)  # the middle: agrees with the truth in one bin of four
    right = np.array([[0.1, 0.0, 0.0], [0.9, 0.1, 0.0], [0.9, 0.8, 0.1], [0.9, 0.9, 0.9]])
    probabilities = np.repeat(right, 3, axis=0)
    evaluation = tiny_config().evaluation
    plain = score(meta, estimate_m, true_m, evaluation, pulses)
    assert np.isnan(plain.head_agreement) and np.isnan(plain.head_recall_large)
    scores = score(meta, estimate_m, true_m, evaluation, pulses, probabilities)
    assert scores.bins == 4 and scores.agreement == 0.25 and scores.recall_large == 0.0
    assert scores.head_agreement == 1.0 and scores.head_recall_large == 1.0
    assert equation2_head(probabilities, BOUNDS, pulses) is probabilities
    assert equation2_head(probabilities, (0.004, 0.008, 0.016), pulses) is None
    assert equation2_head(None, BOUNDS, pulses) is None
