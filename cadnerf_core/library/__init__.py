"""Stage 3: the mini CAD library (its files, silhouettes and occupancy grids).

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "format": ("Library", "LibrarySpec", "load_library"),
    "occupancy": ("OccupancyGrid", "compute_occupancy", "sample_occupancy"),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["Library", "LibrarySpec", "OccupancyGrid", "compute_occupancy", "load_library",
    "sample_occupancy"]

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library, LibrarySpec, load_library
    from cadnerf_core.library.occupancy import OccupancyGrid, compute_occupancy, sample_occupancy
