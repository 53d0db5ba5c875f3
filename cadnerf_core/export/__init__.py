"""Stage 9: poses, views, the orbit, the textured mesh and the results bundle.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "artifacts": ("export_job",),
    "renders": ("render_orbit", "render_views"),
    "mesh": ("extract_mesh", "write_glb", "write_obj"),
    "texture": ("bake_texture",),
    "bundle": ("write_bundle",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["bake_texture", "export_job", "extract_mesh", "render_orbit", "render_views",
    "write_bundle", "write_glb", "write_obj"]

if TYPE_CHECKING:
    from cadnerf_core.export.artifacts import export_job
    from cadnerf_core.export.bundle import write_bundle
    from cadnerf_core.export.mesh import extract_mesh, write_glb, write_obj
    from cadnerf_core.export.renders import render_orbit, render_views
    from cadnerf_core.export.texture import bake_texture
