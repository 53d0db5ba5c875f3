"""A textured mesh from the fields: decimate, UV-unwrap (``atlas``), bake the colour into a texture.

Viewers and DCC tools read a PBR material with a ``baseColorTexture`` far better than vertex
colours (glTF reads those as linear, and Blender ignores them without a material). The radiance
field's colours are trained against the photos' 8-bit values, so they are sRGB-encoded already:
exactly what a glTF ``baseColorTexture`` (and an OBJ ``map_Kd``) holds, with no conversion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from cadnerf_core.export.atlas import unwrap

ColorFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Colour of points [P, 3] seen along unit directions [P, 3] -> [P, 3] in [0, 1]."""

PhotoFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Colour the photos give surface points [P, 3] with unit outward normals [P, 3]: rgb [P, 3]
in [0, 1] and seen [P] bool (``photo_texture.photo_colours``)."""

PADDING = 2
"""Texels between charts in the atlas, so bilinear sampling at a seam stays in its chart."""


ROUGHNESS = 0.9
"""Roughness of the exported material (GLB and USDZ): matte, as the baked colour already holds
the photos' shading."""

SLIVER = 1e-5
"""Triangles smaller than this fraction of the mean area are dropped before unwrapping:
marching cubes leaves slivers of near-coincident vertices that xatlas cannot chart."""


@dataclass(frozen=True)
class TexturedMesh:
    """A mesh with one UV per vertex and its baked colour texture."""

    vertices: np.ndarray  # [V, 3] float, world units
    faces: np.ndarray  # [F, 3] int, counter-clockwise seen from outside
    uv: np.ndarray  # [V, 2] in [0, 1], v up (OBJ and trimesh convention)
    texture: np.ndarray  # [S, S, 3] uint8, sRGB

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh with a non-metallic PBR material holding the texture (for GLB and OBJ)."""
        from PIL import Image

        material = trimesh.visual.material.PBRMaterial(
            name="baked", baseColorTexture=Image.fromarray(self.texture, "RGB"),
            metallicFactor=0.0, roughnessFactor=ROUGHNESS)
        visual = trimesh.visual.TextureVisuals(uv=self.uv, material=material)
        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, visual=visual,
                               process=False)


def decimate(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """The mesh simplified (quadric error, fast-simplification) to at most about ``max_faces``
    triangles, without zero-area triangles (xatlas leaves those unmapped) or unused vertices.
    A mesh already that small is only cleaned."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if len(faces) > max_faces:
        import fast_simplification

        vertices, faces = fast_simplification.simplify(
            vertices.astype(np.float32), faces.astype(np.int32),
            target_reduction=1.0 - max_faces / len(faces))
    out = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    areas = out.area_faces
    out.update_faces(areas > SLIVER * max(float(areas.mean()), 1e-30))
    out.remove_unreferenced_vertices()
    return out


