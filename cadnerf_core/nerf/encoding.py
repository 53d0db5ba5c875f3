"""Positional encoding with BARF's coarse-to-fine frequency annealing."""

from __future__ import annotations

import math

import torch
from torch import nn


def frequency_weights(n_freqs: int, alpha: float, device: torch.device | None = None
                      ) -> torch.Tensor:
    """BARF's window over frequency bands.

    Band k gets weight (1 - cos(pi * clamp(alpha - k, 0, 1))) / 2: zero until alpha reaches k,
    one once alpha passes k + 1, smooth in between.

    Args:
        n_freqs: number of bands L.
        alpha: annealing progress in [0, L] (L or more: every band fully on).
    Returns:
        weights: [n_freqs].
    """
    k = torch.arange(n_freqs, dtype=torch.float32, device=device)
    t = (alpha - k).clamp(0.0, 1.0)
    return (1.0 - torch.cos(t * math.pi)) / 2.0


class PositionalEncoding(nn.Module):
    """x -> (x, sin(2^k pi x), cos(2^k pi x)) for k < n_freqs, bands weighted by annealing."""

    bands: torch.Tensor

    def __init__(self, n_freqs: int, in_dim: int = 3) -> None:
        super().__init__()
        self.n_freqs = n_freqs
        self.in_dim = in_dim
        self.register_buffer("bands", (2.0 ** torch.arange(n_freqs)) * math.pi, persistent=False)
        self.alpha = float(n_freqs)  # fully on unless a phase anneals it

    @property
    def out_dim(self) -> int:
        """Width of the encoding."""
        return self.in_dim * (1 + 2 * self.n_freqs)

    def set_progress(self, fraction: float) -> None:
        """Switch bands on coarse-to-fine: ``fraction`` 0 keeps only x, 1 turns all bands on."""
        self.alpha = float(min(max(fraction, 0.0), 1.0)) * self.n_freqs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Encode points.

        Args:
            x: [..., in_dim].
        Returns:
            [..., in_dim * (1 + 2 * n_freqs)].
        """
        if self.n_freqs == 0:
            return x
        scaled = x[..., None, :] * self.bands[:, None]  # [..., L, in_dim]
        w = frequency_weights(self.n_freqs, self.alpha, x.device)[:, None].to(x.dtype)
        enc = torch.cat([torch.sin(scaled) * w, torch.cos(scaled) * w], dim=-1)  # [..., L, 2d]
        return torch.cat([x, enc.flatten(-2)], dim=-1)
