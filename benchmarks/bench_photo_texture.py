"""Photo texturing benchmark: the mesh's texture from the photos at a job's real sizes.

A bumpy sphere of about 20 000 triangles (an icosphere with waves on it, so the photos hide
parts of it from each other) is photographed by ``N_PHOTOS`` cameras all round at
``PHOTO_WIDTH`` x ``PHOTO_HEIGHT`` (ray cast, a checker on it); the benchmark then times the
UV unwrap with the field's bake (a constant colour, so the field costs nothing) and the same
bake with the photos (``photo_texture.photo_colours``) at ``--size`` (2048 by default), and
reports the share of texels the photos see.

Usage: ``python -m benchmarks.bench_photo_texture [--size N] [--threads N]``.
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np
import trimesh

from cadnerf_core.export.photo_texture import PhotoView, photo_colours
from cadnerf_core.export.texture import bake_texture
from cadnerf_core.mesh.renderer import MeshRenderer, pixel_rays

N_PHOTOS = 8
PHOTO_WIDTH, PHOTO_HEIGHT = 1500, 1000


def bumpy_sphere() -> trimesh.Trimesh:
    """An icosphere (20 480 triangles) with waves of a tenth of its radius."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.8)
    v = np.asarray(sphere.vertices)
    bumps = 1.0 + 0.1 * np.sin(6 * v[:, 0]) * np.sin(6 * v[:, 1]) * np.sin(6 * v[:, 2] + 1)
    return trimesh.Trimesh(v * bumps[:, None], sphere.faces, process=False)


def look_at(eye: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world [4, 4] at ``eye`` looking at the origin, +Y up."""
    z = -eye / np.linalg.norm(eye)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = eye
    return c2w


def photos(mesh: trimesh.Trimesh) -> list[PhotoView]:
    """``N_PHOTOS`` checkered photos all round the mesh, 20 degrees above its equator."""
    K = np.array([[1400.0, 0.0, PHOTO_WIDTH / 2], [0.0, 1400.0, PHOTO_HEIGHT / 2], [0, 0, 1]])
    renderer = MeshRenderer(mesh)
    views = []
    for k in range(N_PHOTOS):
        angle = 2 * np.pi * k / N_PHOTOS
        eye = 3.0 * np.array([np.cos(angle) * 0.94, 0.34, np.sin(angle) * 0.94])
        c2w = look_at(eye)
        result = renderer.render(K, c2w, PHOTO_WIDTH, PHOTO_HEIGHT)
        origins, directions = pixel_rays(K, c2w, PHOTO_WIDTH, PHOTO_HEIGHT)
        points = origins + directions * result.depth.reshape(-1, 1)
        checker = (np.floor(points * 10).astype(int).sum(1) % 2).reshape(PHOTO_HEIGHT,
                                                                         PHOTO_WIDTH)
        rgb = result.rgb * (0.6 + 0.4 * checker[..., None])
        views.append(PhotoView(rgb=rgb.astype(np.float32), K=K, c2w=c2w, mask=result.mask))
    return views


def main() -> None:
    """Time the bake with and without the photos; print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--threads", type=int, default=0, help="OpenCV threads (0: its own)")
    args = parser.parse_args()
    if args.threads:
        import cv2

        cv2.setNumThreads(args.threads)
    mesh = bumpy_sphere()
    views = photos(mesh)
    grey = np.array([0.5, 0.5, 0.5], np.float32)

    def field(p: np.ndarray, d: np.ndarray) -> np.ndarray:
        return np.tile(grey, (len(p), 1))

    start = time.perf_counter()
    bake_texture(mesh, field, args.size)
    field_s = time.perf_counter() - start
    start = time.perf_counter()
    baked = bake_texture(mesh, field, args.size, photos=partial(photo_colours, mesh, views))
    photo_s = time.perf_counter() - start
    print(f"{len(mesh.faces)} triangles, {N_PHOTOS} photos {PHOTO_WIDTH}x{PHOTO_HEIGHT}, "
          f"texture {args.size}: unwrap + field bake {field_s:.1f} s; unwrap + photo "
          f"texture {photo_s:.1f} s (photos: {photo_s - field_s:.1f} s); "
          f"texture {baked.texture.shape[0]} px")


if __name__ == "__main__":
    main()
