"""The three training phases, each a step function and a loop.

1. D fitted to the CAD model's occupancy (binary cross entropy).
2. G (or D, without deformation) and the camera poses fitted to the silhouettes; poses only
   inside a window of steps, coarse-to-fine positional encoding.
3. Colour: D, G and the colour network fitted to the photos, with the offset and correction
   regularisers (means over evaluated samples: lambda_a * mean ||o||_2 + lambda_b * mean |c|,
   so the weights do not depend on the batch size or sample count).
Scene mode adds a last loop where a background field explains the photo behind the object.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from cadnerf_core.config import Phase2Config, Phase3Config
from cadnerf_core.nerf.blur import blur_images, target_blur
from cadnerf_core.nerf.epipolar import epipolar_loss
from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.grid import REFINE_FACTOR
from cadnerf_core.nerf.poses import in_window
from cadnerf_core.nerf.rays import pixel_rays
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.nerf.volrend import Culling, RenderOutput, render_rays
from cadnerf_core.progress import Progress

log = logging.getLogger(__name__)

# points [n] -> (points [n, 3] f32 in [-1, 1]^3, occupancy [n] f32 0/1)
OccupancySampler = Callable[[int], tuple[np.ndarray, np.ndarray]]

POOL_MAX = 1 << 18  # CAD occupancy samples drawn once for phase one
CPU_PASS_RAYS = 2048  # ``render.train_pass_rays`` 0 on the CPU


def autocast(state: TrainState) -> contextlib.AbstractContextManager[None]:
    """bfloat16 autocast on CUDA when configured; nothing on the CPU."""
    if state.device.type == "cuda" and state.config.mixed_precision:
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def upload(t: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A CPU tensor on ``device``. To CUDA through pinned memory without blocking: a copy from
    pageable memory waits for the GPU to drain first, which each step would otherwise do."""
    if device.type == "cuda":
        return t.pin_memory().to(device, non_blocking=True)
    return t.to(device)


def adam(params: Iterable[torch.nn.Parameter] | Iterable[dict[str, Any]], lr: float,
         device: torch.device) -> torch.optim.Adam:
    """Adam; on CUDA its fused kernel (one launch per step instead of several per tensor)."""
    if device.type == "cuda":
        return torch.optim.Adam(params, lr=lr, fused=True)
    return torch.optim.Adam(params, lr=lr)


def _report(progress: Progress | None, stage: str, step: int, total: int) -> None:
    if progress is not None:
        progress.advance(stage, step + 1, total)


def phase1_step(state: TrainState, optimizer: torch.optim.Optimizer, points: torch.Tensor,
                occ: torch.Tensor) -> float:
    """One BCE step of D on CAD occupancy. points [B, 3], occ [B] 0/1. Returns the loss."""
    with autocast(state):
        logit, _ = state.fields.density(points)
    loss = F.binary_cross_entropy_with_logits(logit.float(), occ)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return float(loss.detach())


def run_phase1(state: TrainState, sampler: OccupancySampler,
               progress: Progress | None = None) -> None:
    """Phase one: pretrain D to the CAD occupancy, then set the skip grid from it."""
    cfg = state.config.phase1
    torch.manual_seed(state.config.seed + 1)
    state.fields.set_anneal(1.0)
    pool_pts, pool_occ = sampler(min(POOL_MAX, max(cfg.steps * cfg.batch_points, 1)))
    pts = torch.from_numpy(np.asarray(pool_pts, np.float32)).to(state.device)
    occ = torch.from_numpy(np.asarray(pool_occ, np.float32)).to(state.device)
    optimizer = adam(state.fields.density.parameters(), cfg.lr, state.device)
    for step in range(cfg.steps):
        idx = upload(torch.randint(0, pts.shape[0], (cfg.batch_points,)), state.device)
        state.log("phase1/bce", phase1_step(state, optimizer, pts[idx], occ[idx]))
        _report(progress, "phase1", step, cfg.steps)


