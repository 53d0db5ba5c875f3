"""The mesh's texture from the photos: colours where seen, occlusion, the field elsewhere, gains."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import pytest
import trimesh

from cadnerf_core.export.photo_texture import PhotoView, fit_gains, photo_colours
from cadnerf_core.export.texture import bake_texture, rasterize_uv
from cadnerf_core.mesh.renderer import MeshRenderer, pixel_rays

SIZE, FOCAL = 96, 180.0
K = np.array([[FOCAL, 0.0, SIZE / 2], [0.0, FOCAL, SIZE / 2], [0.0, 0.0, 1.0]])
FACE_COLOURS = {(0, 1): (0.6, 0.2, 0.2), (0, -1): (0.2, 0.6, 0.2), (1, 1): (0.2, 0.2, 0.6),
                (1, -1): (0.6, 0.6, 0.2), (2, 1): (0.6, 0.2, 0.6), (2, -1): (0.2, 0.6, 0.6)}
"""(axis, sign) of a cube's face -> its colour."""


def cube_colour(points: np.ndarray) -> np.ndarray:
    """Each face of the unit cube its own colour. points [N, 3] -> [N, 3]."""
    axis = np.abs(points).argmax(1)
    sign = np.sign(points[np.arange(len(points)), axis]).astype(int)
    return np.array([FACE_COLOURS[(a, s)] for a, s in zip(axis, sign, strict=True)],
                    np.float32).reshape(-1, 3)


