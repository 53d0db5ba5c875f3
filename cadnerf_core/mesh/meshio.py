"""Loading meshes from files into one triangle mesh, and normalising them.

Every supported format comes back as a single ``trimesh.Trimesh`` with triangles only (trimesh
triangulates quads and polygons on load). Multi-part files (GLB scenes, OBJ files with several
materials) are merged into one mesh with the scene graph's transforms applied; textures are kept
as one packed texture where trimesh can pack them, otherwise turned into per-vertex colours, so
the renderer can always colour the result.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from PIL import Image

from cadnerf_core.errors import MeshError

log = logging.getLogger(__name__)

SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tga", ".webp")
MAX_TEXTURE_SIDE = 2048  # renders are a few hundred pixels wide
MERGE_TEXTURE_SIDE = 1024  # each part's texture before parts are packed into one atlas
_PLACEHOLDER_SIDE = 4  # trimesh invents a tiny uniform image when an OBJ has UVs but no MTL

# z-up to y-up: +Z becomes +Y and -Y (the usual z-up front) becomes +Z.
Z_UP_TO_Y_UP = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load a mesh file as one triangle mesh, keeping its texture or colours.

    Args:
        path: an OBJ (with its MTL and textures), PLY, STL, OFF, GLB or glTF file.
    Returns:
        The mesh, triangles only, parts merged, transforms applied.
    Raises:
        MeshError: naming the file, when it is missing, empty, of an unsupported type, not a
            mesh, or has no triangles.
    """
    path = Path(path)
    item = str(path)
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise MeshError(f"unsupported file type '{path.suffix or '(none)'}'", item=item,
                        hint="use one of " + ", ".join(SUPPORTED_EXTENSIONS))
    if not path.is_file():
        raise MeshError("file not found", item=item)
    if path.stat().st_size == 0:
        raise MeshError("file is empty", item=item)
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise MeshError(f"not a readable mesh ({type(exc).__name__}: {exc})", item=item) from exc
    mesh = _to_single_mesh(loaded, item)
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise MeshError("the mesh has no triangles", item=item)
    if not np.isfinite(mesh.vertices).all():
        raise MeshError("the mesh has non-finite vertex coordinates", item=item)
    _attach_sidecar_texture(mesh, path)
    _limit_texture_size(mesh)
    log.debug("loaded %s: %d vertices, %d triangles, visual %s", path, len(mesh.vertices),
              len(mesh.faces), type(mesh.visual).__name__)
    return mesh


def _to_single_mesh(loaded: Any, item: str) -> trimesh.Trimesh:
    """One Trimesh from whatever ``trimesh.load`` returned (a mesh, a scene, a point cloud)."""
    if isinstance(loaded, trimesh.Trimesh):
        return loaded
    if not isinstance(loaded, trimesh.Scene):
        raise MeshError(f"not a mesh (the file holds a {type(loaded).__name__})", item=item)
    parts = [g for g in loaded.dump(concatenate=False)
             if isinstance(g, trimesh.Trimesh) and len(g.faces) > 0]
    if not parts:
        raise MeshError("the mesh has no triangles", item=item)
    if len(parts) == 1:
        return parts[0]
    return merge_meshes(parts)