class CadPrior:
    """CAD occupancy points drawn once, for anchoring D to the template in phases two and three
    (``prior_weight``): a batch's BCE of D at its own, undeformed points."""

    def __init__(self, state: TrainState, sampler: OccupancySampler, pool: int = 1 << 16) -> None:
        pts, occ = sampler(pool)
        self.points = torch.from_numpy(np.asarray(pts, np.float32)).to(state.device)
        self.occupancy = torch.from_numpy(np.asarray(occ, np.float32)).to(state.device)

    def loss(self, state: TrainState, n: int) -> torch.Tensor:
        """BCE of D's logit against the CAD occupancy at ``n`` pool points (CPU draws)."""
        idx = upload(torch.randint(0, self.points.shape[0], (n,)), state.device)
        with autocast(state):
            logit, _ = state.fields.density(self.points[idx])
        return F.binary_cross_entropy_with_logits(logit.float(), self.occupancy[idx])


def make_prior(state: TrainState, sampler: OccupancySampler | None,
               weight: float) -> CadPrior | None:
    """The CAD prior when it applies: a weight, a template (CAD init) and a deformation G."""
    if weight <= 0 or sampler is None or state.fields.deformation is None \
            or not state.config.use_cad_init:
        return None
    return CadPrior(state, sampler)


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


def _occupancy_fn(state: TrainState) -> Callable[[torch.Tensor], torch.Tensor]:
    def occupancy(p: torch.Tensor) -> torch.Tensor:
        with autocast(state):
            return state.fields.query(p, None).occupancy

    return occupancy


def _maybe_update_grid(state: TrainState, step: int) -> None:
    rcfg = state.config.render
    if not rcfg.use_grid or (step + 1) % rcfg.grid_update_every:
        return
    state.grid.update(_occupancy_fn(state), rcfg.grid_threshold, rcfg.grid_dilation)
    if state.fine_grid is not None:
        refresh_fine_grid(state)


@torch.no_grad()
def refresh_fine_grid(state: TrainState) -> None:
    """``state.fine_grid`` remade from the learned field (``SkipGrid.refined``, one fine cell
    of dilation): a culled pass's look-up without gradients then skips the empty margin the
    training grid keeps for the shape to grow, which phase three's settled shape rarely
    needs and its mask loss still covers within a cell."""
    rcfg = state.config.render
    if rcfg.use_grid and rcfg.cull_alpha > 0:
        state.fine_grid = state.grid.refined(_occupancy_fn(state), REFINE_FACTOR,
                                             rcfg.grid_threshold)


def ray_passes(state: TrainState, n: int) -> list[tuple[slice, float]]:
    """How a step's ``n`` rays are split into forward and backward passes
    (``render.train_pass_rays``): each pass's slice and its share of the rays."""
    size = state.config.render.train_pass_rays
    if size <= 0:
        size = n if state.device.type == "cuda" else CPU_PASS_RAYS
    return [(slice(start, min(start + size, n)), (min(start + size, n) - start) / n)
            for start in range(0, n, size)]


def _apply_step(losses: Iterable[torch.Tensor], optimizer: torch.optim.Optimizer | None,
                pose_optimizer: torch.optim.Optimizer | None) -> float:
    """Backpropagate each pass's loss (``ray_passes``; their sum is the step's loss), then step
    once; a non-finite loss or gradient skips the step (never NaN weights). ``optimizer``
    None: only the poses learn (phase two with the shape held). Returns the step's loss.

    The loss and the gradients' total norm come back to the host together, after the backward
    passes: one wait for the GPU per step (a check per tensor waited once per tensor)."""
    optimizers = [opt for opt in (optimizer, pose_optimizer) if opt is not None]
    for opt in optimizers:
        opt.zero_grad(set_to_none=True)
    total: torch.Tensor | None = None
    learned = False
    for loss in losses:
        total = loss.detach().float() if total is None else total + loss.detach().float()
        if loss.requires_grad:
            loss.backward()
            learned = True
    assert total is not None, "a step has at least one pass"
    if not learned:
        log.warning("no sample reached the object in this batch: step skipped")
        return float(total)
    loss = total
    grads = [p.grad for opt in optimizers for group in opt.param_groups for p in group["params"]
             if p.grad is not None]
    norm = torch.nn.utils.get_total_norm(grads) if grads else torch.zeros((), device=loss.device)
    value, grad_norm = torch.stack([loss, norm.float()]).tolist()
    if not math.isfinite(value):
        log.warning("non-finite loss: step skipped")
        return value
    if not math.isfinite(grad_norm):
        log.warning("non-finite gradient: step skipped")
        return value
    for opt in optimizers:
        opt.step()
    return value


