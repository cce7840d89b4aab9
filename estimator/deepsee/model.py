"""DeepSEE (paper §4.2), written from the papers it builds on: TimeSformer's divided space–time attention for the
PSD window, TS2Vec's dilated-convolution encoder for the RTS window, bidirectional multi-head cross-attention
fusion, and an MLP head that outputs the transformed error ``log(1 + k · RPE)``; optionally an ordinal head beside
it (:class:`OrdinalHead`: the logits of P(RPE ≥ t_k) for Equation 2's class boundaries t_k, docs/estimator.md).

Inputs of :meth:`DeepSEE.forward`:

- ``rts``: (B, T, C) float32, the RTS window normalised by :func:`seesys.core.rts_schema.normalise`;
- ``psd``: (B, K_L, H, W, 3) uint8, the PSD matrices as stored (scaled to [0, 1] inside the model).

Differences from the authors' model (docs/estimator.md): a smaller PSD encoder (patch 16 over the 96×128 matrix,
so 48 patches per matrix, width 128, depth 4; theirs is patch 8, 192 patches, width 192) so that one window costs
a few milliseconds on one CPU core; each PSD matrix becomes one token (the mean of its patch tokens) plus the
class token, instead of flattening all patch tokens through one 36,864 → 128 layer (two thirds of their
parameters, and it fixes T and K_L); the cross-attention layers have residual paths and feed-forward blocks
(theirs have neither); the RTS encoder is part of the model and exported with it (theirs runs TS2Vec separately).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from estimator.artefact.compatibility import InputShape
from estimator.artefact.transforms import psd_layer_mask, rts_channel_mask
from estimator.deepsee.config import FusionConfig, ModelConfig, PsdEncoderConfig, RtsEncoderConfig
from estimator.deepsee.rows import Variant


class TokenLinear(nn.Linear):
    """``nn.Linear`` applied to the tokens flattened to one matrix: exported to ONNX as one Gemm with its bias
    inside, instead of a batched MatMul and a separate Add (ONNX Runtime fuses the bias only in two dimensions)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.linear(x.reshape(-1, x.shape[-1]), self.weight, self.bias).reshape(*x.shape[:-1], -1)


