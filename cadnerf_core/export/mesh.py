"""The mesh: marching cubes on the learned density, its specks dropped, decimated, textured from
the photos (``photo_texture``) and, where no photo sees it, from the colour field.

Written as ``mesh.glb`` (binary glTF 2.0: +Y up as glTF wants, which is our world's up; one
unit = the radius of the object's bounding sphere, not metres, as ``poses.json`` says) and as
``mesh.obj`` + ``mesh.mtl`` + ``mesh_texture.png`` for tools without glTF, and as
``mesh.usdz`` for AR Quick Look (``export.usdz``, where Pixar's USD is installed).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from cadnerf_core.export.photo_texture import PhotoView, photo_colours
from cadnerf_core.export.texture import TexturedMesh, bake_texture, decimate
from cadnerf_core.export.usdz import write_usdz
from cadnerf_core.jobfolder import (
    MESH,
    MESH_MTL,
    MESH_OBJ,
    MESH_TEXTURE,
    MESH_USDZ,
    JobFolder,
    atomic_path,
)
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel


def extract_mesh(occupancy: np.ndarray, bound: float, level: float) -> trimesh.Trimesh:
    """Marching cubes (scikit-image) on an occupancy grid over [-bound, bound]^3.

    A field that never crosses ``level`` (barely trained) is cut halfway between its extremes
    instead, so there is always a surface unless the field is constant.

    Args:
        occupancy: [G, G, G] values, index order x, y, z.
    Returns:
        The mesh in world coordinates (no colours yet).
    Raises:
        ValueError: the field is constant (nothing to extract).
    """
    from skimage.measure import marching_cubes

    lo, hi = float(occupancy.min()), float(occupancy.max())
    if hi - lo < 1e-6:
        raise ValueError("the density field is constant: no surface to extract")
    if not lo < level < hi:
        level = (lo + hi) / 2.0
    # Pad with empty space so the surface closes at the grid's border.
    padded = np.pad(occupancy, 1, constant_values=min(lo, 0.0))
    G = occupancy.shape[0]
    spacing = 2.0 * bound / (G - 1)
    verts, faces, _, _ = marching_cubes(padded, level=level, spacing=(spacing,) * 3)
    verts = verts - bound - spacing
    # Occupancy grows inward, so scikit-image's triangles face into the object: flip them
    # (vertex normals then follow from the faces).
    return trimesh.Trimesh(vertices=verts, faces=faces[:, ::-1], process=False)


MIN_PIECE_SHARE = 0.02
"""Pieces of the surface with less area than this share of the largest piece's are dropped:
the specks of density a few-view NeRF leaves in empty space (what they do to the mesh and to
the UV unwrap: ``benchmarks.bench_mesh``)."""


def piece_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """Each triangle's connected piece (triangles joined by shared vertices). Returns [F]."""
    return trimesh.graph.connected_component_labels(mesh.face_adjacency, len(mesh.faces))


def drop_small_pieces(mesh: trimesh.Trimesh, min_share: float = MIN_PIECE_SHARE
                      ) -> trimesh.Trimesh:
    """The mesh without its connected pieces smaller in area than ``min_share`` of the largest
    piece's (the largest is always kept)."""
    if len(mesh.faces) == 0 or min_share <= 0.0:
        return mesh
    labels = piece_labels(mesh)
    areas = np.bincount(labels, weights=mesh.area_faces)
    keep = areas >= min_share * areas.max()
    if keep.all():
        return mesh
    out = mesh.copy()
    out.update_faces(keep[labels])
    out.remove_unreferenced_vertices()
    return out


def occupancy_grid(model: TrainedModel, check: Callable[[], None] | None = None) -> np.ndarray:
    """The learned occupancy on the ``export.mesh_resolution`` grid over the render bound
    (the slow part of the mesh). Returns [G, G, G], index order x, y, z."""
    G, bound = model.state.config.export.mesh_resolution, model.state.config.render.bound
    axis = np.linspace(-bound, bound, G, dtype=np.float32)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    return model.occupancy(points, check=check).reshape(G, G, G)