def _pass_loss(state: TrainState, loss: torch.Tensor, out: RenderOutput,
               cfg: Phase2Config | Phase3Config, share: float,
               prior: CadPrior | None) -> torch.Tensor:
    """One pass's loss: its re-rendering ``loss`` plus the deformation regularisers, scaled by
    the pass's ``share`` of the step's rays (the passes then add up to the step's means), and
    the CAD prior, given to one pass of the step only."""
    loss = loss + cfg.lambda_offset * out.offset_norm + cfg.lambda_correction * out.correction_abs
    if share < 1.0:
        loss = loss * share
    if prior is not None:
        loss = loss + cfg.prior_weight * prior.loss(state, cfg.prior_points)
    return loss


def matches_loss(state: TrainState, data: TrainData, weight: float) -> torch.Tensor | None:
    """``weight`` times the epipolar loss of the photos' matches at the current poses and
    focal length (``nerf.epipolar``); None without matches or weight."""
    if data.matches is None or weight <= 0:
        return None
    return weight * epipolar_loss(state.poses(), state.poses.intrinsics(data.K), data.matches)


def _matches_pass(state: TrainState, data: TrainData, weight: float,
                  posing: bool) -> Iterator[torch.Tensor]:
    """The step's pass of the matches' loss: one while the poses learn (``posing``) and the
    photos have matches, else none."""
    loss = matches_loss(state, data, weight) if posing else None
    if loss is not None:
        yield loss


def phase2_step(state: TrainState, data: TrainData, optimizer: torch.optim.Optimizer | None,
                pose_optimizer: torch.optim.Optimizer | None, step: int,
                prior: CadPrior | None = None) -> float:
    """One silhouette step: G (or D) and, inside the window, the poses (with the photos'
    matches, ``phase2.lambda_matches``). Returns the loss."""
    cfg = state.config.phase2
    state.fields.set_anneal((step / max(cfg.steps, 1) - cfg.anneal[0])
                            / max(cfg.anneal[1] - cfg.anneal[0], 1e-6))
    img, x, y = sample_pixels(data, cfg.rays)

    def losses() -> Iterator[torch.Tensor]:
        for i, (part, share) in enumerate(ray_passes(state, len(img))):
            out = render_batch(state, data, img[part], x[part], y[part], False,
                               pose_optimizer is not None)
            weight = pixel_weights(data, img[part], x[part], y[part])
            loss = weighted_mse(out.acc, data.masks[img[part], y[part], x[part]], weight)
            yield _pass_loss(state, loss, out, cfg, share, prior if i == 0 else None)
        yield from _matches_pass(state, data, cfg.lambda_matches, pose_optimizer is not None)

    return _apply_step(losses(), optimizer, pose_optimizer)


def _phase2_params(state: TrainState) -> list[torch.nn.Parameter]:
    """What phase two fits besides the poses: G, and D unless ``phase2.train_density`` is off
    (then G deforms a frozen D; without G, nothing: the shape stays the CAD model's and only
    the poses move)."""
    deformation = state.fields.deformation
    density = list(state.fields.density.parameters()) if state.config.phase2.train_density \
        else []
    return density if deformation is None else [*deformation.parameters(), *density]


def run_phase2(state: TrainState, data: TrainData, progress: Progress | None = None,
               sampler: OccupancySampler | None = None) -> None:
    """Phase two: deformation and poses from the silhouettes (``sampler``: the CAD occupancy,
    for ``prior_weight``)."""
    cfg = state.config.phase2
    torch.manual_seed(state.config.seed + 2)
    prior = make_prior(state, sampler, cfg.prior_weight)
    shape = _phase2_params(state)
    optimizer = adam(shape, cfg.lr, state.device) if shape else None
    pose_optimizer = adam(state.poses.optimizer_groups(cfg.pose_lr, state.config.phase2.focal_lr),
                          cfg.pose_lr, state.device)
    # Without phase2.train_density, D stays the CAD prior while G deforms it: no parameter
    # gradients for D (saves a third of the backward pass); gradients still flow through D to
    # the offsets (and to the poses).
    state.fields.density.requires_grad_(cfg.train_density)
    for step in range(cfg.steps):
        active = state.config.optimise_poses and in_window(step, cfg.steps, cfg.pose_window)
        if optimizer is None and not active:
            # Nothing to fit outside the pose window when the shape is held.
            _report(progress, "phase2", step, cfg.steps)
            continue
        loss = phase2_step(state, data, optimizer, pose_optimizer if active else None, step,
                           prior)
        state.log("phase2/loss", loss)
        _maybe_update_grid(state, step)
        _report(progress, "phase2", step, cfg.steps)
    state.fields.density.requires_grad_(True)
    state.fields.set_anneal(1.0)