class Attention(nn.Module):
    """Multi-head attention of queries ``x`` over keys/values ``context`` (self-attention when it is ``x``).

    Written out (scaled product, softmax, weighted sum) rather than with ``F.scaled_dot_product_attention``: the
    ONNX exporter decomposes that one into about a dozen shape computations per call, a sixth of the exported
    graph's nodes. Every reshape leaves the batch as ``-1`` for the same reason: a batch size read from the input
    costs Shape, Slice and Concat nodes at every use."""

    def __init__(self, dim: int, heads: int, dropout: float):
        super().__init__()
        self.heads = heads
        self.q = TokenLinear(dim, dim)
        self.kv = TokenLinear(dim, 2 * dim)
        self.proj = TokenLinear(dim, dim)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        n, d = x.shape[1:]
        h = self.heads
        q = self.q(x).reshape(-1, n, h, d // h).transpose(1, 2) * (d // h) ** -0.5
        kv = self.kv(context).reshape(-1, context.shape[1], 2 * h, d // h)
        weights = self.dropout(torch.softmax(q @ kv[:, :, :h].permute(0, 2, 3, 1), dim=-1))
        out = weights @ kv[:, :, h:].transpose(1, 2)
        return self.proj(out.transpose(1, 2).reshape(-1, n, d))


def feed_forward(dim: int, ratio: float, dropout: float) -> nn.Sequential:
    hidden = int(dim * ratio)
    return nn.Sequential(
        nn.LayerNorm(dim),
        TokenLinear(dim, hidden),
        nn.GELU(),
        nn.Dropout(dropout),
        TokenLinear(hidden, dim),
        nn.Dropout(dropout),
    )


class DividedSpaceTimeBlock(nn.Module):
    """TimeSformer's divided attention: each patch attends over the K_L frames at its place (temporal), then over
    the patches of its frame and the class token (spatial), then an MLP; pre-norm and residual throughout."""

    def __init__(self, dim: int, config: PsdEncoderConfig, first: bool):
        super().__init__()
        self.norm_t = nn.LayerNorm(dim)
        self.attn_t = Attention(dim, config.heads, config.dropout)
        self.temporal_fc = TokenLinear(dim, dim)
        if not first:  # TimeSformer starts every later block's temporal path at zero, so it begins as space-only
            nn.init.zeros_(self.temporal_fc.weight)
            nn.init.zeros_(self.temporal_fc.bias)
        self.norm_s = nn.LayerNorm(dim)
        self.attn_s = Attention(dim, config.heads, config.dropout)
        self.mlp = feed_forward(dim, config.mlp_ratio, config.dropout)

    def forward(self, cls: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``cls`` (B, 1, D), ``x`` (B, K, N, D) → the same shapes."""
        _, k, n, d = x.shape
        xt = x.transpose(1, 2).reshape(-1, k, d)
        yt = self.norm_t(xt)
        xt = xt + self.temporal_fc(self.attn_t(yt, yt))
        x = xt.reshape(-1, n, k, d).transpose(1, 2)
        xs = torch.cat([cls.unsqueeze(1).expand(-1, k, -1, -1), x], dim=2).reshape(-1, n + 1, d)
        ys = self.norm_s(xs)
        xs = (xs + self.attn_s(ys, ys)).reshape(-1, k, n + 1, d)
        cls = xs[:, :, 0].mean(dim=1, keepdim=True)
        x = xs[:, :, 1:]
        x = x + self.mlp(x)
        cls = cls + self.mlp(cls)
        return cls, x


class PsdEncoder(nn.Module):
    """Patch embedding of each PSD matrix, spatial and temporal position embeddings, divided space–time blocks.

    ``forward`` returns the patch tokens (B, K, N, D) and the class token (B, D); ``mask`` (B, K, N) replaces the
    embeddings of masked patches with a learnt mask token (masked-reconstruction pretraining).
    """

    def __init__(self, dim: int, config: PsdEncoderConfig, shape: InputShape):
        super().__init__()
        if shape.psd_height % config.patch or shape.psd_width % config.patch:
            raise ValueError(f"PSD {shape.psd_height}×{shape.psd_width} is not a multiple of patch {config.patch}")
        self.patch = config.patch
        self.grid = (shape.psd_height // config.patch, shape.psd_width // config.patch)
        patches = self.grid[0] * self.grid[1]
        self.embed = nn.Conv2d(3, dim, config.patch, config.patch)
        self.cls = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos = nn.Parameter(torch.zeros(1, 1, patches, dim))
        self.time = nn.Parameter(torch.zeros(1, shape.psd_samples, 1, dim))
        self.mask_token = nn.Parameter(torch.zeros(1, 1, 1, dim))
        for p in (self.cls, self.pos, self.time, self.mask_token):
            nn.init.trunc_normal_(p, std=0.02)
        self.blocks = nn.ModuleList(DividedSpaceTimeBlock(dim, config, i == 0) for i in range(config.depth))
        self.norm = nn.LayerNorm(dim)

    @property
    def patches(self) -> int:
        return self.grid[0] * self.grid[1]

    def forward(self, psd: torch.Tensor, mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``psd`` (B, K, 3, H, W) float in [0, 1]."""
        b, k = psd.shape[:2]
        x = self.embed(psd.flatten(0, 1)).flatten(2).transpose(1, 2)
        x = x.reshape(-1, k, self.patches, x.shape[-1])
        if mask is not None:
            x = torch.where(mask.unsqueeze(-1), self.mask_token.to(x.dtype), x)
        x = x + self.pos + self.time
        cls = self.cls.expand(b, 1, -1)
        for block in self.blocks:
            cls, x = block(cls, x)
        return self.norm(x), self.norm(cls).squeeze(1)


class DilatedConvBlock(nn.Module):
    """TS2Vec's residual block: GELU → dilated conv → GELU → dilated conv, plus a 1×1 projection when the width
    changes or on the last block."""

    def __init__(self, channels_in: int, channels_out: int, kernel: int, dilation: int, final: bool):
        super().__init__()
        padding = dilation * (kernel - 1) // 2
        self.conv1 = nn.Conv1d(channels_in, channels_out, kernel, padding=padding, dilation=dilation)
        self.conv2 = nn.Conv1d(channels_out, channels_out, kernel, padding=padding, dilation=dilation)
        self.project = nn.Conv1d(channels_in, channels_out, 1) if channels_in != channels_out or final else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        residual = x if self.project is None else self.project(x)
        return self.conv2(F.gelu(self.conv1(F.gelu(x)))) + residual


class RtsEncoder(nn.Module):
    """TS2Vec's encoder: a linear input projection, optional timestamp masking of the latent (pretraining only),
    ``depth`` dilated blocks of width ``hidden`` (dilations 1, 2, 4, …) and a last block to the output width."""

    def __init__(self, dim: int, config: RtsEncoderConfig, channels: int):
        super().__init__()
        if config.kernel % 2 == 0:
            raise ValueError(f"RTS encoder kernel must be odd, got {config.kernel}")
        self.input_fc = nn.Linear(channels, config.hidden)
        widths = [config.hidden] * config.depth + [dim]
        self.blocks = nn.Sequential(
            *(
                DilatedConvBlock(
                    widths[i - 1] if i else config.hidden, widths[i], config.kernel, 2**i, i == len(widths) - 1
                )
                for i in range(len(widths))
            )
        )
        self.dropout = nn.Dropout(config.dropout)

    def forward(self, rts: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """``rts`` (B, T, C) → tokens (B, T, D); ``keep`` (B, T) zeroes the latent of masked time steps."""
        x = self.input_fc(rts)
        if keep is not None:
            x = x * keep.unsqueeze(-1).to(x.dtype)
        x = self.blocks(x.transpose(1, 2)).transpose(1, 2)
        return self.dropout(x)


class CrossAttentionLayer(nn.Module):
    """One bidirectional layer: RTS tokens attend to PSD tokens and PSD tokens to RTS tokens (both from the
    layer's input), each with a residual path, then a feed-forward block per stream."""

    def __init__(self, dim: int, config: FusionConfig):
        super().__init__()
        self.norm_r = nn.LayerNorm(dim)
        self.norm_p = nn.LayerNorm(dim)
        self.rts_to_psd = Attention(dim, config.heads, config.dropout)
        self.psd_to_rts = Attention(dim, config.heads, config.dropout)
        self.ffn_r = feed_forward(dim, config.ffn_ratio, config.dropout)
        self.ffn_p = feed_forward(dim, config.ffn_ratio, config.dropout)

    def forward(self, r: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        nr, np_ = self.norm_r(r), self.norm_p(p)
        r, p = r + self.rts_to_psd(nr, np_), p + self.psd_to_rts(np_, nr)
        return r + self.ffn_r(r), p + self.ffn_p(p)


def mlp_head(dim_in: int, hidden: tuple[int, ...], dropout: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(dim_in, width), nn.GELU(), nn.Dropout(dropout)]
        dim_in = width
    layers.append(nn.Linear(dim_in, 1))
    return nn.Sequential(*layers)


class OrdinalHead(nn.Module):
    """K logits of P(error ≥ t_k), t_1 < … < t_K, monotone by construction: the first logit minus cumulative
    softplus offsets, so logit_1 ≥ logit_2 ≥ … and the probabilities never cross (a crossing would make the class
    depend on which threshold is read)."""

    def __init__(self, dim_in: int, thresholds: int):
        super().__init__()
        self.first = nn.Linear(dim_in, 1)
        self.steps = nn.Linear(dim_in, thresholds - 1)

    def forward(self, pooled: torch.Tensor) -> torch.Tensor:
        """(B, F) → (B, K) logits, non-increasing along K."""
        offsets = torch.cumsum(F.softplus(self.steps(pooled)), dim=-1)
        first = self.first(pooled)
        return torch.cat([first, first - offsets], dim=-1)


class DeepSEE(nn.Module):
    """The estimator; :meth:`encode` and :meth:`head` split it where stage (c) caches the frozen encoders.

    ``thresholds_m``: the error thresholds of the ordinal head (metres, increasing); empty: no head, and the model
    outputs the transformed error alone, as every model trained before the head did. With a head, the outputs are
    ``(y, logits)``: the transformed error (B,) and the head's logits (B, K) (:func:`exceedance_probabilities`
    turns them into probabilities)."""

    # Buffers (register_buffer): Module.__getattr__ would give them as "Tensor | Module".
    rts_mask: torch.Tensor
    psd_mask: torch.Tensor

    def __init__(
        self,
        config: ModelConfig,
        shape: InputShape,
        variant: Variant = Variant(),
        thresholds_m: tuple[float, ...] = (),
        rts_channels: tuple[str, ...] | None = None,
    ):
        super().__init__()
        if rts_channels is not None and len(rts_channels) != shape.channels:
            raise ValueError(f"{len(rts_channels)} RTS channel names for a model of {shape.channels} channels")
        if list(thresholds_m) != sorted(set(thresholds_m)):
            raise ValueError(f"the ordinal head's thresholds must increase strictly, got {list(thresholds_m)}")
        self.config, self.shape, self.variant = config, shape, variant
        self.thresholds_m = tuple(float(t) for t in thresholds_m)
        dim = config.dim
        # Over the channels the model takes: a model of an earlier schema takes fewer than the schema has now.
        rts_mask = rts_channel_mask(variant.drop_rts, rts_channels, variant.drop_channels)
        self.register_buffer("rts_mask", torch.from_numpy(rts_mask))
        self.register_buffer("psd_mask", torch.from_numpy(psd_layer_mask(variant.drop_psd) / 255.0).float())
        self.rts_encoder = RtsEncoder(dim, config.rts, shape.channels)
        self.psd_encoder = PsdEncoder(dim, config.psd, shape) if variant.use_psd else None
        use_cross = variant.use_psd and variant.fusion == "cross_attention"
        self.fusion = (
            nn.ModuleList(CrossAttentionLayer(dim, config.fusion) for _ in range(config.fusion.layers))
            if use_cross
            else nn.ModuleList()
        )
        if variant.use_psd and not use_cross:
            # w/o CA: the pooled encodings go through fully connected layers instead of cross-attention
            self.concat_fc = nn.Sequential(nn.Linear(2 * dim, 2 * dim), nn.GELU(), nn.Dropout(config.fusion.dropout))
        pooled = (2 if variant.use_psd else 1) * dim
        self.head_net = mlp_head(pooled, config.fusion.head_hidden, config.fusion.dropout)
        self.ordinal = OrdinalHead(pooled, len(self.thresholds_m)) if self.thresholds_m else None

    def psd_input(self, psd: torch.Tensor) -> torch.Tensor:
        """uint8 (B, K, H, W, 3) → float (B, K, 3, H, W) in [0, 1], dropped layers zero."""
        # Channels first before scaling: ONNX Runtime broadcasts a (3,) factor over a last axis of 3 about 30 times
        # slower than a (3, 1, 1) one over whole layers (1 ms of a 6 ms inference).
        return psd.permute(0, 1, 4, 2, 3).to(torch.float32) * self.psd_mask.view(-1, 1, 1)

    def encode(self, rts: torch.Tensor, psd: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """RTS tokens (B, T, D) and PSD tokens (B, K+1, D): one per matrix (mean of its patches) and the class
        token; None without the PSD encoder."""
        r = self.rts_encoder(rts * self.rts_mask)
        if self.psd_encoder is None:
            return r, None
        patches, cls = self.psd_encoder(self.psd_input(psd))
        return r, torch.cat([patches.mean(dim=2), cls.unsqueeze(1)], dim=1)

    def head(self, r: torch.Tensor, p: torch.Tensor | None) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Fusion and output layers: (B,) transformed error, and (B, K) ordinal logits when the model has a head."""
        if p is None:
            pooled = r.mean(dim=1)
        else:
            for layer in self.fusion:
                r, p = layer(r, p)
            pooled = torch.cat([r.mean(dim=1), p.mean(dim=1)], dim=-1)
            if not len(self.fusion):
                pooled = self.concat_fc(pooled)
        y = self.head_net(pooled).squeeze(-1)
        return y if self.ordinal is None else (y, self.ordinal(pooled))

    def forward(self, rts: torch.Tensor, psd: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        return self.head(*self.encode(rts, psd))

    def encoder_modules(self) -> list[nn.Module]:
        return [m for m in (self.rts_encoder, self.psd_encoder) if m is not None]


def exceedance_probabilities(logits: torch.Tensor) -> torch.Tensor:
    """The ordinal head's logits as P(error ≥ t_k); the sigmoid keeps their order, so they stay monotone."""
    return torch.sigmoid(logits)
