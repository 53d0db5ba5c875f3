"""Mesh rendering: silhouettes, depth, polygon silhouettes, texture and colour lookup."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.cameras.conventions import intrinsics_from_fov, look_at, orbit_pose
from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
from cadnerf_core.mesh.renderer import MeshRenderer, render_silhouette_polygons, sample_texture

EVAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval"


def test_unit_sphere_silhouette_area_and_centre_depth() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5)
    size, distance = 64, 4.0
    K = intrinsics_from_fov(40.0, size)
    result = MeshRenderer(sphere).render(K, orbit_pose(20.0, 10.0, distance), size, size)
    # The sphere's image is a disc of radius f * tan(asin(1 / d)).
    radius = K[0, 0] * math.tan(math.asin(1.0 / distance))
    assert result.mask.sum() == pytest.approx(math.pi * radius**2, rel=0.03)
    centre = result.depth[size // 2 - 1:size // 2 + 1, size // 2 - 1:size // 2 + 1]
    np.testing.assert_allclose(centre, distance - 1.0, atol=2e-3)
    assert (result.depth[~result.mask] == 0).all() and (result.depth[result.mask] > 0).all()
    assert result.rgb.dtype == np.float32 and result.rgb.shape == (size, size, 3)
    assert (result.rgb[~result.mask] == 1.0).all()
    assert result.rgb[result.mask].min() > 0.2  # ambient light: nothing is black


def test_silhouette_equals_render_mask_and_background_is_used() -> None:
    box = trimesh.creation.box((1.0, 0.5, 0.8))
    renderer = MeshRenderer(box)
    K, c2w = intrinsics_from_fov(40.0, 48, 40), orbit_pose(45.0, 30.0, 3.0)
    result = renderer.render(K, c2w, 48, 40, background=(0.0, 0.5, 0.0))
    assert np.array_equal(renderer.silhouette(K, c2w, 48, 40), result.mask)
    np.testing.assert_allclose(result.rgb[~result.mask], [[0.0, 0.5, 0.0]] * (~result.mask).sum())


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def _meshes() -> list[trimesh.Trimesh]:
    meshes = [trimesh.creation.icosphere(3), trimesh.creation.box((1.2, 0.3, 0.7)),
              trimesh.creation.torus(0.6, 0.2), trimesh.creation.cylinder(0.4, 1.5)]
    spot = EVAL / "meshes" / "spot" / "spot_triangulated.obj"
    if spot.is_file():
        meshes.append(load_mesh(spot))
    return [normalise_mesh(m) for m in meshes]


@pytest.mark.parametrize("mesh_index", range(5))
def test_polygon_silhouettes_match_ray_casting(mesh_index: int) -> None:
    meshes = _meshes()
    if mesh_index >= len(meshes):
        pytest.skip("shared eval meshes absent")
    mesh = meshes[mesh_index]
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(40.0, 64, 48)
    for azimuth, elevation, distance in [(0, 0, 4.0), (57, 25, 3.0), (210, 60, 2.5)]:
        c2w = orbit_pose(azimuth, elevation, distance)
        rays = renderer.silhouette(K, c2w, 64, 48)
        polygons = render_silhouette_polygons(mesh, K, c2w, 64, 48)
        assert rays.sum() > 100
        assert _iou(rays, polygons) >= 0.98


def test_polygon_silhouette_of_a_mesh_larger_than_the_image() -> None:
    big = trimesh.creation.box((1.0, 1.0, 1.0))
    K, c2w = intrinsics_from_fov(60.0, 32), orbit_pose(10.0, 5.0, 1.2)
    assert render_silhouette_polygons(big, K, c2w, 32, 32).all()
    assert MeshRenderer(big).silhouette(K, c2w, 32, 32).all()


def _textured_quad() -> trimesh.Trimesh:
    """A 2x2 quad in the z = 0 plane facing +Z, each quarter of its texture a pure colour."""
    texture = np.zeros((8, 8, 3), dtype=np.uint8)
    texture[:4, :4] = (255, 0, 0)  # top-left of the image = high v, low u
    texture[:4, 4:] = (0, 255, 0)
    texture[4:, :4] = (0, 0, 255)
    texture[4:, 4:] = (255, 255, 0)
    quad = trimesh.Trimesh(vertices=[[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                           faces=[[0, 1, 2], [0, 2, 3]], process=False)
    quad.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                                image=Image.fromarray(texture))
    return quad


def test_texture_colour_is_sampled_at_the_hit() -> None:
    size = 64
    K = intrinsics_from_fov(40.0, size)
    c2w = look_at(np.array([0.0, 0.0, 4.0]))  # image right = +X, image up = +Y
    result = MeshRenderer(_textured_quad()).render(K, c2w, size, size, background=0.0)
    q = size // 2
    expected = {(q - 8, q - 8): (1, 0, 0), (q - 8, q + 8): (0, 1, 0),
                (q + 8, q - 8): (0, 0, 1), (q + 8, q + 8): (1, 1, 0)}
    shade = result.rgb[q - 8, q - 8, 0]
    assert 0.35 <= shade <= 1.0
    for (row, col), colour in expected.items():
        assert result.mask[row, col]
        np.testing.assert_allclose(result.rgb[row, col], shade * np.array(colour), atol=1e-3)


def test_sample_texture_is_bilinear_and_clamps_at_the_border() -> None:
    texture = np.array([[[0, 0, 0], [200, 100, 0]]], dtype=np.uint8)  # 1 row, 2 texels
    uv = np.array([[0.5, 0.5], [0.0, 0.5], [1.0, 0.5], [0.25, 0.5], [1.25, 0.5]])
    out = sample_texture(texture, uv)
    np.testing.assert_allclose(out[:, 0], [100 / 255, 0.0, 200 / 255, 0.0, 0.0], atol=1e-6)


def test_vertex_and_face_colours_are_used() -> None:
    K, c2w = intrinsics_from_fov(40.0, 32), orbit_pose(0.0, 0.0, 4.0)
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    box.visual.face_colors = (0, 255, 0, 255)
    rgb = MeshRenderer(box).render(K, c2w, 32, 32).rgb[16, 16]
    assert rgb[1] > 0.3 and rgb[0] == 0.0 and rgb[2] == 0.0
    sphere = trimesh.creation.icosphere(2)
    sphere.visual.vertex_colors = (0, 0, 255, 255)
    rgb = MeshRenderer(sphere).render(K, c2w, 32, 32).rgb[16, 16]
    assert rgb[2] > 0.3 and rgb[0] == 0.0 and rgb[1] == 0.0
