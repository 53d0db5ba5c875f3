"""Camera rays for pixels (OpenCV pinhole cameras, pixel centres at +0.5)."""

from __future__ import annotations

import torch


def pixel_rays(c2w: torch.Tensor, K: torch.Tensor, x: torch.Tensor,
               y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space rays through pixel centres.

    Args:
        c2w: [R, 4, 4] camera-to-world pose of each ray's camera.
        K: [R, 3, 3] intrinsics of each ray's camera.
        x, y: [R] integer pixel coordinates (column, row).
    Returns:
        rays_o [R, 3], rays_d [R, 3] unit directions.
    """
    u = x.to(c2w.dtype) + 0.5
    v = y.to(c2w.dtype) + 0.5
    d_cam = torch.stack([(u - K[:, 0, 2]) / K[:, 0, 0], (v - K[:, 1, 2]) / K[:, 1, 1],
                         torch.ones_like(u)], -1)
    d_world = (c2w[:, :3, :3] @ d_cam[..., None])[..., 0]
    return c2w[:, :3, 3], d_world / d_world.norm(dim=-1, keepdim=True)


def image_rays(c2w: torch.Tensor, K: torch.Tensor, width: int,
               height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """All rays of one image, row-major.

    Args:
        c2w: [4, 4]; K: [3, 3].
    Returns:
        rays_o [H*W, 3], rays_d [H*W, 3].
    """
    ys, xs = torch.meshgrid(torch.arange(height, device=c2w.device),
                            torch.arange(width, device=c2w.device), indexing="ij")
    n = height * width
    return pixel_rays(c2w.expand(n, 4, 4), K.expand(n, 3, 3), xs.reshape(-1), ys.reshape(-1))
