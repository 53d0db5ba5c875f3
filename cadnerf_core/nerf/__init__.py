"""Stages 6-8: the fields, volume rendering, empty-space skipping, poses and the three phases.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "model": ("TrainedModel", "resolve_device"),
    "fields": ("CadNerfFields",),
    "state": ("TrainData", "TrainState"),
    "checkpoint": ("last_checkpoint", "save_checkpoint"),
    "grid": ("grid_from_occupancy",),
    "volrend": ("march_rays",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["CadNerfFields", "TrainData", "TrainState", "TrainedModel", "grid_from_occupancy",
    "last_checkpoint", "march_rays", "resolve_device", "save_checkpoint"]

if TYPE_CHECKING:
    from cadnerf_core.nerf.checkpoint import last_checkpoint, save_checkpoint
    from cadnerf_core.nerf.fields import CadNerfFields
    from cadnerf_core.nerf.grid import grid_from_occupancy
    from cadnerf_core.nerf.model import TrainedModel, resolve_device
    from cadnerf_core.nerf.state import TrainData, TrainState
    from cadnerf_core.nerf.volrend import march_rays
