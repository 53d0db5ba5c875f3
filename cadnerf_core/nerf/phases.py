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

from collections.abc import Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from cadnerf_core.config import Phase2Config, Phase3Config
from cadnerf_core.nerf.batch import object_pixels, render_batch, sample_pixels
from cadnerf_core.nerf.blur import blur_images, target_blur
from cadnerf_core.nerf.device import adam, autocast, upload
from cadnerf_core.nerf.grid_update import refresh_fine_grid, update_grids
from cadnerf_core.nerf.losses import matches_loss, pixel_weights, weighted_mse
from cadnerf_core.nerf.passes import apply_step, ray_passes
from cadnerf_core.nerf.poses import in_window
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.nerf.volrend import RenderOutput
from cadnerf_core.progress import Progress

# points [n] -> (points [n, 3] f32 in [-1, 1]^3, occupancy [n] f32 0/1)
OccupancySampler = Callable[[int], tuple[np.ndarray, np.ndarray]]

POOL_MAX = 1 << 18  # CAD occupancy samples drawn once for phase one
PLANE_TV_WINDOW = 64  # texels a side of each colour plane's square in a step's smoothness


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


def _pass_loss(loss: torch.Tensor, out: RenderOutput, cfg: Phase2Config | Phase3Config,
               share: float) -> torch.Tensor:
    """One pass's loss: its re-rendering ``loss`` plus the deformation regularisers, scaled by
    the pass's ``share`` of the step's rays (the passes then add up to the step's means)."""
    loss = loss + cfg.lambda_offset * out.offset_norm + cfg.lambda_correction * out.correction_abs
    if share < 1.0:
        loss = loss * share
    return loss


def _matches_pass(state: TrainState, data: TrainData, weight: float,
                  posing: bool) -> Iterator[torch.Tensor]:
    """The step's pass of the matches' loss: one while the poses learn (``posing``) and the
    photos have matches, else none."""
    loss = matches_loss(state, data, weight) if posing else None
    if loss is not None:
        yield loss


def phase2_step(state: TrainState, data: TrainData, optimizer: torch.optim.Optimizer | None,
                pose_optimizer: torch.optim.Optimizer | None, step: int) -> float:
    """One silhouette step: G (or D) and, inside the window, the poses (with the photos'
    matches, ``phase2.lambda_matches``). Returns the loss."""
    cfg = state.config.phase2
    state.fields.set_anneal((step / max(cfg.steps, 1) - cfg.anneal[0])
                            / max(cfg.anneal[1] - cfg.anneal[0], 1e-6))
    img, x, y = sample_pixels(data, cfg.rays)

    def losses() -> Iterator[torch.Tensor]:
        for part, share in ray_passes(state, len(img)):
            out = render_batch(state, data, img[part], x[part], y[part], False,
                               pose_optimizer is not None)
            weight = pixel_weights(data, img[part], x[part], y[part])
            loss = weighted_mse(out.acc, data.masks[img[part], y[part], x[part]], weight)
            yield _pass_loss(loss, out, cfg, share)
        yield from _matches_pass(state, data, cfg.lambda_matches, pose_optimizer is not None)

    return apply_step(losses(), optimizer, pose_optimizer)


def _phase3_groups(state: TrainState, cfg: Phase3Config) -> list[dict[str, object]]:
    """Phase three's parameter groups: the networks at ``lr``, the colour planes (where the
    field has them) at ``plane_lr``; the background waits for the scene steps."""
    planes = state.fields.color.planes
    nets = [p for name, p in state.fields.named_parameters()
            if not name.startswith(("background.", "color.planes."))]
    groups: list[dict[str, object]] = [{"params": nets, "lr": cfg.lr}]
    if planes is not None:
        groups.append({"params": list(planes.parameters()), "lr": cfg.plane_lr})
    return groups


def _phase2_params(state: TrainState) -> list[torch.nn.Parameter]:
    """What phase two fits besides the poses: G, and D unless ``phase2.train_density`` is off
    (then G deforms a frozen D; without G, nothing: the shape stays the CAD model's and only
    the poses move)."""
    deformation = state.fields.deformation
    density = list(state.fields.density.parameters()) if state.config.phase2.train_density \
        else []
    return density if deformation is None else [*deformation.parameters(), *density]


