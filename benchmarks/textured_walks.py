"""Textured synthetic walks that look like phone photos: the evaluation set's textured meshes
standing on a textured floor, lit, rendered at 768 x 576 through a phone's main lens (65
degrees across, about 27 mm in 35 mm terms), 8 photos walking round once at 15-35 degrees of
elevation, each with its object's mask.

The floor is a square of random tiles and grain (a table top or a rug), so what stands still
round the object shares points between photos as it does in a real room. The object and the
floor are ray cast separately and composited by depth.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from benchmarks.harness import MESHES, mesh_file, mesh_up

TEXTURED = ("spot", "Duck", "CesiumMilkTruck", "fuze", "armchair")
"""The evaluation meshes that carry a colour texture."""
WIDTH, HEIGHT = 768, 576
FOV_DEG = 65.0
VIEWS = 8
ELEVATIONS = (15.0, 35.0)
FLOOR_SIDE = 8.0
SEED = 7


def phone_focal_35mm(fov_deg: float = FOV_DEG, width: int = WIDTH, height: int = HEIGHT) -> float:
    """The 35 mm-equivalent focal length of the render's camera (what a phone's EXIF says)."""
    focal_px = 0.5 * width / np.tan(np.radians(fov_deg) / 2.0)
    return float(focal_px * np.hypot(36.0, 24.0) / np.hypot(width, height))


def floor_mesh(height: float, rng: np.random.Generator) -> trimesh.Trimesh:
    """A ``FLOOR_SIDE`` square at ``height`` (world y), textured with random tiles and grain."""
    side = FLOOR_SIDE / 2.0
    vertices = np.array([[-side, height, -side], [side, height, -side], [side, height, side],
                         [-side, height, side]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    tiles = rng.uniform(0.35, 0.85, (16, 16, 3))
    texture = np.kron(tiles, np.ones((64, 64, 1)))
    texture *= rng.uniform(0.75, 1.0, texture.shape[:2])[..., None]  # grain in every tile
    image = Image.fromarray((np.clip(texture, 0, 1) * 255).astype(np.uint8))
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    return mesh


def render_walk(name: str, out: Path, direction: int = 1) -> tuple[list[Path], list[Path],
                                                                    np.ndarray]:
    """Render the walk of mesh ``name`` into ``out`` (``images/``, ``masks/``, ``cameras.json``).
    Returns the photo paths, mask paths and the cameras [VIEWS, 4, 4] (OpenCV c2w)."""
    from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
    from cadnerf_core.evaluation.dataset import auto_distance, walking_angles
    from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
    from cadnerf_core.mesh.renderer import MeshRenderer

    rng = np.random.default_rng(SEED)
    mesh = normalise_mesh(load_mesh(mesh_file(MESHES / name)), up=mesh_up(name))
    azimuths, elevations = walking_angles(VIEWS, rng, direction, ELEVATIONS)
    angles = list(zip(azimuths, elevations, strict=True))
    distance = auto_distance(mesh, angles, FOV_DEG) * 1.15  # a little room round it
    K = intrinsics_from_fov(FOV_DEG, WIDTH, HEIGHT)
    things, floor = MeshRenderer(mesh), MeshRenderer(floor_mesh(float(mesh.bounds[0][1]), rng))
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "masks").mkdir(parents=True, exist_ok=True)
    photos, masks, cameras = [], [], []
    for k, (azimuth, elevation) in enumerate(angles):
        c2w = orbit_pose(float(azimuth), float(elevation), distance)
        shot, ground = things.render(K, c2w, WIDTH, HEIGHT), floor.render(K, c2w, WIDTH, HEIGHT)
        front = shot.mask & (~ground.mask | (shot.depth <= ground.depth))
        backdrop = np.where(ground.mask[..., None], ground.rgb, 0.92)  # a pale wall behind
        rgb = np.where(front[..., None], shot.rgb, backdrop)
        photos.append(out / "images" / f"{k:03d}.jpg")
        masks.append(out / "masks" / f"{k:03d}.png")
        Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8)).save(photos[-1], quality=92)
        Image.fromarray(front.astype(np.uint8) * 255).save(masks[-1])
        cameras.append(c2w)
    (out / "cameras.json").write_text(json.dumps({
        "mesh": name, "fov_deg": FOV_DEG, "width": WIDTH, "height": HEIGHT,
        "direction": direction, "azimuths": azimuths.tolist(), "elevations": elevations.tolist(),
        "c2w": [c.tolist() for c in cameras], "K": K.tolist()}))
    return photos, masks, np.stack(cameras)


def mirrored(refined: np.ndarray, truth: np.ndarray) -> bool:
    """Whether the refined cameras walk round the object the other way from the truth: for
    most consecutive photos, the next camera stands on the other side (its own right or left)
    of the current one. Needs no alignment, so a walk that only a flip would align counts."""
    def sides(c2w: np.ndarray) -> np.ndarray:
        step = c2w[1:, :3, 3] - c2w[:-1, :3, 3]
        return np.sign(np.einsum("ni,ni->n", step, c2w[:-1, :3, 0]))

    return bool(np.mean(sides(refined) != sides(truth)) > 0.5)
