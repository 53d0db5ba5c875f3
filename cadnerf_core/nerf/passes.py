"""One optimiser step over several passes: a step's rays split into forward and backward
passes that fit in memory, their gradients added up, then one guarded update."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

import torch

from cadnerf_core.nerf.state import TrainState

log = logging.getLogger(__name__)

CPU_PASS_RAYS = 2048  # ``render.train_pass_rays`` 0 on the CPU


def ray_passes(state: TrainState, n: int) -> list[tuple[slice, float]]:
    """How a step's ``n`` rays are split into forward and backward passes
    (``render.train_pass_rays``): each pass's slice and its share of the rays."""
    size = state.config.render.train_pass_rays
    if size <= 0:
        size = n if state.device.type == "cuda" else CPU_PASS_RAYS
    return [(slice(start, min(start + size, n)), (min(start + size, n) - start) / n)
            for start in range(0, n, size)]


def apply_step(losses: Iterable[torch.Tensor], optimizer: torch.optim.Optimizer | None,
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
