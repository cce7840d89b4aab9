"""Self-supervised pretraining objectives of the two encoders (paper §4.2.2, §5.4).

- PSD encoder: masked reconstruction. Half of the patches of the K_L × N patch grid (``mask_ratio``), drawn per
  window, have their embedding replaced by the encoder's mask token; a decoder of two fully connected layers
  reconstructs every patch's cells from the encoder's output token, and the loss is the MSE on the masked patches.
- RTS encoder: TS2Vec (Yue et al. 2022). Two overlapping random crops of each window are encoded, each with its
  own random timestamp mask on the latent; the hierarchical contrastive loss compares their representations on
  the overlap: at every scale (max-pooled by 2 until one step is left) an instance-wise term (the same time step
  of the other view against the other windows of the batch) and a temporal term (the same time step of the other
  view against the other time steps of the window), weighted ``alpha`` and ``1 − alpha``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from estimator.deepsee.model import PsdEncoder, RtsEncoder


def patchify(psd: torch.Tensor, patch: int) -> torch.Tensor:
    """(B, K, 3, H, W) → (B, K, N, 3·patch²), patches in the patch embedding's row-major order."""
    b, k, c, h, w = psd.shape
    x = psd.reshape(b, k, c, h // patch, patch, w // patch, patch)
    return x.permute(0, 1, 3, 5, 2, 4, 6).reshape(b, k, (h // patch) * (w // patch), c * patch * patch)


def random_patch_mask(batch: int, frames: int, patches: int, ratio: float, generator: torch.Generator) -> torch.Tensor:
    """(B, K, N) bool, exactly round(ratio · K · N) True per window, chosen uniformly."""
    total = frames * patches
    count = int(round(ratio * total))
    order = torch.rand(batch, total, generator=generator).argsort(dim=1)
    mask = torch.zeros(batch, total, dtype=torch.bool)
    mask.scatter_(1, order[:, :count], True)
    return mask.reshape(batch, frames, patches)


class PsdReconstruction(nn.Module):
    """The PSD encoder with its two-layer reconstruction decoder."""

    def __init__(self, encoder: PsdEncoder, dim: int):
        super().__init__()
        self.encoder = encoder
        self.decoder = nn.Sequential(nn.Linear(dim, dim), nn.GELU(), nn.Linear(dim, 3 * encoder.patch**2))

    def loss(self, psd: torch.Tensor, ratio: float, generator: torch.Generator) -> torch.Tensor:
        """MSE on the masked patches of ``psd`` (B, K, 3, H, W) in [0, 1]."""
        b, k = psd.shape[:2]
        mask = random_patch_mask(b, k, self.encoder.patches, ratio, generator).to(psd.device)
        tokens, _ = self.encoder(psd, mask)
        error = (self.decoder(tokens) - patchify(psd, self.encoder.patch)) ** 2
        return error[mask].mean()


def _randint(low: int, high: int, generator: torch.Generator, size: tuple[int, ...] = ()) -> torch.Tensor:
    """Uniform integers in [low, high)."""
    return torch.randint(low, high, size, generator=generator)


def _take(x: torch.Tensor, starts: torch.Tensor, length: int) -> torch.Tensor:
    """Per row b, the steps starts[b] … starts[b] + length − 1 of x (B, T, C)."""
    steps = starts.to(x.device).unsqueeze(1) + torch.arange(length, device=x.device)
    return x.gather(1, steps.unsqueeze(-1).expand(-1, -1, x.shape[2]))


def _keep_mask(batch: int, length: int, probability: float, generator: torch.Generator, device) -> torch.Tensor:
    """TS2Vec's binomial timestamp mask: each step kept with probability 1 − ``probability``."""
    return (torch.rand(batch, length, generator=generator) >= probability).to(device)


def instance_loss(z1: torch.Tensor, z2: torch.Tensor) -> torch.Tensor:
    """At each time step, each window's other view is the positive among the 2B − 1 other representations."""
    b = z1.shape[0]
    if b == 1:
        return z1.new_zeros(())
    z = torch.cat([z1, z2], dim=0).transpose(0, 1)  # (T, 2B, C)
    return _contrast(z, b)


def temporal_loss(z1: torch.Tensor, z2: torch.Tensor) -> torch.Tensor:
    """In each window, a time step's other view is the positive among the 2T − 1 other time steps."""
    t = z1.shape[1]
    if t == 1:
        return z1.new_zeros(())
    return _contrast(torch.cat([z1, z2], dim=1), t)


def _contrast(z: torch.Tensor, half: int) -> torch.Tensor:
    """Mean negative log-softmax of the positive pairs (i, i ± half) over dot-product similarities, self excluded."""
    n = z.shape[1]
    similarity = z @ z.transpose(1, 2)
    eye = torch.eye(n, dtype=torch.bool, device=z.device)
    log_p = F.log_softmax(similarity.masked_fill(eye, float("-inf")), dim=-1)
    rows = torch.arange(n, device=z.device)
    positives = (rows + half) % n
    return -log_p[:, rows, positives].mean()


def hierarchical_loss(z1: torch.Tensor, z2: torch.Tensor, alpha: float) -> torch.Tensor:
    """Instance and temporal terms at every max-pooled scale; at length one only the instance term."""
    loss = z1.new_zeros(())
    levels = 0
    while z1.shape[1] > 1:
        loss = loss + alpha * instance_loss(z1, z2) + (1 - alpha) * temporal_loss(z1, z2)
        levels += 1
        z1 = F.max_pool1d(z1.transpose(1, 2), kernel_size=2).transpose(1, 2)
        z2 = F.max_pool1d(z2.transpose(1, 2), kernel_size=2).transpose(1, 2)
    loss = loss + alpha * instance_loss(z1, z2)
    return loss / (levels + 1)


def ts2vec_loss(
    encoder: RtsEncoder, x: torch.Tensor, alpha: float, mask_probability: float, generator: torch.Generator
) -> torch.Tensor:
    """TS2Vec's loss on a batch of RTS windows ``x`` (B, T, C): two overlapping crops with random offsets."""
    b, t = x.shape[:2]
    overlap = int(_randint(2, t + 1, generator))
    left = int(_randint(0, t - overlap + 1, generator))
    right = left + overlap
    outer_left = int(_randint(0, left + 1, generator))
    outer_right = int(_randint(right, t + 1, generator))
    offsets = _randint(-outer_left, t - outer_right + 1, generator, (b,))
    view1 = _take(x, offsets + outer_left, right - outer_left)
    view2 = _take(x, offsets + left, outer_right - left)
    z1 = encoder(view1, _keep_mask(b, view1.shape[1], mask_probability, generator, x.device))[:, -overlap:]
    z2 = encoder(view2, _keep_mask(b, view2.shape[1], mask_probability, generator, x.device))[:, :overlap]
    return hierarchical_loss(z1, z2, alpha)