def run_phase2(state: TrainState, data: TrainData, progress: Progress | None = None) -> None:
    """Phase two: deformation and poses from the silhouettes."""
    cfg = state.config.phase2
    torch.manual_seed(state.config.seed + 2)
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
        loss = phase2_step(state, data, optimizer, pose_optimizer if active else None, step)
        state.log("phase2/loss", loss)
        update_grids(state, step)
        _report(progress, "phase2", step, cfg.steps)
    state.fields.density.requires_grad_(True)
    state.fields.set_anneal(1.0)


def phase3_step(state: TrainState, data: TrainData, optimizer: torch.optim.Optimizer,
                pose_optimizer: torch.optim.Optimizer | None = None, scene: bool = False,
                targets: torch.Tensor | None = None,
                on_object: torch.Tensor | None = None) -> float:
    """One colour step (D, G and colour; the background too in scene mode; the poses inside
    phase three's window, with the photos' matches, ``phase3.lambda_matches``; a share
    ``phase3.object_rays`` of the rays among ``on_object``, ``batch.object_pixels``).
    Returns the loss."""
    cfg = state.config.phase3
    img, x, y = sample_pixels(data, cfg.rays, 0.0 if scene else cfg.object_rays, on_object)
    target = data.scene_images if scene and data.scene_images is not None else data.images
    if targets is not None:
        target = targets
    white = None if scene else torch.ones(3, device=state.device)

    def losses() -> Iterator[torch.Tensor]:
        for part, share in ray_passes(state, len(img)):
            pimg, px, py = img[part], x[part], y[part]
            out = render_batch(state, data, pimg, px, py, True, pose_optimizer is not None,
                               white, cull=True)
            assert out.rgb is not None
            loss = F.mse_loss(out.rgb, target[pimg, py, px])
            if cfg.mask_weight > 0:
                weight = pixel_weights(data, pimg, px, py)
                loss = loss + cfg.mask_weight * weighted_mse(out.acc, data.masks[pimg, py, px],
                                                             weight)
            yield _pass_loss(loss, out, cfg, share)
        yield from _matches_pass(state, data, cfg.lambda_matches, pose_optimizer is not None)
        planes = state.fields.color.planes
        if planes is not None and cfg.lambda_planes > 0:
            yield cfg.lambda_planes * planes.smoothness(PLANE_TV_WINDOW)

    return apply_step(losses(), optimizer, pose_optimizer)


def run_phase3(state: TrainState, data: TrainData, progress: Progress | None = None) -> None:
    """Phase three: colour re-rendering on white; then, in scene mode, with the background."""
    cfg = state.config.phase3
    torch.manual_seed(state.config.seed + 3)
    state.fields.set_anneal(1.0)
    background = state.fields.background
    optimizer = adam(_phase3_groups(state, cfg), cfg.lr, state.device)
    scene_steps = cfg.scene_steps if background is not None and data.scene_images is not None \
        else 0
    total = cfg.steps + scene_steps
    pose_optimizer = adam(state.poses.optimizer_groups(cfg.pose_lr, state.config.phase2.focal_lr),
                          cfg.pose_lr, state.device)
    blurred: dict[float, torch.Tensor] = {}
    on_object = object_pixels(data) if cfg.object_rays > 0 else None
    refresh_fine_grid(state)
    for step in range(cfg.steps):
        active = state.config.optimise_poses and in_window(step, cfg.steps, cfg.pose_window)
        sigma = target_blur(step, cfg.steps, cfg.pose_window, cfg.pose_blur) * data.width
        if active and sigma > 0 and sigma not in blurred:
            blurred[sigma] = blur_images(data.images, sigma)
        targets = blurred[sigma] if active and sigma > 0 else None
        state.log("phase3/loss", phase3_step(state, data, optimizer,
                                             pose_optimizer if active else None,
                                             targets=targets, on_object=on_object))
        update_grids(state, step)
        _report(progress, "phase3", step, total)
    if scene_steps and background is not None:
        optimizer.add_param_group({"params": list(background.parameters())})
        for step in range(scene_steps):
            state.log("phase3/scene_loss", phase3_step(state, data, optimizer, None, scene=True))
            _report(progress, "phase3", cfg.steps + step, total)
