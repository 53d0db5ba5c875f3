"""Keeping a job's skip grids in step with the learned field during training: the training
grid refreshed every ``render.grid_update_every`` steps, and the finer grid phase three's
culled passes look up."""

from __future__ import annotations

from collections.abc import Callable

import torch

from cadnerf_core.nerf.device import autocast
from cadnerf_core.nerf.grid import REFINE_FACTOR
from cadnerf_core.nerf.state import TrainState


def _occupancy_fn(state: TrainState) -> Callable[[torch.Tensor], torch.Tensor]:
    def occupancy(p: torch.Tensor) -> torch.Tensor:
        with autocast(state):
            return state.fields.query(p, None).occupancy

    return occupancy


def update_grids(state: TrainState, step: int) -> None:
    """After ``step``: every ``render.grid_update_every`` steps, the training grid (and the
    fine grid, when there is one) remade from the learned field."""
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