def phase3_step(state: TrainState, data: TrainData, optimizer: torch.optim.Optimizer,
                pose_optimizer: torch.optim.Optimizer | None = None, scene: bool = False,
                targets: torch.Tensor | None = None, prior: CadPrior | None = None) -> float:
    """One colour step (D, G and colour; the background too in scene mode; the poses inside
    phase three's window, with the photos' matches, ``phase3.lambda_matches``). Returns the
    loss."""
    cfg = state.config.phase3
    img, x, y = sample_pixels(data, cfg.rays)
    target = data.scene_images if scene and data.scene_images is not None else data.images
    if targets is not None:
        target = targets
    white = None if scene else torch.ones(3, device=state.device)

    def losses() -> Iterator[torch.Tensor]:
        for i, (part, share) in enumerate(ray_passes(state, len(img))):
            pimg, px, py = img[part], x[part], y[part]
            out = render_batch(state, data, pimg, px, py, True, pose_optimizer is not None,
                               white, cull=True)
            assert out.rgb is not None
            loss = F.mse_loss(out.rgb, target[pimg, py, px])
            if cfg.mask_weight > 0:
                weight = pixel_weights(data, pimg, px, py)
                loss = loss + cfg.mask_weight * weighted_mse(out.acc, data.masks[pimg, py, px],
                                                             weight)
            yield _pass_loss(state, loss, out, cfg, share, prior if i == 0 else None)
        yield from _matches_pass(state, data, cfg.lambda_matches, pose_optimizer is not None)

    return _apply_step(losses(), optimizer, pose_optimizer)


def run_phase3(state: TrainState, data: TrainData, progress: Progress | None = None,
               sampler: OccupancySampler | None = None) -> None:
    """Phase three: colour re-rendering on white; then, in scene mode, with the background
    (``sampler``: the CAD occupancy, for ``prior_weight``)."""
    cfg = state.config.phase3
    torch.manual_seed(state.config.seed + 3)
    prior = make_prior(state, sampler, cfg.prior_weight)
    state.fields.set_anneal(1.0)
    background = state.fields.background
    params = [p for name, p in state.fields.named_parameters()
              if not name.startswith("background.")]
    optimizer = adam(params, cfg.lr, state.device)
    scene_steps = cfg.scene_steps if background is not None and data.scene_images is not None \
        else 0
    total = cfg.steps + scene_steps
    pose_optimizer = adam(state.poses.optimizer_groups(cfg.pose_lr, state.config.phase2.focal_lr),
                          cfg.pose_lr, state.device)
    blurred: dict[float, torch.Tensor] = {}
    refresh_fine_grid(state)
    for step in range(cfg.steps):
        active = state.config.optimise_poses and in_window(step, cfg.steps, cfg.pose_window)
        sigma = target_blur(step, cfg.steps, cfg.pose_window, cfg.pose_blur) * data.width
        if active and sigma > 0 and sigma not in blurred:
            blurred[sigma] = blur_images(data.images, sigma)
        targets = blurred[sigma] if active and sigma > 0 else None
        state.log("phase3/loss", phase3_step(state, data, optimizer,
                                             pose_optimizer if active else None,
                                             targets=targets, prior=prior))
        _maybe_update_grid(state, step)
        _report(progress, "phase3", step, total)
    if scene_steps and background is not None:
        optimizer.add_param_group({"params": list(background.parameters())})
        for step in range(scene_steps):
            state.log("phase3/scene_loss", phase3_step(state, data, optimizer, None, scene=True))
            _report(progress, "phase3", cfg.steps + step, total)