def look_at(eye: Sequence[float], target: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """OpenCV camera-to-world [4, 4] at ``eye`` looking at ``target``, +Y world up."""
    z = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = eye
    return c2w


def shoot(mesh: trimesh.Trimesh, eye: Sequence[float],
          colour: Callable[[np.ndarray], np.ndarray], gain: float = 1.0) -> PhotoView:
    """A photo of ``mesh`` from ``eye``: each pixel the unshaded ``colour`` of the point it
    sees, white background, the mesh's outline as its mask."""
    c2w = look_at(eye)
    result = MeshRenderer(mesh).render(K, c2w, SIZE, SIZE)
    origins, directions = pixel_rays(K, c2w, SIZE, SIZE)
    points = (origins + directions * result.depth.reshape(-1, 1))[result.mask.ravel()]
    rgb = np.ones((SIZE * SIZE, 3), np.float32)
    rgb[result.mask.ravel()] = np.clip(colour(points) * gain, 0.0, 1.0)
    return PhotoView(rgb=rgb.reshape(SIZE, SIZE, 3), K=K, c2w=c2w, mask=result.mask)


def face_points(axis: int, sign: int, offset: float = 0.5, half: float = 0.4,
                n: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """A grid of points [n*n, 3] on the plane ``x[axis] = sign * offset`` within ``half`` of
    its centre, and their normals [n*n, 3] (along ``sign`` on ``axis``)."""
    u, v = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    others = [a for a in range(3) if a != axis]
    points = np.zeros((n * n, 3))
    points[:, axis] = sign * offset
    points[:, others[0]], points[:, others[1]] = u.ravel(), v.ravel()
    normals = np.zeros_like(points)
    normals[:, axis] = sign
    return points, normals


CUBE = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
AROUND = [(3.5, 0.0, 0.0), (-3.5, 0.0, 0.0), (0.0, 3.5, 0.1), (0.0, -3.5, 0.1),
          (0.0, 0.0, 3.5), (0.0, 0.0, -3.5), (2.5, 1.0, 2.5), (-2.5, 1.0, -2.5)]
"""Eyes all round the cube: every face seen head-on, two seen obliquely as well."""


def test_seen_texels_take_the_colour_of_the_photos() -> None:
    views = [shoot(CUBE, eye, cube_colour) for eye in AROUND]
    for (axis, sign), expected in FACE_COLOURS.items():
        points, normals = face_points(axis, sign)
        rgb, seen = photo_colours(CUBE, views, points, normals)
        assert seen.all(), (axis, sign)
        assert np.abs(rgb - expected).max() < 0.02, (axis, sign)


def test_an_occluded_texel_takes_no_colour_from_the_photo_that_cannot_see_it() -> None:
    """A small blue block in front of the cube hides the middle of its front face from the
    photo straight ahead; the photo from the side sees behind the block."""
    block = trimesh.creation.box(extents=(0.4, 0.4, 0.4),
                                 transform=trimesh.transformations.translation_matrix(
                                     (0.0, 0.0, 1.2)))
    scene = trimesh.Trimesh(*trimesh.util.append_faces(
        [CUBE.vertices, block.vertices], [CUBE.faces, block.faces]), process=False)
    blue = np.array([0.1, 0.1, 0.9], np.float32)

    def colour(points: np.ndarray) -> np.ndarray:
        return np.where(points[:, 2:] > 0.99, blue, cube_colour(points))

    ahead = shoot(scene, (0.0, 0.0, 4.0), colour)
    side = shoot(scene, (4.0 * np.sin(0.87), 0.0, 4.0 * np.cos(0.87)), colour)
    front = FACE_COLOURS[(2, 1)]
    behind, normals = face_points(2, 1, half=0.1, n=5)  # in the block's shadow from ahead
    rgb, seen = photo_colours(scene, [ahead, side], behind, normals)
    assert seen.all() and np.abs(rgb - front).max() < 0.02  # the side's, not the block's
    rgb, seen = photo_colours(scene, [ahead], behind, normals)
    assert not seen.any()  # hidden from the only photo: left to the field
    clear, normals = face_points(2, 1, half=0.08, n=3)
    clear[:, 0] -= 0.38  # on the front face, clear of the block's shadow from ahead
    rgb, seen = photo_colours(scene, [ahead], clear, normals)
    assert seen.all() and np.abs(rgb - front).max() < 0.02


def test_the_field_fills_what_no_photo_sees() -> None:
    """Photos from the +x side only: the -x face of the baked texture keeps the field's grey."""
    views = [shoot(CUBE, eye, cube_colour) for eye in [(3.5, 0.0, 0.0), (2.5, 1.0, 2.5)]]
    grey = np.array([0.5, 0.5, 0.5], np.float32)
    size = 128
    baked = bake_texture(CUBE, lambda p, d: np.tile(grey, (len(p), 1)), size,
                         photos=partial(photo_colours, CUBE, views))
    texel, face, bary = rasterize_uv(baked.uv, baked.faces, size)
    points = np.einsum("tk,tkd->td", bary, baked.vertices[baked.faces[face]])
    colours = baked.texture.reshape(-1, 3)[texel] / 255.0
    inner = np.abs(points[:, 1:]).max(1) < 0.4  # on the x faces, away from their edges
    back = inner & (points[:, 0] < -0.49)
    front = inner & (points[:, 0] > 0.49)
    assert back.sum() > 100 and front.sum() > 100
    assert np.abs(colours[back] - grey).max() < 0.01
    assert np.abs(colours[front] - FACE_COLOURS[(0, 1)]).max() < 0.03


def test_exposure_matching_undoes_a_gain() -> None:
    rng = np.random.default_rng(1)
    truth = rng.uniform(0.1, 0.7, (500, 3))
    rgb = np.stack([truth * g for g in (1.0, 1.0, 1.3, 1.0)])
    seen = rng.random((4, 500)) < 0.7
    gains = fit_gains(rgb, seen)
    assert gains[2] == pytest.approx(np.full(3, 1 / 1.3), abs=0.01)
    assert gains[[0, 1, 3]] == pytest.approx(np.ones((3, 3)), abs=0.01)


def test_a_photo_brighter_than_the_rest_is_matched_to_them() -> None:
    """The photo of the +x face head-on is 1.3 times too bright; the gains are fitted on the
    whole cube, which the other photos see at their true exposure."""
    views = [shoot(CUBE, eye, cube_colour, gain=1.3 if i == 0 else 1.0)
             for i, eye in enumerate(AROUND)]
    faces = [face_points(axis, sign) for axis, sign in FACE_COLOURS]
    points, normals = np.concatenate([p for p, _ in faces]), np.concatenate([n for _, n in faces])
    rgb, seen = photo_colours(CUBE, views, points, normals)
    assert seen.all()
    assert np.abs(rgb - cube_colour(points)).max() < 0.02
