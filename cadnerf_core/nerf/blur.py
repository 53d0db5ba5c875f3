"""Phase three's blurred targets: how blurred at each step, and the blur itself.

In phase three's pose window the colour targets are blurred (``Phase3Config.pose_blur``),
which widens the loss's basin in pose; the blur halves each third of the window.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from cadnerf_core.nerf.poses import in_window


def target_blur(step: int, total: int, window: tuple[float, float], blur: float) -> float:
    """Phase three's target blur at ``step`` of ``total``: ``blur`` in the first third of the
    pose ``window``, half of it in the second, a quarter in the last, 0 outside the window
    (``Phase3Config.pose_blur``; same units as ``blur``)."""
    start, end = window
    if blur <= 0 or not in_window(step, total, window):
        return 0.0
    level = min(2, int(3 * (step / total - start) / (end - start)))
    return blur / 2**level


def blur_images(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur (standard deviation ``sigma`` pixels, reflected borders) of [N, H, W, C]
    images, separably. Returns a new [N, H, W, C] tensor (``images`` itself for sigma <= 0)."""
    if sigma <= 0:
        return images
    n, height, width, channels = images.shape
    # Three standard deviations, within what reflect padding allows.
    radius = max(1, min(int(3 * sigma), height - 1, width - 1))
    t = torch.arange(-radius, radius + 1, dtype=images.dtype, device=images.device)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    x = images.permute(0, 3, 1, 2).reshape(-1, 1, height, width)
    x = F.conv2d(F.pad(x, (radius, radius, 0, 0), mode="reflect"), k.view(1, 1, 1, -1))
    x = F.conv2d(F.pad(x, (0, 0, radius, radius), mode="reflect"), k.view(1, 1, -1, 1))
    return x.reshape(n, channels, height, width).permute(0, 2, 3, 1).contiguous()
