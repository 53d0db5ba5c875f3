"""Synthetic datasets with ground-truth cameras, and reading NeRF-synthetic folders.

``render_dataset`` renders a mesh as a person would photograph it walking around it once:
views in order, azimuths going one way round, elevations varying. The folder it writes
(``images/NNN.png`` RGBA, ``masks/NNN.png``, ``transforms.json``, optional ``test/`` split with
``transforms_test.json``, and ``dataset.json`` with the seed and angles) is a NeRF-synthetic
dataset, so ``load_dataset`` reads it as well as the Blender scenes of the original NeRF, and a
real capture's folder (``capture``: photos, masks and ``cameras.json``).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh
from PIL import Image

from cadnerf_core.cameras.conventions import (
    from_transforms_json,
    intrinsics_from_fov,
    orbit_pose,
    to_transforms_json,
)
from cadnerf_core.errors import InputError
from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
from cadnerf_core.mesh.renderer import MeshRenderer, render_silhouette_polygons

log = logging.getLogger(__name__)

TARGET_FILL = 0.72  # auto distance: the object's largest extent over the views, share of frame
AZIMUTH_JITTER = 0.2  # share of the azimuth step training views are moved at random
MIN_DISTANCE = 1.2  # the camera stays outside the unit sphere holding the object


@dataclass
class Dataset:
    """Images with their cameras: one split, and the held-out split when there is one."""

    images: np.ndarray  # [N, H, W, 3] float32 in [0, 1], composited on white
    masks: np.ndarray  # [N, H, W] bool
    c2w: np.ndarray  # [N, 4, 4] OpenCV camera-to-world
    K: np.ndarray  # [N, 3, 3]
    names: list[str]  # frame names (file stems), in order
    root: Path  # the dataset folder
    test: Dataset | None = None  # held-out split (transforms_test.json), when present
    masked: bool = True  # the masks came with the frames (False: whole-frame placeholders)


def walking_angles(n_views: int, rng: np.random.Generator, direction: int,
                   elevation_range: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Azimuths and elevations of a walk once around the object.

    Args:
        n_views: number of views.
        rng: random generator (start azimuth, jitter, elevations).
        direction: +1 (azimuth increasing) or -1.
        elevation_range: (min, max) elevation in degrees.
    Returns:
        azimuths [n] in [0, 360) and elevations [n], degrees.
    """
    step = 360.0 / n_views
    offsets = np.arange(n_views) * step + rng.uniform(-AZIMUTH_JITTER, AZIMUTH_JITTER,
                                                      n_views) * step
    azimuths = np.mod(rng.uniform(0.0, 360.0) + direction * offsets, 360.0)
    elevations = rng.uniform(elevation_range[0], elevation_range[1], n_views)
    return azimuths, elevations


def auto_distance(mesh: trimesh.Trimesh, angles: list[tuple[float, float]], fov_deg: float,
                  size: int = 128) -> float:
    """Camera distance at which the object's largest extent over the views fills TARGET_FILL.

    Starts from the distance at which the unit bounding sphere fills the frame to TARGET_FILL,
    measures the silhouettes there, and moves the camera by the ratio (apparent size goes as
    one over distance).

    Args:
        mesh: normalised mesh (inside the unit sphere); angles: (azimuth, elevation) degrees.
        fov_deg: horizontal field of view; size: silhouette size used to measure.
    Returns:
        distance from the origin.
    """
    half = math.radians(fov_deg) / 2.0
    start = 1.0 / math.sin(math.atan(TARGET_FILL * math.tan(half)))
    K = intrinsics_from_fov(fov_deg, size)
    extent = 0.0
    for azimuth, elevation in angles:
        mask = render_silhouette_polygons(mesh, K, orbit_pose(azimuth, elevation, start),
                                          size, size)
        if mask.any():
            ys, xs = np.nonzero(mask)
            extent = max(extent, (xs.max() - xs.min() + 1) / size, (ys.max() - ys.min() + 1) / size)
    if extent == 0.0:
        return start
    return max(MIN_DISTANCE, start * extent / TARGET_FILL)


