"""Occupancy grid for empty-space skipping.

A coarse boolean grid over [-bound, bound]^3. It starts from the retrieved CAD model's occupancy
(dilated, so the deformation can grow the shape), and is refreshed from the learned occupancy
during training (again dilated). Samples in empty cells are never sent to the networks.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F

REFINE_FACTOR = 2
"""How many times finer than training's the grids made from a learned field are
(``SkipGrid.refined``): phase three's culled passes and display renders use them."""


class SkipGrid:
    """A boolean grid ``occupied`` [G, G, G] (index order x, y, z) over [-bound, bound]^3."""

    def __init__(self, occupied: torch.Tensor, bound: float) -> None:
        self.occupied = occupied.bool()
        self.bound = bound

    @property
    def resolution(self) -> int:
        """Cells per side."""
        return int(self.occupied.shape[0])

    @classmethod
    def full(cls, resolution: int, bound: float, device: torch.device | str = "cpu") -> SkipGrid:
        """A grid with every cell occupied (no skipping)."""
        return cls(torch.ones((resolution,) * 3, dtype=torch.bool, device=device), bound)

    def cell_centres(self) -> torch.Tensor:
        """Centres of all cells, x-major. Returns [G^3, 3]."""
        G = self.resolution
        steps = torch.arange(G, device=self.occupied.device) + 0.5
        axis = steps / G * 2 * self.bound - self.bound
        xs, ys, zs = torch.meshgrid(axis, axis, axis, indexing="ij")
        return torch.stack([xs, ys, zs], -1).reshape(-1, 3)

    def contains(self, points: torch.Tensor) -> torch.Tensor:
        """Whether points lie in occupied cells (False outside the grid).

        Args:
            points: [N, 3].
        Returns:
            [N] bool.
        """
        G = self.resolution
        idx = torch.floor((points + self.bound) / (2 * self.bound) * G).long()
        inside = ((idx >= 0) & (idx < G)).all(-1)
        idx = idx.clamp(0, G - 1)
        return inside & self.occupied[idx[:, 0], idx[:, 1], idx[:, 2]]

    def fraction(self) -> float:
        """Fraction of occupied cells."""
        return float(self.occupied.float().mean())

    def set_from_values(self, values: torch.Tensor, threshold: float, dilation: int) -> None:
        """Occupied where ``values`` [G^3] (per cell, x-major) exceed ``threshold``, dilated."""
        occ = (values.reshape((self.resolution,) * 3) > threshold).float()
        if not bool(occ.any()):
            # An update that finds nothing (a collapsed density early in a phase) would stop all
            # sampling for good; keep the previous grid instead.
            return
        self.occupied = dilate(occ, dilation).bool()

    @torch.no_grad()
    def update(self, occupancy_fn: Callable[[torch.Tensor], torch.Tensor], threshold: float,
               dilation: int, chunk: int = 65536) -> None:
        """Refresh from a learned occupancy at one random point per cell (as nerfacc does; the
        dilation covers what a single sample misses).

        Args:
            occupancy_fn: points [P, 3] -> occupancy [P] in [0, 1].
        """
        centres = self.cell_centres()
        cell = 2 * self.bound / self.resolution
        pts = centres + (torch.rand(centres.shape, device=centres.device) - 0.5) * cell
        vals = torch.cat([occupancy_fn(pts[i:i + chunk]).float()
                          for i in range(0, pts.shape[0], chunk)])
        self.set_from_values(vals, threshold, dilation)

    @torch.no_grad()
    def refined(self, occupancy_fn: Callable[[torch.Tensor], torch.Tensor], factor: int,
                threshold: float, dilation: int = 1, chunk: int = 65536) -> SkipGrid:
        """A grid ``factor`` times finer (for display renders and culled training passes):
        occupied where the learned occupancy at a fine cell's centre exceeds ``threshold``
        (dilated by ``dilation`` fine cells, for what a centre misses) and this grid is
        occupied (what training never sampled stays empty, as it rendered in training).
        Where that finds nothing (a collapsed field), this grid's cells, each split.

        Args:
            occupancy_fn: points [P, 3] -> occupancy [P] in [0, 1].
        Returns:
            A grid of ``resolution * factor`` cells a side over the same bounds.
        """
        fine = SkipGrid.full(self.resolution * factor, self.bound, self.occupied.device)
        coarse = self.occupied.repeat_interleave(factor, 0).repeat_interleave(factor, 1)
        coarse = coarse.repeat_interleave(factor, 2).reshape(-1)
        # Only the fine cells inside occupied coarse ones are looked up: the rest stay empty.
        idx = coarse.nonzero()[:, 0]
        centres = fine.cell_centres()[idx]
        vals = torch.zeros(coarse.shape[0], device=coarse.device)
        if idx.numel():
            vals[idx] = torch.cat([occupancy_fn(centres[i:i + chunk]).float()
                                   for i in range(0, centres.shape[0], chunk)])
        occ = dilate((vals.reshape((fine.resolution,) * 3) > threshold).float(), dilation)
        fine.occupied = coarse.reshape(occ.shape).clone()
        if bool(occ.any()):
            fine.occupied &= occ.bool()
        return fine


def dilate(occ: torch.Tensor, cells: int) -> torch.Tensor:
    """Binary dilation of a [G, G, G] float grid by ``cells`` (a cube structuring element)."""
    if cells <= 0:
        return occ
    k = 2 * cells + 1
    return F.max_pool3d(occ[None, None], kernel_size=k, stride=1, padding=cells)[0, 0]


def grid_from_occupancy(query: Callable[[np.ndarray], np.ndarray], resolution: int,
                        bound: float, dilation: int, subsamples: int = 3,
                        device: torch.device | str = "cpu") -> SkipGrid:
    """A skip grid from a CAD occupancy query (e.g. the library's ``OccupancyGrid.query``).

    Args:
        query: points [P, 3] float -> occupancy [P] (bool, or float thresholded at 0.5).
        resolution, bound: the skip grid's cells per side and half extent.
        dilation: cells added around occupied ones.
        subsamples: points per cell side tested (a cell is occupied if any is inside).
    """
    grid = SkipGrid.full(resolution, bound, device)
    centres = grid.cell_centres().cpu().numpy()
    cell = 2 * bound / resolution
    offs = ((np.arange(subsamples) + 0.5) / subsamples - 0.5) * cell
    any_inside = np.zeros(len(centres), dtype=bool)
    for dx in offs:
        for dy in offs:
            for dz in offs:
                any_inside |= np.asarray(query(centres + np.array([dx, dy, dz]))) > 0.5
    grid.set_from_values(torch.from_numpy(any_inside).to(device).float(), 0.5, dilation)
    return grid
