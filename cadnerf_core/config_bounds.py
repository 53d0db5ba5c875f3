"""Bounds of the pipeline config (``cadnerf_core.config``): the largest value of each field that
scales a job's work or memory, and the budget on points per pass x network width; and the base
class of its sections.

Each bound is several times what the largest preset uses, so no sensible job is refused;
with ``MAX_POINT_WIDTH`` they keep the largest accepted job within a worker's memory
(``docs/reliability.md``, section 6).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import BaseModel, ConfigDict

if TYPE_CHECKING:
    from cadnerf_core.config import PipelineConfig



class Frozen(BaseModel):
    """Base of every config section: immutable, unknown keys rejected (a typo in an override
    must fail loudly)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


MAX_STEPS = 50_000  # per phase (``paper``: 20 000 in phase three)
MAX_POINTS = 262_144  # CAD occupancy points per phase-one step (``standard``: 32 768)
MAX_RAYS = 65_536  # rays per step, rendering chunk or pass (``standard``: 8192)
MAX_SAMPLES = 512  # samples per ray (``paper``: 128)
MAX_LR = 1.0  # Adam steps this large already throw every weight away
MAX_WEIGHT = 1000.0  # loss weights (``paper``: 10)
MAX_SEED = 2**31 - 1  # numpy and torch take it on every platform
MAX_MATCH_SIZE = 2048  # long side of the crops features are found in
MAX_POINT_WIDTH = 2**26
"""Most (points evaluated in one training pass) x (widest network): the activations a pass keeps
for its backward pass, the memory that grows with a configuration. ``standard`` and ``paper``
are at it on a GPU (one pass of all rays)."""
MAX_RENDER_POINT_WIDTH = 4 * MAX_POINT_WIDTH
"""The same for a rendering chunk, which keeps no activations for a backward pass."""


def point_loads(config: PipelineConfig) -> dict[str, int]:
    """Points evaluated in one training pass of each kind, named by the fields setting them."""
    render = config.render
    pass_rays = {name: min(rays, render.train_pass_rays or rays)
                 for name, rays in (("phase2.rays", config.phase2.rays),
                                    ("phase3.rays", config.phase3.rays))}
    loads = {f"{name} x render.samples_per_ray": rays * render.samples_per_ray
             for name, rays in pass_rays.items()}
    loads["phase1.batch_points"] = config.phase1.batch_points
    return loads


def check_point_budget(config: PipelineConfig) -> None:
    """Raise ValueError naming the fields when points per pass x network width passes
    ``MAX_POINT_WIDTH`` (each field within its own bound can still multiply past memory)."""
    field, render = config.field, config.render
    width = max(field.hidden, field.deform_hidden, field.color_hidden)
    loads = [(what, points, MAX_POINT_WIDTH) for what, points in point_loads(config).items()]
    loads.append(("render.chunk_rays x render.samples_per_ray",
                  render.chunk_rays * render.samples_per_ray, MAX_RENDER_POINT_WIDTH))
    for what, points, limit in loads:
        if points * width > limit:
            raise ValueError(
                f"{what} = {points} points per pass x network width {width} = "
                f"{points * width}; the limit is {limit}: lower one of them (width: the "
                "largest of field.hidden, deform_hidden, color_hidden)")
