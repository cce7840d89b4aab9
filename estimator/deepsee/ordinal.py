"""DeepSEE's ordinal head in training: its thresholds (Equation 2's class boundaries), its targets and the loss
``MSE(y) + λ · BCE(head)`` that stages (c) and (d) and fine-tuning minimise (λ: ``[ordinal_head] bce_weight`` of
configs/estimator.toml). A model without a head (the LSTM, a DeepSEE trained before the head) is trained on the
MSE alone, as before."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from estimator.deepsee.config import EstimatorConfig
from seesys.core.equation2 import PulseSettings
from seesys.core.errors import ConfigError
from seesys.core.exceedance import class_boundaries_m
from seesys.io.core_settings import load_pulse_settings

# Probabilities are clipped this far from 0 and 1 before the logarithm of the validation BCE: the model's float32
# sigmoid reaches exactly 1.
_CLIP = 1e-7


def head_thresholds(config: EstimatorConfig, pulses: PulseSettings | None = None) -> tuple[float, ...]:
    """The thresholds a new DeepSEE's head gets: Equation 2's class boundaries (``pulses``: configs/advisory.toml
    by default), or none when ``[ordinal_head] enabled`` is false. Raises ``ConfigError`` when two boundaries
    coincide (an empty class): the head's probabilities would be of one threshold twice."""
    if not config.ordinal_head.enabled:
        return ()
    bounds = class_boundaries_m(pulses or load_pulse_settings())
    if len(set(bounds)) != len(bounds):
        raise ConfigError(
            f"Equation 2's class boundaries {[b * 1000 for b in bounds]} mm repeat one (an empty "
            f"class): the ordinal head needs distinct ones; set [ordinal_head] enabled = false or "
            f"change [equation2] of configs/advisory.toml"
        )
    return bounds


def model_thresholds(model: nn.Module) -> tuple[float, ...]:
    """The head's thresholds of ``model``; empty for a model without a head (the LSTM, an older DeepSEE)."""
    return tuple(getattr(model, "thresholds_m", ()))


def exceeded(error_m: np.ndarray, thresholds_m: tuple[float, ...]) -> np.ndarray:
    """(N, K) float32 targets of the head: 1 where the true error is at least the threshold."""
    return (np.asarray(error_m, np.float64)[:, None] >= np.asarray(thresholds_m, np.float64)[None, :]).astype(
        np.float32
    )


def training_loss(
    outputs: torch.Tensor | tuple[torch.Tensor, torch.Tensor],
    y: torch.Tensor,
    targets: torch.Tensor | None,
    weight: float,
) -> torch.Tensor:
    """MSE of the transformed error, plus ``weight`` × the head's BCE (on its logits) when ``outputs`` has one.
    Raises ``ValueError`` when the model has a head but no targets were made for it."""
    if not isinstance(outputs, tuple):
        return nn.functional.mse_loss(outputs, y)
    if targets is None:
        raise ValueError("the model has an ordinal head but no head targets were given")
    estimate, logits = outputs
    return nn.functional.mse_loss(estimate, y) + weight * nn.functional.binary_cross_entropy_with_logits(
        logits, targets
    )


def bce(probabilities: np.ndarray, targets: np.ndarray) -> float:
    """Mean binary cross-entropy of probabilities (N, K) against 0/1 targets."""
    p = np.clip(np.asarray(probabilities, np.float64), _CLIP, 1 - _CLIP)
    return float(-np.mean(targets * np.log(p) + (1 - targets) * np.log1p(-p)))


def validation_loss(
    y: np.ndarray, probabilities: np.ndarray | None, y_true: np.ndarray, targets: np.ndarray | None, weight: float
) -> float:
    """:func:`training_loss` of a whole validation set, from the model's probabilities (numpy)."""
    mse = float(np.mean((y - y_true) ** 2))
    if probabilities is None or targets is None:
        return mse
    return mse + weight * bce(probabilities, targets)