def render_dataset(mesh_path: str | Path, out_dir: str | Path, n_views: int, size: int,
                   seed: int, up: Literal["y", "z"] = "y", test_views: int = 0,
                   elevation_range: tuple[float, float] = (0.0, 60.0),
                   direction: int | None = None, fov_deg: float = 40.0,
                   distance: float | None = None) -> Path:
    """Render a mesh into a NeRF-synthetic dataset with ground-truth cameras.

    Args:
        mesh_path: any file ``load_mesh`` reads; it is normalised (unit sphere, +Y up).
        out_dir: folder to write (created; existing files of the same names are replaced).
        n_views: training views, in walking order; size: image side in pixels.
        seed: seed of every random choice (start azimuth, jitter, elevations, direction).
        up: the file's up axis. test_views: held-out views at random angles (0 = none).
        elevation_range: (min, max) elevation in degrees.
        direction: +1 (azimuth increasing) or -1; random when None.
        fov_deg: horizontal field of view. distance: camera distance; None = auto
            (the object's largest extent fills about 72% of the frame).
    Returns:
        out_dir as a Path.
    Raises:
        MeshError: the mesh cannot be loaded. ValueError: bad counts or ranges.
    """
    if n_views < 1 or size < 8 or test_views < 0:
        raise ValueError("need n_views >= 1, size >= 8 and test_views >= 0")
    if not 0.0 <= elevation_range[0] <= elevation_range[1] < 90.0:
        raise ValueError(f"elevation range {elevation_range} must be within [0, 90)")
    mesh = normalise_mesh(load_mesh(mesh_path), up=up)
    rng = np.random.default_rng(seed)
    if direction is None:
        direction = int(rng.choice([-1, 1]))
    if direction not in (-1, 1):
        raise ValueError(f"direction must be +1 or -1, not {direction}")
    azimuths, elevations = walking_angles(n_views, rng, direction, elevation_range)
    test_az = rng.uniform(0.0, 360.0, test_views)
    test_el = rng.uniform(elevation_range[0], elevation_range[1], test_views)
    if distance is None:
        distance = auto_distance(mesh, list(zip(azimuths, elevations, strict=True)), fov_deg)
    out = Path(out_dir)
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(fov_deg, size)
    _write_split(renderer, K, size, azimuths, elevations, distance, out, "", "transforms.json")
    if test_views:
        _write_split(renderer, K, size, test_az, test_el, distance, out, "test/",
                     "transforms_test.json")
    meta = {"seed": seed, "mesh": str(Path(mesh_path).resolve()), "up": up,
            "direction": direction, "distance": distance, "fov_deg": fov_deg, "size": size,
            "elevation_range": list(elevation_range), "azimuths": azimuths.tolist(),
            "elevations": elevations.tolist(), "test_azimuths": test_az.tolist(),
            "test_elevations": test_el.tolist()}
    (out / "dataset.json").write_text(json.dumps(meta, indent=2))
    log.info("wrote %d training and %d test views of %s to %s", n_views, test_views,
             mesh_path, out)
    return out


def _write_split(renderer: MeshRenderer, K: np.ndarray, size: int, azimuths: np.ndarray,
                 elevations: np.ndarray, distance: float, out: Path, prefix: str,
                 transforms_name: str) -> None:
    """Render and write one split: ``{prefix}images``, ``{prefix}masks`` and its json."""
    (out / prefix / "images").mkdir(parents=True, exist_ok=True)
    (out / prefix / "masks").mkdir(parents=True, exist_ok=True)
    poses, paths = [], []
    for i, (azimuth, elevation) in enumerate(zip(azimuths, elevations, strict=True)):
        c2w = orbit_pose(float(azimuth), float(elevation), distance)
        result = renderer.render(K, c2w, size, size, background=1.0)
        alpha = result.mask.astype(np.uint8) * 255
        rgb = np.round(result.rgb * 255.0).astype(np.uint8)
        name = f"{i:03d}.png"
        Image.fromarray(np.dstack([rgb, alpha])).save(out / prefix / "images" / name)  # RGBA
        Image.fromarray(alpha).save(out / prefix / "masks" / name)  # L
        poses.append(c2w)
        paths.append(f"{prefix}images/{i:03d}")
    data = to_transforms_json(np.stack(poses), K, size, size, paths)
    (out / transforms_name).write_text(json.dumps(data, indent=2))


