"""Files other tools open: photos under ``images/``, ``transforms.json``, a COLMAP model, the
conventions of ``poses.json``, and ``results.zip`` holding them all.

``transforms.json`` follows nerfstudio's ``nerfstudio-data`` layout (``camera_model: OPENCV``,
per-frame ``fl_x fl_y cx cy w h k1 k2 p1 p2``, ``file_path`` and ``mask_path`` relative to the
file, OpenGL camera axes) and keeps the NeRF-synthetic ``camera_angle_x`` for tools that read
only that. Every path in it resolves both in the job folder and inside ``results.zip``.
"""

from __future__ import annotations

import os
import shutil
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cadnerf_core.cameras.conventions import CV_TO_GL, fov_from_intrinsics
from cadnerf_core.export.colmap import ColmapCamera, colmap_text
from cadnerf_core.export.texture import TexturedMesh
from cadnerf_core.jobfolder import (
    BUNDLE,
    BUNDLE_IMAGE_SUFFIXES,
    COLMAP_CAMERAS,
    COLMAP_IMAGES,
    COLMAP_POINTS,
    IMAGES,
    MASKS,
    InputPhoto,
    JobFolder,
    atomic_path,
    bundle_image_name,
    ensure_folder,
    numbered_name,
)

CONVENTIONS: dict[str, str] = {
    "c2w": "4x4 camera-to-world matrix; camera axes as OpenCV: x right, y down, z forward "
           "(the camera looks along +z)",
    "world": "right-handed, +Y up, the object centred at the origin inside the unit sphere, its "
             "front toward +Z (the retrieved CAD model's frame)",
    "units": "normalised: 1 = the radius of the object's bounding sphere, not metres (the "
             "photos carry no scale)",
    "K": "3x3 pinhole intrinsics in pixels, pixel centres at +0.5 (COLMAP's convention), no "
         "distortion",
    "K_photo": "intrinsics in the pixels of the photo after its EXIF orientation, "
               "width x height as in width and height",
    "K_canonical": "intrinsics in the square canonical crop the NeRF was trained on",
    "transforms.json": "the same cameras with OpenGL camera axes: c2w @ diag(1, -1, -1, 1)",
    "sparse/0": "COLMAP text model: world-to-camera poses, OpenCV axes, PINHOLE cameras in photo "
                "pixels; points sampled on mesh.glb",
}
"""What ``poses.json`` states about its own numbers."""


def upright_pixels(photo: InputPhoto) -> np.ndarray | None:
    """None when tools read the stored photo as the pipeline did (an upright JPEG or PNG), else
    its upright RGB pixels [H, W, 3] uint8 to store as PNG (other formats, rotated EXIF)."""
    from PIL import Image, ImageOps

    from cadnerf_core.intake.photos import stored_orientation

    with Image.open(photo.path) as image:
        if (photo.path.suffix.lower() in BUNDLE_IMAGE_SUFFIXES
                and stored_orientation(image)[0] == 1):
            return None
        return np.asarray(ImageOps.exif_transpose(image).convert("RGB"))


def add_image(folder: JobFolder, photo: InputPhoto, pixels: np.ndarray | None) -> str:
    """Store a photo under ``images/`` for other tools. Returns its name.

    Args:
        photo: the stored photo; pixels: None to keep the upload itself (a hard link where the
            file system allows, else a copy), or its upright pixels [H, W, 3] uint8 (PNG).
    """
    from PIL import Image

    name = bundle_image_name(photo.path, pixels is None)
    target = folder.file(name)
    ensure_folder(target.parent)
    target.unlink(missing_ok=True)
    if pixels is not None:
        with atomic_path(target) as tmp:
            Image.fromarray(np.asarray(pixels, np.uint8), "RGB").save(tmp, format="PNG")
        return name
    try:
        os.link(photo.path, target)
    except OSError:
        shutil.copyfile(photo.path, target)
    return name


def write_images(folder: JobFolder) -> dict[int, str]:
    """Every photo under ``images/`` (``add_image``). Returns index -> name."""
    return {p.index: add_image(folder, p, upright_pixels(p)) for p in folder.photos()}


