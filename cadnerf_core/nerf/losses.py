"""The re-rendering losses of phases two and three: per-pixel weighted errors and the
photos' matches."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from cadnerf_core.nerf.epipolar import epipolar_loss
from cadnerf_core.nerf.state import TrainData, TrainState


def weighted_mse(pred: torch.Tensor, target: torch.Tensor,
                 weight: torch.Tensor | None) -> torch.Tensor:
    """Mean squared error of a batch where each ray counts by its ``weight``.

    Args:
        pred, target: [n] or [n, C].
        weight: [n] in [0, 1] (``TrainData.weights`` at the batch's pixels), or None: plain MSE.
    Returns:
        Scalar: sum of weighted squared errors over the summed weight (times C); 0 with a
        gradient when every weight is 0.
    """
    if weight is None:
        return F.mse_loss(pred, target)
    error = (pred - target) ** 2
    if error.dim() > 1:
        error = error.mean(dim=-1)
    return (weight * error).sum() / weight.sum().clamp_min(1e-6)


def pixel_weights(data: TrainData, img: torch.Tensor, x: torch.Tensor,
                  y: torch.Tensor) -> torch.Tensor | None:
    """Loss weights [n] of pixels (img, x, y), or None when every pixel weighs 1."""
    return None if data.weights is None else data.weights[img, y, x]


def matches_loss(state: TrainState, data: TrainData, weight: float) -> torch.Tensor | None:
    """``weight`` times the epipolar loss of the photos' matches at the current poses and
    focal length (``nerf.epipolar``); None without matches or weight."""
    if data.matches is None or weight <= 0:
        return None
    return weight * epipolar_loss(state.poses(), state.poses.intrinsics(data.K), data.matches)
