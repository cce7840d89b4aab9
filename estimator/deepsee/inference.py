"""Batched forward passes of a torch model over windows (training validation, evaluation, estimation)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from estimator.deepsee.data import Windows


def batch_tensors(windows: Windows, index: np.ndarray, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The RTS (B, T, C) float32 and PSD (B, K, H, W, 3) uint8 inputs of windows ``index``, on ``device``."""
    rts = torch.from_numpy(windows.rts[index]).to(device)
    psd = torch.from_numpy(np.stack([windows.psd_at(int(i)) for i in index])).to(device)
    return rts, psd


@torch.no_grad()
def predict(model: nn.Module, windows: Windows, batch_size: int, device: torch.device) -> np.ndarray:
    """The model's outputs (transformed scale) for every window, in eval mode; the model's mode is restored."""
    was_training = model.training
    model.eval()
    out = []
    for start in range(0, len(windows), batch_size):
        index = np.arange(start, min(start + batch_size, len(windows)))
        out.append(model(*batch_tensors(windows, index, device)).float().cpu().numpy())
    model.train(was_training)
    return np.concatenate(out) if out else np.zeros(0, np.float32)
