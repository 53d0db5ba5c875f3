"""A training batch: random pixels over the photos and their rays rendered at the current
poses."""

from __future__ import annotations

import contextlib

import torch
import torch.nn.functional as F

from cadnerf_core.nerf.device import autocast, upload
from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.rays import pixel_rays
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.nerf.volrend import Culling, RenderOutput, render_rays

OBJECT_DILATION = 2
"""Pixels around each mask that count as the object's when rays are drawn on it (its edge)."""


def object_pixels(data: TrainData) -> torch.Tensor:
    """Flat indices (image, row, column) of the pixels on the photos' objects, their masks
    dilated by ``OBJECT_DILATION`` pixels. Returns [M] long on the CPU (M >= 1)."""
    side = 2 * OBJECT_DILATION + 1
    grown = F.max_pool2d(data.masks.float().cpu()[:, None], side, stride=1,
                         padding=OBJECT_DILATION)[:, 0]
    found = torch.nonzero(grown.reshape(-1) > 0.5)[:, 0]
    return found if len(found) else torch.arange(grown.numel())


def sample_pixels(data: TrainData, n: int, object_share: float = 0.0,
                  on_object: torch.Tensor | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random pixels over all photos (CPU generator: same draws on every device); a share
    ``object_share`` of them among ``on_object`` (``object_pixels``), the rest anywhere.

    Returns:
        image index [n], x [n], y [n] (long, on the data's device).
    """
    on = round(n * object_share) if on_object is not None else 0
    anywhere = torch.randint(0, data.n_images * data.height * data.width, (n - on,))
    if on:
        assert on_object is not None
        anywhere = torch.cat([on_object[torch.randint(0, len(on_object), (on,))], anywhere])
    flat = upload(anywhere, data.images.device)
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
