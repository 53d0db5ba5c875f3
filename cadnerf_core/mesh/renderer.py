"""Rendering meshes: Embree ray casting for colour, depth and masks; polygon filling for
bulk silhouettes.

One ray per pixel through the pixel centre (pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)`` in
the coordinates ``K`` maps to, so its centre is ``(i + 0.5, j + 0.5)``), OpenCV camera axes as in
``cameras.py``. Shading is Lambertian under a light near the camera plus ambient light, two-sided
(normals are turned toward the viewer), so open or badly wound meshes render without black faces.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from cadnerf_core.mesh.meshio import texture_image

AMBIENT = 0.35  # share of light reaching every surface, so nothing renders black
DEFAULT_GREY = 0.7  # colour of meshes with neither texture nor colours
# Light direction in camera axes (toward the light): from the camera, a little up and left.
LIGHT_CAMERA = np.array([-0.3, -0.4, -1.0]) / np.linalg.norm([-0.3, -0.4, -1.0])
_MAX_TESTS_PER_CHUNK = 1 << 20  # pixel-in-triangle tests per numpy batch (memory bound)


@dataclass
class RenderResult:
    """One rendered view."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1], background where nothing is hit
    mask: np.ndarray  # [H, W] bool, True where a ray hits the mesh
    depth: np.ndarray  # [H, W] float32, camera z of the hit (0 = no hit)


