"""The demo's photos, made like a user's: a textured chair standing on a tiled floor, photographed
walking round it once, as JPEGs at a phone-like size whose EXIF carries the lens, each with the
chair's mask.

The chair's wood and the floor's tiles give the photos points to share, as print, grain and a
table top do in a real room; the object and the floor are ray cast apart and composited by
depth, so each mask is exactly the chair.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

WIDTH, HEIGHT = 1024, 768
"""Photo size in pixels, as a phone's photo shrunk for upload: the chair stands 420 to 510
pixels tall, and every photo of the demo's walk shares points with a neighbour
(``tests/core/test_demo_photos.py``); at 640 x 480 some share none, and their cameras then rest
on their outlines alone."""
FOCAL_35MM = 30
"""The lens, 35 mm equivalent (a phone's main lens is about 26), written to each photo's EXIF."""
ELEVATIONS = (15.0, 35.0)
"""Range of the camera's elevation in degrees, as a person holds a phone."""
FLOOR_SIDE = 8.0
_EXIF_IFD, _FOCAL_35MM_TAG = 0x8769, 0xA405  # Exif sub-IFD, FocalLengthIn35mmFilm
_FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


def demo_mesh(path: Path) -> Path:
    """Write a chair-like mesh (seat, back, four legs) made with trimesh.creation."""
    chair_shape().export(path)
    return path


def chair_shape() -> trimesh.Trimesh:
    """Seat, back and four legs, in one mesh (untextured)."""
    move = trimesh.transformations.translation_matrix
    parts = [trimesh.creation.box((1.0, 0.12, 1.0), move((0, 0.0, 0))),
             trimesh.creation.box((1.0, 1.0, 0.12), move((0, 0.56, -0.44)))]
    parts += [trimesh.creation.box((0.12, 0.9, 0.12), move((x, -0.5, z)))
              for x in (-0.42, 0.42) for z in (-0.42, 0.42)]
    chair = trimesh.util.concatenate(parts)
    assert isinstance(chair, trimesh.Trimesh)  # boxes concatenate to one mesh
    return chair


def grain_texture(rng: np.random.Generator, tint: tuple[float, float, float],
                  side: int = 512) -> Image.Image:
    """A square RGB texture of blotches at three scales and fine grain, tinted ``tint``."""
    value = np.zeros((side, side))
    for cells, weight in ((8, 0.5), (32, 0.3), (128, 0.2)):
        coarse = rng.uniform(0.0, 1.0, (cells, cells))
        value += weight * np.kron(coarse, np.ones((side // cells, side // cells)))
    value = 0.55 + 0.45 * value * rng.uniform(0.8, 1.0, (side, side))
    rgb = np.clip(value[..., None] * np.array(tint), 0.0, 1.0)
    return Image.fromarray((rgb * 255).astype(np.uint8))


def textured(mesh: trimesh.Trimesh, image: Image.Image, repeat: float) -> trimesh.Trimesh:
    """``mesh`` with ``image`` projected on each face along its normal's main axis (``repeat``:
    texture copies per unit length), every face given its own vertices."""
    corners = mesh.vertices[mesh.faces]  # [F, 3, 3]
    axis = np.abs(mesh.face_normals).argmax(axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # the two axes across each face
    uv = np.take_along_axis(corners, keep[:, None, :], axis=2) * repeat
    out = trimesh.Trimesh(corners.reshape(-1, 3), np.arange(corners.shape[0] * 3).reshape(-1, 3),
                          process=False)
    out.visual = trimesh.visual.TextureVisuals(uv=uv.reshape(-1, 2), image=image)  # repeats
    return out


def demo_focal_px(width: int = WIDTH, height: int = HEIGHT) -> float:
    """The lens's focal length in pixels of a ``width`` x ``height`` photo."""
    return FOCAL_35MM * math.hypot(width, height) / _FULL_FRAME_DIAGONAL_MM


def _save_jpeg(rgb: np.ndarray, path: Path) -> None:
    """Save [H, W, 3] floats in [0, 1] as a JPEG whose EXIF gives the lens."""
    exif = Image.Exif()
    exif.get_ifd(_EXIF_IFD)[_FOCAL_35MM_TAG] = FOCAL_35MM
    image = Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    image.save(path, format="JPEG", quality=92, exif=exif)


def render_demo_photos(out: Path, views: int = 6, width: int = WIDTH, height: int = HEIGHT,
                       seed: int = 0) -> tuple[list[Path], list[Path]]:
    """Render the walk into ``out`` (``images/NNN.jpg``, ``masks/NNN.png``).

    Returns:
        The photos' and masks' paths, in walking order.
    """
    from cadnerf_core.cameras import orbit_pose
    from cadnerf_core.evaluation.dataset import auto_distance, walking_angles
    from cadnerf_core.mesh.meshio import normalise_mesh
    from cadnerf_core.mesh.renderer import MeshRenderer

    rng = np.random.default_rng(seed)
    chair = normalise_mesh(textured(chair_shape(), grain_texture(rng, (0.8, 0.55, 0.3)), 1.0))
    side = FLOOR_SIDE / 2.0
    floor = trimesh.creation.box((FLOOR_SIDE, 0.01, FLOOR_SIDE),
                                 trimesh.transformations.translation_matrix(
                                     (0.0, float(chair.bounds[0][1]) - 0.005, 0.0)))
    floor = textured(floor, grain_texture(rng, (0.75, 0.78, 0.85)), 2.0 / side)
    focal = demo_focal_px(width, height)
    fov = math.degrees(2.0 * math.atan(0.5 * min(width, height) / focal))  # across the short side
    K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
    azimuths, elevations = walking_angles(views, rng, 1, ELEVATIONS)
    angles = list(zip(azimuths.tolist(), elevations.tolist(), strict=True))
    distance = auto_distance(chair, angles, fov) * 1.1
    things, ground = MeshRenderer(chair), MeshRenderer(floor)
    for folder in ("images", "masks"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    photos, masks = [], []
    for k, (azimuth, elevation) in enumerate(angles):
        c2w = orbit_pose(azimuth, elevation, distance)
        shot, below = things.render(K, c2w, width, height), ground.render(K, c2w, width, height)
        front = shot.mask & (~below.mask | (shot.depth <= below.depth))
        rgb = np.where(front[..., None], shot.rgb, np.where(below.mask[..., None], below.rgb,
                                                            0.92))
        photos.append(out / "images" / f"{k:03d}.jpg")
        masks.append(out / "masks" / f"{k:03d}.png")
        _save_jpeg(rgb, photos[-1])
        Image.fromarray(front.astype(np.uint8) * 255).save(masks[-1])
    return photos, masks