def load_dataset(path: str | Path, hold_out: Sequence[int] = ()) -> Dataset:
    """Read a dataset folder: ours, any NeRF-synthetic (Blender) scene, or a real capture.

    The training split comes from ``transforms_train.json`` or ``transforms.json``; the test
    split from ``transforms_test.json`` when present. Frame paths may omit the extension
    (``.png`` is tried). Without these files, a capture's ``cameras.json`` (``capture``) is
    read. RGBA images are composited on white and their alpha is the mask; otherwise a
    ``masks/`` image beside ``images/`` is the mask and the photo is composited on white by it,
    else the whole frame is the object (``Dataset.masked`` False).

    Args:
        path: the dataset folder.
        hold_out: training frames (0-based, in the file's order) moved to the test split, for
            a folder without one (a capture's).
    Returns:
        Dataset with ``test`` set when there is a test split.
    Raises:
        InputError: no transforms or cameras file, a broken one, or a frame image is missing.
        ValueError: ``hold_out`` names a frame that is not there, or the folder has a test
            split already.
    """
    from cadnerf_core.evaluation.capture import hold_out_views, load_capture

    root = Path(path)
    train_json = next((root / name for name in ("transforms_train.json", "transforms.json")
                       if (root / name).is_file()), None)
    if train_json is None and (root / "cameras.json").is_file():
        dataset = load_capture(root)
    elif train_json is None:
        raise InputError("no transforms_train.json, transforms.json or cameras.json",
                         item=str(root))
    else:
        dataset = _load_split(root, train_json)
    if (root / "transforms_test.json").is_file():
        dataset.test = _load_split(root, root / "transforms_test.json")
    return hold_out_views(dataset, hold_out) if hold_out else dataset


def _load_split(root: Path, json_path: Path) -> Dataset:
    """One split of a NeRF-synthetic folder."""
    try:
        data = json.loads(json_path.read_text())
        frames = [str(frame["file_path"]) for frame in data["frames"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"not a transforms file ({exc})", item=str(json_path)) from None
    images, masks, names, found = [], [], [], []
    for file_path in frames:
        rgb, mask, masked = read_frame(root / file_path)
        images.append(rgb)
        masks.append(mask)
        found.append(masked)
        names.append(Path(file_path).stem)
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise InputError(f"frames have different sizes {sorted(shapes)}", item=str(json_path))
    height, width = images[0].shape[:2]
    c2w, K = from_transforms_json(data, width, height)
    return Dataset(images=np.stack(images), masks=np.stack(masks), c2w=c2w, K=K, names=names,
                   root=root, masked=all(found))


def read_frame(image_path: Path, mask_path: Path | None = None,
               ) -> tuple[np.ndarray, np.ndarray, bool]:
    """One frame: its image on white, its mask, and whether the mask came with it.

    The mask is the image's alpha, else ``mask_path``, else ``masks/<stem>.png`` beside an
    ``images/`` folder; the image is composited on white by it. Without one the whole frame
    is the object and the image is kept as it is.

    Args:
        image_path: the image (``.png`` is tried when the path has no such file).
        mask_path: its mask (white = object), when the dataset names one.
    Returns:
        image [H, W, 3] f32 in [0, 1], mask [H, W] bool, and whether a mask was found.
    Raises:
        InputError: the image or the named mask is missing, or has another size.
    """
    given = image_path
    if not image_path.is_file():
        image_path = image_path.with_name(image_path.name + ".png")
    if not image_path.is_file():
        raise InputError("frame image not found", item=str(given))
    with Image.open(image_path) as image:
        has_alpha = image.mode in ("RGBA", "LA") or "transparency" in image.info
        pixels = np.asarray(image.convert("RGBA"), dtype=np.float32) / 255.0
    rgb, alpha = pixels[..., :3], pixels[..., 3]
    if not has_alpha:
        beside = image_path.parent.parent / "masks" / (image_path.stem + ".png")
        if mask_path is None and image_path.parent.name == "images" and beside.is_file():
            mask_path = beside
        if mask_path is None:
            return rgb, np.ones(rgb.shape[:2], dtype=bool), False
        if not mask_path.is_file():
            raise InputError("frame mask not found", item=str(mask_path))
        with Image.open(mask_path) as mask_image:
            alpha = (np.asarray(mask_image.convert("L")) > 127).astype(np.float32)
        if alpha.shape != rgb.shape[:2]:
            raise InputError(f"mask is {alpha.shape[::-1]}, its image {rgb.shape[1::-1]}",
                             item=str(mask_path))
    return rgb * alpha[..., None] + (1.0 - alpha[..., None]), alpha > 0.5, True
