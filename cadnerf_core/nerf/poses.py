"""Learned camera pose corrections: P_opt = T(xi) @ P_init, xi = (axis-angle, translation).

As in NeRF--: one 6-vector per camera, mapped to SE(3) by ``cameras.se3_exp``. The correction is
applied on the left, in the world frame: with cameras around the origin, its rotation part moves
a camera along its viewing sphere (azimuth and elevation errors) and rolls it, which is exactly
how retrieved poses are wrong.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from cadnerf_core.cameras.conventions import se3_exp


class PoseCorrection(nn.Module):
    """Per-camera SE(3) corrections of fixed initial poses, and one focal-length factor shared
    by every camera (NeRF--: the photos' focal length learned with their poses); zero
    corrections and a factor of 1 mean unchanged."""

    c2w_init: torch.Tensor

    def __init__(self, c2w_init: torch.Tensor, focal_bound: float = 1.0,
                 learn_focal: bool = False) -> None:
        """Args: c2w_init: [N, 4, 4] initial camera-to-world poses; focal_bound: the factor
        stays within [1 / focal_bound, focal_bound]; learn_focal: the factor is trained."""
        super().__init__()
        self.register_buffer("c2w_init", c2w_init.float().clone())
        self.xi = nn.Parameter(torch.zeros(c2w_init.shape[0], 6, dtype=torch.float32,
                                           device=c2w_init.device))
        self.focal_bound = float(focal_bound)
        # factor = bound ** tanh(logit): smooth, bounded, 1 at 0.
        self.focal_logit = nn.Parameter(torch.zeros(1, dtype=torch.float32,
                                                    device=c2w_init.device),
                                        requires_grad=learn_focal and focal_bound > 1.0)

    def focal_scale(self) -> torch.Tensor:
        """The shared focal-length factor. Returns [] float32."""
        if self.focal_bound <= 1.0:
            return torch.ones((), device=self.focal_logit.device)
        return torch.exp(math.log(self.focal_bound) * torch.tanh(self.focal_logit[0]))

    def intrinsics(self, K: torch.Tensor) -> torch.Tensor:
        """``K`` [..., 3, 3] with its focal lengths times ``focal_scale`` (principal point
        kept: the crops are centred on the object)."""
        diagonal = torch.zeros(3, 3, device=K.device, dtype=K.dtype)
        diagonal[0, 0] = diagonal[1, 1] = 1.0
        return K * (1.0 + diagonal * (self.focal_scale().to(K.dtype) - 1.0))

    def optimizer_groups(self, lr: float, focal_lr: float) -> list[dict[str, Any]]:
        """Adam parameter groups: the SE(3) corrections at ``lr``, the focal factor (when it
        learns) at ``focal_lr``."""
        groups: list[dict[str, Any]] = [{"params": [self.xi], "lr": lr}]
        if self.focal_logit.requires_grad:
            groups.append({"params": [self.focal_logit], "lr": focal_lr})
        return groups

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