def merge_meshes(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate meshes, keeping textures (packed) or falling back to per-vertex colours.

    Args:
        parts: meshes already in a common frame.
    Returns:
        One mesh with all the triangles.
    """
    textured = [p for p in parts if texture_image(p) is not None]
    if len(textured) > 1:
        # Packing copies every texture into one atlas: shrink them first, or a few 2k
        # textures make an 8k atlas (seconds to build, hundreds of MB).
        parts = [p.copy() for p in parts]
        for part in parts:
            _limit_texture_size(part, MERGE_TEXTURE_SIDE)
    try:
        merged = trimesh.util.concatenate(parts)
    except Exception as exc:  # texture packing can fail on odd materials
        log.debug("texture-preserving merge failed (%s); using vertex colours", exc)
        merged = None
    if isinstance(merged, trimesh.Trimesh) and (not textured or texture_image(merged)):
        return merged
    coloured = []
    for part in parts:
        copy = part.copy()
        copy.visual = _as_colour_visuals(part)
        coloured.append(copy)
    result = trimesh.util.concatenate(coloured)
    assert isinstance(result, trimesh.Trimesh)
    return result


def _as_colour_visuals(mesh: trimesh.Trimesh) -> trimesh.visual.ColorVisuals:
    """Per-vertex colours of a mesh (texture sampled at each vertex's UV)."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        try:
            converted = visual.to_color()
            return trimesh.visual.ColorVisuals(mesh, vertex_colors=converted.vertex_colors)
        except Exception as exc:  # no UVs or an unreadable image: use the material colour
            log.debug("texture to colour conversion failed: %s", exc)
            colour = np.asarray(visual.material.main_color, dtype=np.uint8)
            faces = np.tile(colour, (len(mesh.faces), 1))
            return trimesh.visual.ColorVisuals(mesh, face_colors=faces)
    if isinstance(visual, trimesh.visual.ColorVisuals):
        return trimesh.visual.ColorVisuals(mesh, vertex_colors=visual.vertex_colors)
    return trimesh.visual.ColorVisuals(mesh)


def texture_image(mesh: trimesh.Trimesh) -> Image.Image | None:
    """The colour texture of a UV-mapped mesh, or None (no texture, or trimesh's placeholder)."""
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.TextureVisuals) or visual.uv is None:
        return None
    material = visual.material
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if not isinstance(image, Image.Image) or max(image.size) <= _PLACEHOLDER_SIDE:
        return None
    return image


def _set_texture_image(mesh: trimesh.Trimesh, image: Image.Image) -> None:
    """Replace the colour texture of a textured mesh."""
    assert isinstance(mesh.visual, trimesh.visual.TextureVisuals)
    material = mesh.visual.material
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        material.baseColorTexture = image
    else:
        material.image = image


def _attach_sidecar_texture(mesh: trimesh.Trimesh, path: Path) -> None:
    """Give a UV-mapped mesh with no material its texture when one lies next to the file.

    Some OBJ files ship their texture without an MTL file (Keenan Crane's ``spot``: UVs and
    ``spot_texture.png``). Candidates, in order: an image whose name starts with the mesh
    name's first word, ``texture*``, then the folder's only image.
    """
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.TextureVisuals) or visual.uv is None:
        return
    if texture_image(mesh) is not None:
        return
    images = sorted(p for p in path.parent.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
    first_word = path.stem.replace("-", "_").split("_")[0].lower()
    ranked = ([p for p in images if p.stem.lower().startswith(first_word)]
              + [p for p in images if p.stem.lower().startswith("texture")]
              + (images if len(images) == 1 else []))
    if not ranked:
        return
    try:
        image = Image.open(ranked[0])
        image.load()
    except OSError as exc:
        log.warning("texture %s next to %s is unreadable: %s", ranked[0], path, exc)
        return
    mesh.visual = trimesh.visual.TextureVisuals(
        uv=visual.uv, image=image, material=trimesh.visual.material.SimpleMaterial(image=image))
    log.info("%s: using texture %s found next to it", path.name, ranked[0].name)


def _limit_texture_size(mesh: trimesh.Trimesh, max_side: int = MAX_TEXTURE_SIDE) -> None:
    """Shrink a texture larger than ``max_side`` (UVs are relative, so they stay valid)."""
    image = texture_image(mesh)
    if image is None or max(image.size) <= max_side:
        return
    factor = max_side / max(image.size)
    new_size = (max(1, round(image.size[0] * factor)), max(1, round(image.size[1] * factor)))
    _set_texture_image(mesh, image.resize(new_size, Image.Resampling.BILINEAR))


def normalise_mesh(mesh: trimesh.Trimesh, up: Literal["y", "z"] = "y") -> trimesh.Trimesh:
    """A copy centred at the origin (bounding-box centre), scaled to max |v| = 1, +Y up.

    Args:
        mesh: any mesh with at least one vertex away from its bounding-box centre.
        up: the file's up axis; ``"z"`` rotates +Z to +Y (and -Y, the usual front, to +Z).
    Returns:
        The normalised copy; visuals (texture, colours) are kept.
    """
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', not {up!r}")
    out = mesh.copy()
    if up == "z":
        out.apply_transform(Z_UP_TO_Y_UP)
    lo, hi = out.vertices.min(axis=0), out.vertices.max(axis=0)
    out.apply_translation(-(lo + hi) / 2.0)
    radius = float(np.linalg.norm(out.vertices, axis=1).max())
    if radius <= 0.0:
        raise MeshError("the mesh is a single point and cannot be normalised")
    out.apply_scale(1.0 / radius)
    return out
