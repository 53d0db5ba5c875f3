"""Device helpers for training: reduced precision, host-to-device copies, the optimiser.

Each picks the fast path on CUDA and the plain one on the CPU, so training code calls them
without asking which device it runs on.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import torch

if TYPE_CHECKING:
    from cadnerf_core.nerf.state import TrainState


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
