"""Volume rendering of an occupancy field: samples in a bounding sphere, grid skipping, alpha
compositing.

D's output is an occupancy probability in [0, 1] (phase one trains it with binary cross entropy).
We use it directly as each sample's alpha, as UNISURF does, instead of mapping it to a density
sigma and computing alpha = 1 - exp(-sigma * delta): the pretrained CAD field then renders the
CAD silhouette exactly with no scale to tune, and the result does not depend on the sample
spacing once the field is near binary (the first sample inside the object stops the ray).
Weights are alpha_i * prod_{j<i} (1 - alpha_j); accumulated opacity is their sum.

The renderer never owns the network: it takes the fields as a callable, as in nerfacc.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.grid import SkipGrid

FieldFn = Callable[[torch.Tensor, torch.Tensor | None], FieldOutputs]
"""(points [P, 3], dirs [P, 3] or None) -> FieldOutputs; dirs None: occupancy only."""


@dataclass(frozen=True)
class Culling:
    """Which samples a training render may leave out of its differentiable pass, decided by a
    pass of occupancy alone without gradients (as nerfacc's ``alpha_thre`` and
    ``early_stop_eps``): a sample of alpha below ``alpha`` adds next to nothing to colour or
    opacity and, through the sigmoid's slope, next to no gradient; one behind opaque matter
    (transmittance below ``transmittance``) none at all."""

    alpha: float = 1e-3
    transmittance: float = 1e-3


@dataclass
class RenderOutput:
    """Per-ray results and what the regularisers need."""

    acc: torch.Tensor  # [R] accumulated opacity
    rgb: torch.Tensor | None  # [R, 3] composited on the background, None without colour
    depth: torch.Tensor  # [R] expected distance (where the ray stops)
    offset_norm: torch.Tensor  # [] mean ||o||_2 over evaluated samples (0 without G)
    correction_abs: torch.Tensor  # [] mean |c| over evaluated samples
    n_evaluated: int  # samples of the differentiable pass (a culling pass's not counted)


def ray_sphere(rays_o: torch.Tensor, rays_d: torch.Tensor,
               radius: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Entry and exit distances of unit-direction rays through a sphere at the origin.

    Args:
        rays_o, rays_d: [R, 3].
    Returns:
        near [R], far [R], hit [R] bool (near clamped at 0; near == far where missed).
    """
    b = (rays_o * rays_d).sum(-1)
    c = (rays_o * rays_o).sum(-1) - radius * radius
    disc = b * b - c
    hit = disc > 0
    # Clamp away from zero: sqrt's infinite slope at 0 times clamp's zero gradient is NaN, and
    # missed rays carry pose gradients here.
    root = torch.sqrt(disc.clamp_min(1e-12))
    near = (-b - root).clamp_min(0.0)
    far = torch.where(hit, (-b + root).clamp_min(0.0), near)
    return near, far, hit & (far > near)


def sample_distances(near: torch.Tensor, far: torch.Tensor, n: int, stratified: bool,
                     generator: torch.Generator | None = None) -> torch.Tensor:
    """Distances of ``n`` samples per ray between near and far, jittered within bins if asked.

    Args:
        near, far: [R].
    Returns:
        t: [R, n] increasing.
    """
    bins = torch.arange(n, device=near.device, dtype=near.dtype)
    if stratified:
        u = torch.rand(near.shape[0], n, device=near.device, dtype=near.dtype,
                       generator=generator)
    else:
        u = torch.full((near.shape[0], n), 0.5, device=near.device, dtype=near.dtype)
    frac = (bins + u) / n
    return near[:, None] + (far - near)[:, None] * frac


def composite(alpha: torch.Tensor) -> torch.Tensor:
    """Compositing weights w_i = alpha_i * prod_{j<i} (1 - alpha_j).

    Args:
        alpha: [R, S] in [0, 1].
    Returns:
        weights: [R, S].
    """
    ones = torch.ones_like(alpha[:, :1])
    trans = torch.cumprod(torch.cat([ones, 1.0 - alpha[:, :-1] + 1e-7], -1), -1)
    return alpha * trans


