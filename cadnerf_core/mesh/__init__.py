"""Meshes: loading and normalising any mesh file, and the ray-cast mesh renderer.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "meshio": ("load_mesh", "normalise_mesh"),
    "renderer": ("MeshRenderer",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["MeshRenderer", "load_mesh", "normalise_mesh"]

if TYPE_CHECKING:
    from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
    from cadnerf_core.mesh.renderer import MeshRenderer