def rasterize_uv(uv: np.ndarray, faces: np.ndarray, size: int,
                 margin: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which triangle covers each texel centre of a ``size`` x ``size`` texture, and where.

    Every triangle's bounding box of texels is enumerated at once (triangles of an atlas are a
    few texels wide). A texel belongs to the triangle it lies deepest inside; texels up to
    ``margin`` texels outside a chart's border are claimed too (barycentrics clamped), so that
    bilinear filtering at the border reads the chart's own colours (``PADDING`` keeps charts
    further apart than that).

    Args:
        uv: [V, 2] in [0, 1], v up; faces: [F, 3].
    Returns:
        texel [T] (row * size + column, each at most once), face [T], barycentric [T, 3]
        (non-negative, summing to 1).
    """
    corners = uv[faces] * size  # [F, 3, 2]
    corners[..., 1] = size - corners[..., 1]  # v up -> image row down
    lo = np.clip(np.ceil(corners.min(1) - 0.5 - margin), 0, size - 1).astype(np.int64)
    hi = np.clip(np.floor(corners.max(1) - 0.5 + margin), 0, size - 1).astype(np.int64)
    extent = np.maximum(hi - lo + 1, 0)
    count = extent[:, 0] * extent[:, 1]
    face = np.repeat(np.arange(len(faces)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    col = lo[face, 0] + local % extent[face, 0]
    row = lo[face, 1] + local // extent[face, 0]
    p = np.stack([col + 0.5, row + 0.5], 1)
    tri = corners[face]  # [T, 3, 2]
    # Signed distance (texels) of the centre to each edge, positive inside; the edge facing
    # corner k gives barycentric k.
    edge_start, edge_end = tri[:, [1, 2, 0]], tri[:, [2, 0, 1]]
    direction = edge_end - edge_start
    length = np.maximum(np.linalg.norm(direction, axis=2), 1e-12)
    cross = (direction[..., 0] * (p[:, None, 1] - edge_start[..., 1])
             - direction[..., 1] * (p[:, None, 0] - edge_start[..., 0]))
    area = ((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
            - (tri[:, 1, 1] - tri[:, 0, 1]) * (tri[:, 2, 0] - tri[:, 0, 0]))
    orient = np.where(area < 0, -1.0, 1.0)[:, None]
    depth = (cross * orient / length).min(1)
    keep = (depth >= -margin) & (np.abs(area) > 1e-12)
    bary = np.clip(cross * orient / np.abs(np.where(keep, area, 1.0))[:, None], 0.0, None)
    bary /= np.maximum(bary.sum(1, keepdims=True), 1e-12)
    texel = (row * size + col)[keep]
    order = np.lexsort((-depth[keep], texel))  # per texel, the deepest triangle first
    texel, first = np.unique(texel[order], return_index=True)
    return texel, face[keep][order][first], bary[keep][order][first]


def fill_empty(texture: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Every uncovered texel takes the colour of the nearest covered one, so filtering and
    mipmaps at chart borders never blend in a background colour.

    Args:
        texture: [S, S, 3]; covered: [S, S] bool.
    """
    from scipy.ndimage import distance_transform_edt

    if not covered.any():
        return texture
    _, (rows, cols) = distance_transform_edt(~covered, return_indices=True)
    return texture[rows, cols]


def bake_texture(mesh: trimesh.Trimesh, color: ColorFn, size: int,
                 check: Callable[[], None] | None = None,
                 photos: PhotoFn | None = None) -> TexturedMesh:
    """UV-unwrap ``mesh`` and bake ``color`` (seen head-on, against each point's normal) into a
    ``size`` x ``size`` sRGB texture.

    Args:
        mesh: the (decimated) surface, outward normals.
        color: the radiance field's colour at points seen along directions.
        check: called while the atlas is made (a cancel raises).
        photos: the photos' colour of the texels; where given, ``color`` only fills the
            texels no photo sees.
    """
    vertices = np.asarray(mesh.vertices, np.float64)
    normals = np.asarray(mesh.vertex_normals, np.float64)
    vmapping, faces, uv = unwrap(vertices, np.asarray(mesh.faces), size, PADDING, check)
    vertices, normals = vertices[vmapping], normals[vmapping]
    texel, face, bary = rasterize_uv(uv, faces, size)
    points = np.einsum("tk,tkd->td", bary, vertices[faces[face]])
    normal = np.einsum("tk,tkd->td", bary, normals[faces[face]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    rgb = np.zeros((size * size, 3), np.float32)
    covered = np.zeros(size * size, bool)
    if len(texel):
        rgb[texel] = _texel_colours(points, normal, color, photos)
        covered[texel] = True
    texture = fill_empty(rgb.reshape(size, size, 3), covered.reshape(size, size))
    texture_u8 = np.round(np.clip(texture, 0.0, 1.0) * 255.0).astype(np.uint8)
    return TexturedMesh(vertices=vertices, faces=faces, uv=uv, texture=texture_u8)


def _texel_colours(points: np.ndarray, normal: np.ndarray, color: ColorFn,
                   photos: PhotoFn | None) -> np.ndarray:
    """The photos' colour of texels where some photo sees them, the field's elsewhere.

    points, normal [T, 3] -> rgb [T, 3] float32."""
    if photos is None:
        return np.asarray(color(points.astype(np.float32), (-normal).astype(np.float32)))
    rgb, seen = photos(points, normal)
    rgb = np.array(rgb, np.float32)
    if not seen.all():
        rest = ~seen
        rgb[rest] = color(points[rest].astype(np.float32), (-normal[rest]).astype(np.float32))
    return rgb
