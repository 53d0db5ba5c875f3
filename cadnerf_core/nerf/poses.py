"""Learned camera pose corrections: P_opt = T(xi) @ P_init, xi = (axis-angle, translation).

As in NeRF--: one 6-vector per camera, mapped to SE(3) by ``cameras.se3_exp``. The correction is
applied on the left, in the world frame: with cameras around the origin, its rotation part moves
a camera along its viewing sphere (azimuth and elevation errors) and rolls it, which is exactly
how retrieved poses are wrong.
"""

from __future__ import annotations

import torch
from torch import nn

from cadnerf_core.cameras import se3_exp


class PoseCorrection(nn.Module):
    """Per-camera SE(3) corrections of fixed initial poses; zero means unchanged."""

    c2w_init: torch.Tensor

    def __init__(self, c2w_init: torch.Tensor) -> None:
        """Args: c2w_init: [N, 4, 4] initial camera-to-world poses."""
        super().__init__()
        self.register_buffer("c2w_init", c2w_init.float().clone())
        self.xi = nn.Parameter(torch.zeros(c2w_init.shape[0], 6, dtype=torch.float32,
                                           device=c2w_init.device))

    def forward(self, index: torch.Tensor | None = None) -> torch.Tensor:
        """Corrected poses.

        Args:
            index: [R] camera indices, or None for every camera.
        Returns:
            c2w: [R, 4, 4] (or [N, 4, 4]).
        """
        xi = self.xi if index is None else self.xi[index]
        init = self.c2w_init if index is None else self.c2w_init[index]
        return se3_exp(xi) @ init


def in_window(step: int, total: int, window: tuple[float, float]) -> bool:
    """Whether ``step`` (0-based, of ``total``) lies in the fractional ``window`` [start, end)."""
    if total <= 0:
        return False
    frac = step / total
    return window[0] <= frac < window[1]
