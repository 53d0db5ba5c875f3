"""The job folder's names and name rules: every file and folder name, the downloadable
artifacts and their media types, and how photo, mask and view names are made and read.

Part of the job folder's owner (``jobfolder``, which re-exports all of it); nothing else spells
these names. Standard library only, so anything may import it.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath
from typing import Literal

INPUTS = "inputs"
MASK_UPLOADS = f"{INPUTS}/masks"
MASKS = "masks"
VIEWS = "views"
MATCHES = "matches"
MATCH_CACHE = f"{MATCHES}/pairs.npz"
CHECKPOINTS = "checkpoints"
EVAL = "eval"
CONFIG = "config.json"
RETRIEVAL = "retrieval.json"
WARNINGS = "warnings.json"
MASK_SOURCES = "masks.json"
POSES = "poses.json"
TRANSFORMS = "transforms.json"
METRICS = "metrics.json"
RESULT = "result.json"
ORBIT_VIDEO = "orbit.mp4"
ORBIT_GIF = "orbit.gif"
MESH = "mesh.glb"
MESH_OBJ = "mesh.obj"
MESH_MTL = "mesh.mtl"
MESH_TEXTURE = "mesh_texture.png"
MESH_USDZ = "mesh.usdz"
IMAGES = "images"
SPARSE = "sparse/0"
COLMAP_CAMERAS = f"{SPARSE}/cameras.txt"
COLMAP_IMAGES = f"{SPARSE}/images.txt"
COLMAP_POINTS = f"{SPARSE}/points3D.txt"
BUNDLE = "results.zip"
LOG = "log.txt"

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".heic", ".heif", ".hif", ".avif")
"""Suffixes of the photos in ``inputs/`` (anything else there is ignored)."""

MEDIA_TYPES: dict[str, str] = {
    ORBIT_VIDEO: "video/mp4", ORBIT_GIF: "image/gif", MESH: "model/gltf-binary",
    MESH_OBJ: "model/obj", MESH_MTL: "model/mtl", MESH_TEXTURE: "image/png",
    MESH_USDZ: "model/vnd.usdz+zip",
    BUNDLE: "application/zip",
    RESULT: "application/json", POSES: "application/json", TRANSFORMS: "application/json",
    METRICS: "application/json",
    RETRIEVAL: "application/json", WARNINGS: "application/json", CONFIG: "application/json",
    MASK_SOURCES: "application/json",
    COLMAP_CAMERAS: "text/plain", COLMAP_IMAGES: "text/plain", COLMAP_POINTS: "text/plain",
    LOG: "text/plain",
}
"""The single files a user may download, in listing order, and their Content-Type."""

OVERLAY_SUFFIX = "_overlay.jpg"
OVERLAY_SIDE = 1024
"""Longest side of a stored overlay in pixels: a picture to look at on a page (the mask
itself keeps the photo's size)."""

_NUMBERED = re.compile(rf"^(?:{VIEWS}/\d{{3}}\.png|{MASKS}/\d{{3}}(?:\.png|{OVERLAY_SUFFIX})"
                       rf"|{MATCHES}/\d{{3}}_\d{{3}}\.jpg"
                       rf"|{IMAGES}/\d{{3}}_[A-Za-z0-9_-]+\.(?:jpg|jpeg|png))$")
BUNDLE_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
"""Photo types copied into ``images/`` as uploaded (every tool reads them); others become PNG."""
_PHOTO_INDEX = re.compile(r"^(\d{3})_")

MaskSource = Literal["uploaded", "alpha", "learned", "grabcut"]
"""Where a photo's mask came from: an uploaded mask, the photo's alpha, background removal."""


def match_picture_name(i: int, j: int) -> str:
    """The name of the picture of photos ``i`` and ``j``'s matches (0-based indices)."""
    return f"{MATCHES}/{i:03d}_{j:03d}.jpg"


def safe_stem(filename: str) -> str:
    """A file-name stem of ``[A-Za-z0-9_-]`` only, at most 40 characters ("photo" if empty)."""
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    stem = base.rsplit(".", 1)[0] if "." in base.lstrip(".") else base
    clean = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_-")[:40]
    return clean or "photo"


def photo_file_name(index: int, filename: str, ext: str) -> str:
    """The stored name of photo ``index``: ``NNN_<safe stem>.<ext>`` (the client's name never
    becomes a path; NNN keeps the upload order when sorted)."""
    return f"{index:03d}_{safe_stem(filename)}.{ext.lower().lstrip('.')}"


def photo_index(stored_name: str) -> int | None:
    """The photo index of a stored name (``"002_b.jpg"`` -> 2), None for other names."""
    match = _PHOTO_INDEX.match(PurePosixPath(stored_name.replace("\\", "/")).name)
    return int(match.group(1)) if match else None


def numbered_name(folder: str, index: int) -> str:
    """``<folder>/NNN.png``: view (``VIEWS``) or used mask (``MASKS``) number ``index``."""
    return f"{folder}/{index:03d}.png"


def overlay_name(index: int) -> str:
    """``masks/NNN_overlay.jpg``: the overlay of photo ``index``'s mask."""
    return f"{MASKS}/{index:03d}{OVERLAY_SUFFIX}"


def bundle_image_name(photo: Path | str, as_uploaded: bool) -> str:
    """``images/<stored name>`` for a photo kept as uploaded, else ``images/<stored stem>.png``."""
    name = PurePosixPath(Path(photo).name)
    return f"{IMAGES}/{name if as_uploaded else name.with_suffix('.png')}"


def is_artifact_name(name: str) -> bool:
    """Whether ``name`` is one a user may download (a fixed file, a view, a used mask or its
    overlay)."""
    return name in MEDIA_TYPES or _NUMBERED.match(name) is not None


def media_type(name: str) -> str:
    """The Content-Type of an artifact name."""
    if name in MEDIA_TYPES:
        return MEDIA_TYPES[name]
    if _NUMBERED.match(name):
        return "image/jpeg" if name.endswith((".jpg", ".jpeg")) else "image/png"
    return "application/octet-stream"