def surface(model: TrainedModel, grid: np.ndarray,
            min_share: float = MIN_PIECE_SHARE) -> trimesh.Trimesh:
    """The untextured surface a job exports from its ``occupancy_grid``: marching cubes, pieces
    under ``min_share`` of the largest dropped, decimated to ``export.mesh_faces`` triangles;
    in the job's world frame."""
    ecfg = model.state.config.export
    whole = extract_mesh(grid, model.state.config.render.bound, ecfg.mesh_level)
    return decimate(drop_small_pieces(whole, min_share), ecfg.mesh_faces)


def write_glb(path: Path, mesh: TexturedMesh) -> None:
    """Write the textured mesh as binary glTF (with vertex normals, so it shades smoothly),
    atomically."""
    with atomic_path(path) as tmp:
        data = mesh.to_trimesh().export(file_type="glb", include_normals=True)
        assert isinstance(data, bytes)
        tmp.write_bytes(data)


def obj_text(mesh: TexturedMesh, mtl_name: str) -> str:
    """Wavefront OBJ of the textured mesh: positions, UVs, one material; faces ``v/vt``."""
    lines = ["# CAD-NeRF mesh: +Y up, 1 unit = the object's bounding-sphere radius",
             f"mtllib {mtl_name}", "o mesh"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in mesh.uv]
    lines.append("usemtl baked")
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in mesh.faces + 1]
    return "\n".join(lines) + "\n"


def mtl_text(texture_name: str) -> str:
    """The OBJ material: diffuse colour from the texture, no specular highlight."""
    return ("newmtl baked\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nNs 0\nillum 1\nd 1\n"
            f"map_Kd {texture_name}\n")


def write_obj(folder: JobFolder, mesh: TexturedMesh) -> None:
    """``mesh.obj``, ``mesh.mtl`` and ``mesh_texture.png`` (names relative to each other)."""
    from PIL import Image

    with atomic_path(folder.file(MESH_TEXTURE)) as tmp:
        Image.fromarray(mesh.texture, "RGB").save(tmp, format="PNG")
    folder.write_text(MESH_MTL, mtl_text(Path(MESH_TEXTURE).name))
    folder.write_text(MESH_OBJ, obj_text(mesh, Path(MESH_MTL).name))


EXPORT_STEPS = 6
"""Reports of stage "export": the mesh's occupancy, its surface, its texture and its files
(``export_mesh``), the files for other tools, ``results.zip`` (``artifacts.export_job``)."""


def export_mesh(job_dir: Path, model: TrainedModel, progress: Progress | None = None,
                views: Sequence[PhotoView] = ()) -> TexturedMesh:
    """mesh.glb, mesh.obj and mesh.usdz: marching cubes on the learned occupancy, decimated to
    ``export.mesh_faces`` triangles, coloured into an ``export.texture_size`` texture.

    Args:
        views: the photos with their refined cameras (``photo_texture.photo_views``); with
            ``export.texture_from_photos`` they colour every texel they see, the field the rest.
    Returns:
        The textured mesh.
    """
    ecfg = model.state.config.export
    check = None if progress is None else progress.check

    def report(done: int) -> None:
        if progress is not None:
            progress.step("export", done, EXPORT_STEPS)

    grid = occupancy_grid(model, check)
    report(1)
    mesh = surface(model, grid)
    report(2)

    def color(p: np.ndarray, d: np.ndarray) -> np.ndarray:
        return model.colors(p, d, check=check)

    photos = (partial(photo_colours, mesh, views, check=check)
              if ecfg.texture_from_photos and views else None)
    textured = bake_texture(mesh, color, ecfg.texture_size, check, photos)
    report(3)  # then checks: before any output, a cancelled or deleted job writes nothing more
    folder = JobFolder(job_dir)
    write_glb(folder.file(MESH), textured)
    write_obj(folder, textured)
    write_usdz(folder.file(MESH_USDZ), textured, folder.file(MESH_TEXTURE), check)
    report(4)
    return textured
