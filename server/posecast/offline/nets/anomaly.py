"""Anomaly autoencoder (paper Sec. 3.2.1, 4.2): plausible poses reconstruct, others don't.

Input: the 19 joint positions in the character frame (57), normalised. Output: the
18 non-root local rotations as 6D (108); FK turns them back into positions, and the
mean lower-body position error is the sample's score ``R``.
Layers ``57 -> 28 -> 14 -> 7 -> 7 -> 14 -> 28 -> 108``, ReLU on all but the last.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass

import torch
from torch import nn


@dataclass(frozen=True)
class AnomalyConfig:
    widths: tuple[int, ...] = (57, 28, 14, 7, 7, 14, 28, 108)

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


class AnomalyAE(nn.Module):
    def __init__(self, cfg: AnomalyConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w = cfg.widths
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(w))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x (..., 57)`` normalised local positions -> ``(..., 108)`` rotations (6D)."""
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = torch.relu(x)
        return x
