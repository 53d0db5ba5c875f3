"""The textured mesh: decimation, UV bake, GLB (Khronos validator) and OBJ + MTL + texture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from cadnerf_core.export.mesh import drop_small_pieces, extract_mesh, write_glb, write_obj
from cadnerf_core.export.texture import TexturedMesh, bake_texture, decimate, rasterize_uv
from cadnerf_core.jobfolder import MESH, MESH_OBJ, MESH_TEXTURE, JobFolder
from tests.gltf_validator import assert_no_errors_or_warnings, needs_validator


def _quadrant_colour(points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Red where x > 0, green where y > 0: a colour field with sharp, checkable edges."""
    return np.stack([(points[:, 0] > 0), (points[:, 1] > 0) * 0.5,
                     np.full(len(points), 0.2)], 1).astype(np.float32)


@pytest.fixture(scope="module")
def baked() -> TexturedMesh:
    G = 40
    axis = np.linspace(-1.1, 1.1, G)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    mesh = extract_mesh((np.sqrt(x**2 + y**2 + z**2) < 0.6).astype(np.float32), 1.1, 0.5)
    return bake_texture(decimate(mesh, 2000), _quadrant_colour, 128)


def test_decimation_keeps_the_shape() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.6)
    small = decimate(sphere, 1000)
    assert 800 <= len(small.faces) <= 1000
    assert np.linalg.norm(small.vertices, axis=1) == pytest.approx(0.6, abs=0.02)
    again = decimate(small, 10_000)
    assert len(again.faces) == len(small.faces) and (again.area_faces > 0).all()


def _field_with_specks() -> trimesh.Trimesh:
    """Marching cubes on a ball of radius 0.6 with two specks of density beside it: one of a
    single voxel, one a cube of two voxels a side."""
    G = 40
    axis = np.linspace(-1.1, 1.1, G)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    field = (np.sqrt(x**2 + y**2 + z**2) < 0.6).astype(np.float32)
    field[35, 35, 35] = 1.0
    field[3:5, 3:5, 30:32] = 1.0
    return extract_mesh(field, 1.1, 0.5)


def test_specks_of_density_are_dropped_and_the_object_kept() -> None:
    whole = _field_with_specks()
    assert len(whole.split(only_watertight=False)) == 3
    clean = drop_small_pieces(whole)
    assert len(clean.split(only_watertight=False)) == 1
    assert np.linalg.norm(clean.vertices, axis=1).max() < 0.7  # the ball's, nothing beside it
    ball = max(whole.split(only_watertight=False), key=lambda piece: piece.area)
    assert clean.area == pytest.approx(ball.area)
    assert len(clean.vertices) == len(np.unique(clean.faces))  # no vertex left unused


def test_pieces_of_like_size_are_all_kept() -> None:
    twins = trimesh.util.concatenate([trimesh.creation.icosphere(radius=0.3).apply_translation(
        [dx, 0.0, 0.0]) for dx in (-0.5, 0.5)])
    assert len(drop_small_pieces(twins).faces) == len(twins.faces)
    assert drop_small_pieces(twins, 0.0) is twins


def test_rasterize_covers_a_triangle_once_with_barycentrics() -> None:
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    texel, face, bary = rasterize_uv(uv, faces, 8)
    assert len(texel) == 64 and len(np.unique(texel)) == 64  # two halves tile the square
    assert np.allclose(bary.sum(1), 1.0) and (bary >= -1e-6).all()
    row, col = texel // 8, texel % 8
    # Texel centre (col + 0.5, row + 0.5) in pixels, v up: uv = (x / 8, 1 - y / 8).
    u, v = (col + 0.5) / 8, 1 - (row + 0.5) / 8
    assert np.allclose(np.einsum("tk,tkd->td", bary, uv[faces[face]]), np.stack([u, v], 1))


def test_texture_holds_the_field_colour_at_each_vertex(baked: TexturedMesh) -> None:
    size = baked.texture.shape[0]
    col = np.clip((baked.uv[:, 0] * size).astype(int), 0, size - 1)
    row = np.clip(((1 - baked.uv[:, 1]) * size).astype(int), 0, size - 1)
    sampled = baked.texture[row, col] / 255.0
    expected = _quadrant_colour(baked.vertices, baked.vertices)
    # Vertices on the colour edges (x or y near 0) may take either side's texel.
    away = (np.abs(baked.vertices[:, 0]) > 0.05) & (np.abs(baked.vertices[:, 1]) > 0.05)
    assert np.abs(sampled - expected).max(1)[away].max() < 0.01
    assert baked.texture.dtype == np.uint8 and (baked.uv >= 0).all() and (baked.uv <= 1).all()


def test_glb_has_a_textured_non_metallic_material(tmp_path: Path, baked: TexturedMesh) -> None:
    write_glb(tmp_path / MESH, baked)
    scene = trimesh.load(tmp_path / MESH, force="mesh")
    assert isinstance(scene, trimesh.Trimesh)
    material = scene.visual.material
    assert isinstance(material, trimesh.visual.material.PBRMaterial)
    assert material.metallicFactor == 0.0 and material.baseColorTexture is not None
    assert material.baseColorTexture.size == (128, 128)
    assert len(scene.faces) == len(baked.faces)


@needs_validator
def test_glb_passes_the_khronos_validator(tmp_path: Path, baked: TexturedMesh) -> None:
    write_glb(tmp_path / MESH, baked)
    assert_no_errors_or_warnings(tmp_path / MESH)


def test_obj_with_material_and_texture_loads_back(tmp_path: Path, baked: TexturedMesh) -> None:
    folder = JobFolder(tmp_path)
    write_obj(folder, baked)
    loaded = trimesh.load(folder.file(MESH_OBJ), force="mesh", process=False)
    assert isinstance(loaded, trimesh.Trimesh)
    assert len(loaded.faces) == len(baked.faces)
    assert np.allclose(loaded.visual.uv, baked.uv, atol=1e-5)
    assert loaded.visual.material.image.size == (128, 128)
    assert folder.file(MESH_TEXTURE).is_file()