def _evaluate(fn: FieldFn, points: torch.Tensor, dirs: torch.Tensor, keep: torch.Tensor,
              with_color: bool
              ) -> tuple[torch.Tensor, torch.Tensor | None, FieldOutputs | None, int]:
    """Evaluate the fields only at kept samples; scatter back to dense [R*S] tensors.
    Returns alpha, rgb, the fields' outputs and the number of samples evaluated."""
    n = keep.shape[0]
    idx = keep.nonzero()[:, 0]
    alpha = torch.zeros(n, device=points.device, dtype=torch.float32)
    rgb = torch.zeros(n, 3, device=points.device, dtype=torch.float32) if with_color else None
    if idx.numel() == 0:
        return alpha, rgb, None, 0
    out = fn(points[idx], dirs[idx])
    alpha = alpha.index_put((idx,), out.occupancy.float())
    if rgb is not None and out.rgb is not None:
        rgb = rgb.index_put((idx,), out.rgb.float())
    return alpha, rgb, out, int(idx.numel())


def cull_samples(fn: FieldFn, points: torch.Tensor, keep: torch.Tensor,
                 culling: Culling) -> torch.Tensor:
    """The samples worth a differentiable pass: ``keep`` less those of low alpha or behind
    opaque matter (``Culling``), judged by occupancy alone without gradients.

    Args:
        points: [R, S, 3] samples along each ray, in order.
        keep: [R, S] bool, the samples the grid leaves.
    Returns:
        [R, S] bool, a subset of ``keep``.
    """
    R, S = keep.shape
    with torch.no_grad():
        idx = keep.reshape(-1).nonzero()[:, 0]
        alpha = torch.zeros(R * S, device=points.device, dtype=torch.float32)
        if idx.numel():
            occupancy = fn(points.reshape(-1, 3)[idx], None).occupancy.float()
            alpha = alpha.index_put((idx,), occupancy)
        alpha = alpha.reshape(R, S)
        ones = torch.ones_like(alpha[:, :1])
        trans = torch.cumprod(torch.cat([ones, 1.0 - alpha[:, :-1]], -1), -1)
    return keep & (alpha > culling.alpha) & (trans > culling.transmittance)


def render_rays(fn: FieldFn, rays_o: torch.Tensor, rays_d: torch.Tensor, n_samples: int,
                radius: float, grid: SkipGrid | None, with_color: bool, stratified: bool,
                background: torch.Tensor | None = None,
                culling: Culling | None = None) -> RenderOutput:
    """Render rays through the fields.

    Args:
        fn: fields callable (points [P, 3], dirs [P, 3] or None) -> FieldOutputs; dirs None
            (the culling pass): occupancy only.
        rays_o, rays_d: [R, 3], unit directions.
        n_samples: samples per ray inside the bounding sphere.
        radius: bounding sphere radius.
        grid: empty-space-skipping grid; samples in empty cells are not evaluated (alpha 0).
        with_color: also composite colour.
        stratified: jitter samples (training) or take bin centres (rendering).
        background: [R, 3] or [3] colour behind the object (default white).
        culling: leave samples of low alpha or behind opaque matter out of the pass
            (``cull_samples``; None: every sample the grid leaves is evaluated).
    Returns:
        RenderOutput.
    """
    R = rays_o.shape[0]
    near, far, hit = ray_sphere(rays_o, rays_d, radius)
    t = sample_distances(near, far, n_samples, stratified)  # [R, S]
    points = rays_o[:, None] + rays_d[:, None] * t[..., None]  # [R, S, 3]
    keep = hit[:, None].expand(R, n_samples)
    if grid is not None:
        keep = keep & grid.contains(points.reshape(-1, 3)).reshape(R, n_samples)
    if culling is not None:
        keep = cull_samples(fn, points, keep, culling)
    dirs = rays_d[:, None].expand(R, n_samples, 3).reshape(-1, 3)
    alpha, rgb, out, n_evaluated = _evaluate(fn, points.reshape(-1, 3), dirs, keep.reshape(-1),
                                             with_color)
    weights = composite(alpha.reshape(R, n_samples))
    acc = weights.sum(-1)
    depth = (weights * t).sum(-1) + (1.0 - acc) * far
    color = None
    if rgb is not None:
        bg = torch.ones(3, device=rays_o.device) if background is None else background
        color = (weights[..., None] * rgb.reshape(R, n_samples, 3)).sum(1)
        color = color + (1.0 - acc)[:, None] * bg
    zero = torch.zeros((), device=rays_o.device)
    off = zero if out is None or out.offset is None else out.offset.float().norm(dim=-1).mean()
    cor = zero if out is None or out.correction is None else out.correction.float().abs().mean()
    return RenderOutput(acc, color, depth, off, cor, n_evaluated)


