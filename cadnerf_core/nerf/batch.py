"""A training batch: random pixels over the photos and their rays rendered at the current
poses."""

from __future__ import annotations

import contextlib

import torch

from cadnerf_core.nerf.device import autocast, upload
from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.rays import pixel_rays
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.nerf.volrend import Culling, RenderOutput, render_rays


def sample_pixels(data: TrainData, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random pixels over all photos (CPU generator: same draws on every device).

    Returns:
        image index [n], x [n], y [n] (long, on the data's device).
    """
    flat = upload(torch.randint(0, data.n_images * data.height * data.width, (n,)),
                  data.images.device)
    img = flat // (data.height * data.width)
    rem = flat % (data.height * data.width)
    return img, rem % data.width, rem // data.width


def render_batch(state: TrainState, data: TrainData, img: torch.Tensor, x: torch.Tensor,
                 y: torch.Tensor, with_color: bool, pose_grad: bool,
                 background: torch.Tensor | None = None, cull: bool = False) -> RenderOutput:
    """Render training rays of pixels (img, x, y) at the current poses (``cull``: samples of
    alpha below ``render.cull_alpha`` or behind opaque matter left out, ``volrend.Culling``)."""
    with contextlib.nullcontext() if pose_grad else torch.no_grad():
        c2w = state.poses(img)
        K = state.poses.intrinsics(data.K[img])
    rays_o, rays_d = pixel_rays(c2w, K, x, y)
    if background is None and with_color and state.fields.background is not None \
            and data.scene_images is not None:
        background = state.fields.background(rays_d)

    def fn(p: torch.Tensor, d: torch.Tensor | None) -> FieldOutputs:
        # Only the networks run in reduced precision; compositing stays in float32.
        with autocast(state):
            return state.fields.query(p, d if with_color else None)

    rcfg = state.config.render
    culling = Culling(rcfg.cull_alpha) if cull and rcfg.cull_alpha > 0 else None
    grid = (state.fine_grid or state.grid) if culling is not None else state.grid
    return render_rays(fn, rays_o, rays_d, rcfg.samples_per_ray, rcfg.bound,
                       grid if rcfg.use_grid else None, with_color, True, background, culling)