def write_bundle(folder: JobFolder) -> list[str]:
    """Write ``results.zip`` of ``JobFolder.bundle_members`` (already-compressed media stored,
    text deflated), paths inside as in the job folder. Returns the members."""
    members = folder.bundle_members()
    stored = (".png", ".jpg", ".jpeg", ".mp4", ".gif", ".glb", ".usdz")
    with atomic_path(folder.file(BUNDLE)) as tmp, zipfile.ZipFile(tmp, "w") as bundle:
        for name in members:
            method = zipfile.ZIP_STORED if name.endswith(stored) else zipfile.ZIP_DEFLATED
            bundle.write(folder.file(name), name, compress_type=method)
    return members


def mask_for(folder: JobFolder, index: int, size: tuple[int, int]) -> str | None:
    """``masks/NNN.png`` when it matches its photo as uploaded pixel for pixel, else None (a
    photo over the working size has its mask at the working size, which tools reading masks
    beside images would reject)."""
    from PIL import Image

    name = numbered_name(MASKS, index)
    if not folder.file(name).is_file():
        return None
    with Image.open(folder.file(name)) as mask:
        return name if mask.size == size else None


def nerfstudio_transforms(c2w: np.ndarray, K_photo: Sequence[np.ndarray],
                          sizes: Sequence[tuple[int, int]], images: Sequence[str],
                          masks: Sequence[str | None]) -> dict[str, Any]:
    """``transforms.json`` (nerfstudio-data, NeRF-synthetic compatible) of the kept photos.

    Args:
        c2w: [N, 4, 4] refined OpenCV poses; K_photo: N [3, 3] in photo pixels;
        sizes: N (width, height); images, masks: N paths relative to the file (mask None: none).
    """
    frames = []
    for pose, K, (width, height), image, mask in zip(c2w, K_photo, sizes, images, masks,
                                                     strict=True):
        frame: dict[str, Any] = {
            "file_path": image, "transform_matrix": (np.asarray(pose) @ CV_TO_GL).tolist(),
            "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]),
            "cy": float(K[1, 2]), "w": int(width), "h": int(height),
            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
        if mask is not None:
            frame["mask_path"] = mask
        frames.append(frame)
    angle = fov_from_intrinsics(np.asarray(K_photo[0]), sizes[0][0]) if frames else 0.0
    return {"camera_model": "OPENCV", "camera_angle_x": angle, "frames": frames}


def novel_view_entries(names: Sequence[str], c2w: np.ndarray, K: np.ndarray,
                       size: int) -> list[dict[str, Any]]:
    """``poses.json``'s ``novel_views``: each new view's file, pose and intrinsics."""
    return [{"view": name, "c2w": np.asarray(pose).tolist(), "K": np.asarray(K).tolist(),
             "width": size, "height": size} for name, pose in zip(names, c2w, strict=True)]


def write_colmap(folder: JobFolder, cameras: Sequence[ColmapCamera], mesh: TexturedMesh) -> None:
    """``sparse/0/{cameras,images,points3D}.txt``."""
    texts = colmap_text(cameras, mesh)
    for name, text in zip((COLMAP_CAMERAS, COLMAP_IMAGES, COLMAP_POINTS), texts, strict=True):
        folder.write_text(name, text)


def export_for_tools(job_dir: Path, poses: list[dict[str, Any]], c2w: np.ndarray,
                     mesh: TexturedMesh) -> None:
    """images/, transforms.json and sparse/0/ for the kept photos.

    Args:
        poses: ``poses.json``'s photo entries (with ``K_photo``, ``width``, ``height``).
        c2w: [N, 4, 4] refined poses of the kept photos, in photo order.
    """
    folder = JobFolder(job_dir)
    images = write_images(folder)
    kept = [p for p in poses if not p["discarded"]]
    K_photo = [np.asarray(p["K_photo"]) for p in kept]
    sizes = [(int(p["width"]), int(p["height"])) for p in kept]
    image_names = [images[p["index"]] for p in kept]
    mask_names = [mask_for(folder, p["index"], size) for p, size in zip(kept, sizes, strict=True)]
    folder.write_transforms(nerfstudio_transforms(c2w, K_photo, sizes, image_names, mask_names))
    cameras = [ColmapCamera(name=name.removeprefix(f"{IMAGES}/"), c2w=np.asarray(pose), K=K,
                            width=w, height=h)
               for name, pose, K, (w, h) in zip(image_names, c2w, K_photo, sizes, strict=True)]
    write_colmap(folder, cameras, mesh)
