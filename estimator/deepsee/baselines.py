"""The LSTM baseline of Table 3: two LSTM layers over the normalised RTS window, the last step's state through fully
connected layers. It regresses the same transformed label as DeepSEE and sees the RTS window only (the other
baseline, the random forest, is :mod:`estimator.deepsee.forest`).
"""

from __future__ import annotations

import torch
from torch import nn

from estimator.deepsee.config import LstmConfig


class LstmBaseline(nn.Module):
    """2 LSTM layers + fully connected; takes (rts, psd) like DeepSEE and ignores the PSD."""

    def __init__(self, config: LstmConfig, channels: int):
        super().__init__()
        self.config, self.channels = config, channels
        self.lstm = nn.LSTM(channels, config.hidden, num_layers=config.layers, batch_first=True)
        self.head = nn.Sequential(
            nn.Linear(config.hidden, config.head_hidden), nn.GELU(), nn.Linear(config.head_hidden, 1)
        )

    def forward(self, rts: torch.Tensor, psd: torch.Tensor) -> torch.Tensor:
        out, _ = self.lstm(rts)
        return self.head(out[:, -1]).squeeze(-1)