@torch.no_grad()
def march_rays(fn: FieldFn, rays_o: torch.Tensor, rays_d: torch.Tensor, n_samples: int,
               radius: float, grid: SkipGrid | None, background: torch.Tensor,
               block: int = 8, min_transmittance: float = 1e-3
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Render rays for display: the same samples as ``render_rays`` (bin centres), marched in
    blocks of ``block`` samples with early termination once a ray is opaque.

    Only the rays that meet an occupied cell of ``grid`` are marched (the others see the
    background), and each block evaluates the fields at its kept samples alone: in a view the
    object covers a fifth of, most rays never reach it.

    Args:
        fn: fields callable, as for ``render_rays``; must return colour.
        rays_o, rays_d: [R, 3], unit directions.
        background: [3] colour behind the object.
    Returns:
        rgb [R, 3], acc [R].
    """
    R = rays_o.shape[0]
    near, far, hit = ray_sphere(rays_o, rays_d, radius)
    live = hit.nonzero()[:, 0]
    t = sample_distances(near[live], far[live], n_samples, False)  # [L, S]
    origins, dirs = rays_o[live], rays_d[live]
    occupied = None
    if grid is not None:  # block by block: only [L, block] points at a time, as the march
        occupied = torch.cat([grid.contains(
            (origins[:, None] + dirs[:, None] * t[:, lo:lo + block, None]).reshape(-1, 3))
            .reshape(t.shape[0], t[:, lo:lo + block].shape[1])
            for lo in range(0, n_samples, block)], 1)
        meets = occupied.any(1)
        live, t, origins, dirs = live[meets], t[meets], origins[meets], dirs[meets]
        occupied = occupied[meets]
    L = live.shape[0]
    trans = torch.ones(L, device=rays_o.device)
    color = torch.zeros(L, 3, device=rays_o.device)
    active = torch.ones(L, dtype=torch.bool, device=rays_o.device)
    for start in range(0, n_samples, block):
        ts = t[:, start:start + block]
        b = ts.shape[1]
        keep = active[:, None].expand(L, b)
        if occupied is not None:
            keep = keep & occupied[:, start:start + b]
        ray, sample = keep.nonzero(as_tuple=True)
        if ray.numel() == 0:
            continue
        out = fn(origins[ray] + dirs[ray] * ts[ray, sample][:, None], dirs[ray])
        assert out.rgb is not None
        alpha = torch.zeros(L, b, device=rays_o.device).index_put((ray, sample),
                                                                  out.occupancy.float())
        rgb = torch.zeros(L, b, 3, device=rays_o.device).index_put((ray, sample),
                                                                   out.rgb.float())
        weights = composite(alpha) * trans[:, None]
        color += (weights[..., None] * rgb).sum(1)
        trans = trans * torch.prod(1.0 - alpha, -1)
        active = active & (trans > min_transmittance)
        if not bool(active.any()):
            break
    full_trans = torch.ones(R, device=rays_o.device).index_put((live,), trans)
    full_color = torch.zeros(R, 3, device=rays_o.device).index_put((live,), color)
    return full_color + full_trans[:, None] * background, 1.0 - full_trans
