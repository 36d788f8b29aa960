"""Building blocks of the dense-grid field backends: the coarse-to-fine resolution check and the colour decoder.

Colour: ``rgb = sigmoid(g₁..₃ + MLP([g₁.., SH(d)]))`` — a direct colour from the first three appearance features
``g`` of the grid plus, with ``decoder="mlp"``, a view-dependent residual of a one-hidden-layer MLP on all features
and the spherical-harmonics encoding of the view direction ``d``; its last layer is zero at start, so training
begins as a plain RGB grid.
"""

from __future__ import annotations

from typing import Any

import torch

from .encoding import spherical_harmonics


def start_resolution(config: Any) -> int:
    """The starting grid resolution ``resolution / 2^len(upsample_steps)`` of a grid config (``resolution``,
    ``upsample_steps``, ``features``, ``decoder``, ``occupancy_resolution``), checking that it is exact, that the
    occupancy resolution divides it and that the features suit the decoder (ValueError naming the config)."""
    name = type(config).__name__
    if config.features < 3 or (config.decoder == "rgb" and config.features != 3):
        raise ValueError(f"{name}: features must be >= 3 (exactly 3 with decoder='rgb'), got {config.features}")
    start, levels = config.resolution >> len(config.upsample_steps), len(config.upsample_steps)
    occupancy = config.occupancy_resolution
    if start << levels != config.resolution or (occupancy and start % occupancy):
        raise ValueError(f"{name}: resolution {config.resolution} must be a multiple of 2^{levels} "
                         f"(len(upsample_steps)) times occupancy_resolution {occupancy}")
    return start


class ColorDecoder(torch.nn.Module):
    """Appearance features ``(M, features)`` and unit directions ``(M,3)`` → ``rgb (M,3)`` (module docstring)."""

    def __init__(self, features: int, decoder: str, hidden: int, sh_degree: int) -> None:
        super().__init__()
        self.sh_degree = sh_degree
        self.mlp = None
        if decoder == "mlp":
            width = features + (sh_degree + 1) ** 2
            self.mlp = torch.nn.Sequential(torch.nn.Linear(width, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 3))
            torch.nn.init.zeros_(self.mlp[2].weight)
            torch.nn.init.zeros_(self.mlp[2].bias)

    def forward(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        logits = features[:, :3]
        if self.mlp is not None:
            logits = logits + self.mlp(torch.cat([features, spherical_harmonics(directions, self.sh_degree)], -1))
        return torch.sigmoid(logits)