def pixel_rays(K: np.ndarray, c2w: np.ndarray, width: int,
               height: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the pixel centres, row-major.

    Args:
        K: [3, 3] intrinsics; c2w: [4, 4] OpenCV camera-to-world pose.
        width, height: image size in pixels.
    Returns:
        origins [H*W, 3] and directions [H*W, 3] in world axes, each direction scaled so its
        camera z component is 1 (a ray parameter is then the hit's depth).
    """
    xs, ys = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pixels = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1)
    dirs_cam = pixels @ np.linalg.inv(K).T
    dirs_cam /= dirs_cam[:, 2:3]
    directions = dirs_cam @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], directions.shape)
    return origins, directions


class _ColourSource:
    """Surface colour at ray hits from a mesh's texture, vertex or face colours, or grey."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.texture: np.ndarray | None = None  # [Th, Tw, 3] uint8
        self.face_uv: np.ndarray | None = None  # [F, 3, 2]
        self.corner_colours: np.ndarray | None = None  # [F, 3, 3] f32 (vertex colours)
        self.face_colours: np.ndarray | None = None  # [F, 3] f32
        self.flat = np.full(3, DEFAULT_GREY, dtype=np.float32)
        visual = mesh.visual
        if isinstance(visual, trimesh.visual.TextureVisuals):
            self._init_texture(mesh, visual)
        elif not isinstance(visual, trimesh.visual.ColorVisuals):
            return
        elif visual.kind == "vertex":
            colours = np.asarray(visual.vertex_colors, dtype=np.float32)[:, :3] / 255.0
            self.corner_colours = colours[mesh.faces]
        elif visual.kind == "face":
            self.face_colours = np.asarray(visual.face_colors, dtype=np.float32)[:, :3] / 255.0

    def _init_texture(self, mesh: trimesh.Trimesh, visual: trimesh.visual.TextureVisuals) -> None:
        image = texture_image(mesh)
        if image is not None:
            self.texture = np.asarray(image.convert("RGB"), dtype=np.uint8)
            self.face_uv = np.asarray(visual.uv, dtype=np.float64)[mesh.faces]
        else:
            self.flat = np.asarray(visual.material.main_color[:3], dtype=np.float32) / 255.0

    def colours(self, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Colours at hits. faces [N] int, bary [N, 3] -> [N, 3] float32 in [0, 1]."""
        if self.texture is not None and self.face_uv is not None:
            uv = np.einsum("nk,nkd->nd", bary, self.face_uv[faces])
            return sample_texture(self.texture, uv)
        if self.corner_colours is not None:
            return np.einsum("nk,nkc->nc", bary, self.corner_colours[faces]).astype(np.float32)
        if self.face_colours is not None:
            return self.face_colours[faces]
        return np.broadcast_to(self.flat, (len(faces), 3))


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup (trimesh's convention: v = 0 at the image's bottom row).

    UVs outside [0, 1] repeat the texture; samples near its border clamp to the edge texels.

    Args:
        texture: [Th, Tw, 3] uint8; uv: [N, 2].
    Returns:
        [N, 3] float32 in [0, 1].
    """
    th, tw = texture.shape[:2]
    uv = np.where((uv < 0.0) | (uv > 1.0), np.mod(uv, 1.0), uv)  # keep 1.0 on the far edge
    x = uv[:, 0] * tw - 0.5
    y = (1.0 - uv[:, 1]) * th - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    # Clamp at the border: atlases do not tile, and wrapping would bleed the far side in.
    xi, yi = x0.astype(np.int64), y0.astype(np.int64)
    x0i, x1i = np.clip(xi, 0, tw - 1), np.clip(xi + 1, 0, tw - 1)
    y0i, y1i = np.clip(yi, 0, th - 1), np.clip(yi + 1, 0, th - 1)
    top = texture[y0i, x0i] * (1 - fx) + texture[y0i, x1i] * fx
    bottom = texture[y1i, x0i] * (1 - fx) + texture[y1i, x1i] * fx
    return ((top * (1 - fy) + bottom * fy) / 255.0).astype(np.float32)


class MeshRenderer:
    """Ray-casting renderer of one mesh; the Embree scene is built once, here."""

    def __init__(self, mesh: trimesh.Trimesh, lit: bool = True) -> None:
        """Args: mesh: a triangle mesh (texture, vertex or face colours used when present);
        lit: shade it (``_shade``); False shows its colours as they are (a texture baked
        from photos or a field already holds the light)."""
        self.mesh = mesh
        self.lit = lit
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        # Embree works in float32: shift the mesh to its box centre to keep precision.
        self._offset = (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=(vertices - self._offset).astype(np.float32),
                     indices=np.asarray(mesh.faces, dtype=np.int32))
        self._normals = np.asarray(mesh.face_normals, dtype=np.float64)
        self._colours = _ColourSource(mesh)

    def _cast(self, K: np.ndarray, c2w: np.ndarray, width: int,
              height: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Cast one ray per pixel. Returns directions [H*W, 3] and Embree's hit record."""
        origins, directions = pixel_rays(np.asarray(K, dtype=np.float64),
                                         np.asarray(c2w, dtype=np.float64), width, height)
        hits = self._scene.run((origins - self._offset).astype(np.float32),
                               directions.astype(np.float32), output=1)
        return directions, hits

    def silhouette(self, K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> np.ndarray:
        """Where the mesh covers a pixel centre.

        Args:
            K: [3, 3]; c2w: [4, 4] OpenCV pose; width, height: image size.
        Returns:
            mask: [H, W] bool.
        """
        _, hits = self._cast(K, c2w, width, height)
        return (hits["primID"] >= 0).reshape(height, width)

    def render(self, K: np.ndarray, c2w: np.ndarray, width: int, height: int,
               background: float | Sequence[float] = 1.0) -> RenderResult:
        """Colour, mask and depth of one view.

        Args:
            K: [3, 3] intrinsics; c2w: [4, 4] OpenCV camera-to-world pose.
            width, height: image size in pixels.
            background: grey level or RGB triple for pixels with no hit.
        Returns:
            RenderResult with rgb [H, W, 3] f32, mask [H, W] bool, depth [H, W] f32.
        """
        directions, hits = self._cast(K, c2w, width, height)
        hit = hits["primID"] >= 0
        faces = hits["primID"][hit].astype(np.int64)
        u, v = hits["u"][hit].astype(np.float64), hits["v"][hit].astype(np.float64)
        bary = np.stack([1.0 - u - v, u, v], axis=1)
        rgb = np.empty((width * height, 3), dtype=np.float32)
        rgb[:] = np.broadcast_to(np.asarray(background, dtype=np.float32), 3)
        rgb[hit] = self._colours.colours(faces, bary)
        if self.lit:
            rgb[hit] *= self._shade(faces, directions[hit], c2w)
        depth = np.zeros(width * height, dtype=np.float32)
        depth[hit] = hits["tfar"][hit]
        return RenderResult(rgb=np.clip(rgb, 0.0, 1.0).reshape(height, width, 3),
                            mask=hit.reshape(height, width), depth=depth.reshape(height, width))

    def _shade(self, faces: np.ndarray, directions: np.ndarray, c2w: np.ndarray) -> np.ndarray:
        """Lambertian shading factor of hits. faces [N], directions [N, 3] -> [N, 1] f32."""
        normals = self._normals[faces]
        facing = np.einsum("nd,nd->n", normals, directions)
        normals = normals * np.where(facing > 0, -1.0, 1.0)[:, None]
        light = np.asarray(c2w, dtype=np.float64)[:3, :3] @ LIGHT_CAMERA
        lambert = np.clip(normals @ light, 0.0, 1.0)
        return (AMBIENT + (1.0 - AMBIENT) * lambert).astype(np.float32)[:, None]


def render_silhouette_polygons(mesh: trimesh.Trimesh, K: np.ndarray, c2w: np.ndarray,
                               width: int, height: int) -> np.ndarray:
    """Silhouette by projecting every triangle and filling it (no ray casting).

    A pixel is covered when its centre lies in a projected triangle (edges included), the rule
    of the ray caster. Triangles are grouped by the size of their pixel box and tested in bulk
    with numpy edge functions. (``cv2.fillPoly`` on many triangles uses the even-odd rule, which
    punches holes where triangles overlap, and OpenCV's fill adds about a pixel on every edge.)
    Triangles reaching behind the camera's near plane are skipped: cameras are meant to be
    outside the object.

    Args:
        mesh: triangle mesh; K: [3, 3]; c2w: [4, 4] OpenCV pose; width, height: image size.
    Returns:
        mask: [H, W] bool.
    """
    tris = _project_triangles(mesh, K, c2w)
    xs, ys = tris[..., 0], tris[..., 1]  # [F, 3] each
    # Pixel i's centre is i + 0.5: the first and last pixel whose centre is inside the box.
    x_lo = np.ceil(np.minimum(np.minimum(xs[:, 0], xs[:, 1]), xs[:, 2]) - 0.5).astype(np.int64)
    x_hi = np.floor(np.maximum(np.maximum(xs[:, 0], xs[:, 1]), xs[:, 2]) - 0.5).astype(np.int64)
    y_lo = np.ceil(np.minimum(np.minimum(ys[:, 0], ys[:, 1]), ys[:, 2]) - 0.5).astype(np.int64)
    y_hi = np.floor(np.maximum(np.maximum(ys[:, 0], ys[:, 1]), ys[:, 2]) - 0.5).astype(np.int64)
    np.maximum(x_lo, 0, out=x_lo)
    np.maximum(y_lo, 0, out=y_lo)
    np.minimum(x_hi, width - 1, out=x_hi)
    np.minimum(y_hi, height - 1, out=y_hi)
    keep = np.flatnonzero((x_hi >= x_lo) & (y_hi >= y_lo))
    extent = np.maximum(x_hi[keep] - x_lo[keep], y_hi[keep] - y_lo[keep]) + 1
    lo = np.stack([x_lo[keep], y_lo[keep]], axis=1)
    tris = tris[keep]
    mask = np.zeros((height, width), dtype=bool)
    box = 1
    while len(extent) and box // 2 < extent.max():
        chosen = np.flatnonzero((extent <= box) & (extent > box // 2))
        step = max(1, _MAX_TESTS_PER_CHUNK // (box * box))
        for start in range(0, len(chosen), step):
            part = chosen[start:start + step]
            _fill_triangles(mask, tris[part], lo[part], box)
        box *= 2
    return mask


def _project_triangles(mesh: trimesh.Trimesh, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Pixel coordinates of the triangles wholly in front of the camera. Returns [F', 3, 2]."""
    w2c = np.linalg.inv(np.asarray(c2w, dtype=np.float64))
    cam = np.asarray(mesh.vertices, dtype=np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
    faces = np.asarray(mesh.faces)
    in_front = cam[:, 2] > 1e-6
    faces = faces[in_front[faces[:, 0]] & in_front[faces[:, 1]] & in_front[faces[:, 2]]]
    proj = cam @ np.asarray(K, dtype=np.float64).T
    uv = proj[:, :2] / np.where(in_front, proj[:, 2], 1.0)[:, None]
    return uv[faces]


def _fill_triangles(mask: np.ndarray, tris: np.ndarray, lo: np.ndarray, box: int) -> None:
    """Mark pixel centres inside triangles whose pixel boxes fit in ``box`` x ``box``.

    Args:
        mask: [H, W] bool, updated in place; tris: [N, 3, 2] pixel coordinates;
        lo: [N, 2] first pixel (x, y) of each triangle's box.
    """
    offsets = np.stack(np.meshgrid(np.arange(box), np.arange(box)), -1).reshape(-1, 2)
    pix = lo[:, None, :] + offsets[None]  # [N, B*B, 2]
    centres = pix + 0.5
    a, b, c = tris[:, 0:1], tris[:, 1:2], tris[:, 2:3]  # [N, 1, 2]

    def edge(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        d = q - p
        return d[..., 0] * (centres[..., 1] - p[..., 1]) - d[..., 1] * (centres[..., 0] - p[..., 0])

    e0, e1, e2 = edge(a, b), edge(b, c), edge(c, a)
    inside = (((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0)))
    height, width = mask.shape
    inside &= (pix[..., 0] < width) & (pix[..., 1] < height)
    mask[pix[..., 1][inside], pix[..., 0][inside]] = True
