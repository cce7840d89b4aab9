"""Batched forward passes of a torch model over windows (training validation, evaluation, estimation)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from estimator.deepsee.data import Windows
from estimator.deepsee.model import exceedance_probabilities


def uses_psd(model: nn.Module) -> bool:
    """False for the models of the RTS window only (the LSTM, DeepSEE w/o PSD): their PSD input is not read."""
    return getattr(model, "psd_encoder", None) is not None


def batch_tensors(
    windows: Windows, index: np.ndarray, device: torch.device, with_psd: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """The RTS (B, T, C) float32 and PSD (B, K, H, W, 3) uint8 inputs of windows ``index``, on ``device``; without
    ``with_psd`` an empty PSD tensor (the matrices are the large part to read)."""
    rts = torch.from_numpy(windows.rts[index]).to(device)
    if not with_psd:
        return rts, torch.zeros((len(index), 0), dtype=torch.uint8, device=device)
    psd = torch.from_numpy(np.stack([windows.psd_at(int(i)) for i in index])).to(device)
    return rts, psd


@torch.no_grad()
def predict_outputs(
    model: nn.Module, windows: Windows, batch_size: int, device: torch.device
) -> tuple[np.ndarray, np.ndarray | None]:
    """The model's transformed-scale outputs (N,) for every window, and its head's probabilities P(error ≥ t_k)
    (N, K) (None for a model without a head); in eval mode, the model's mode restored."""
    was_training = model.training
    model.eval()
    ys, probabilities = [], []
    for start in range(0, len(windows), batch_size):
        index = np.arange(start, min(start + batch_size, len(windows)))
        out = model(*batch_tensors(windows, index, device, uses_psd(model)))
        if isinstance(out, tuple):
            out, logits = out
            probabilities.append(exceedance_probabilities(logits).float().cpu().numpy())
        ys.append(out.float().cpu().numpy())
    model.train(was_training)
    thresholds = len(getattr(model, "thresholds_m", ()))
    y = np.concatenate(ys) if ys else np.zeros(0, np.float32)
    if not thresholds:
        return y, None
    return y, np.concatenate(probabilities) if probabilities else np.zeros((0, thresholds), np.float32)


def predict(model: nn.Module, windows: Windows, batch_size: int, device: torch.device) -> np.ndarray:
    """The model's outputs (transformed scale) for every window (:func:`predict_outputs` without the head)."""
    return predict_outputs(model, windows, batch_size, device)[0]
