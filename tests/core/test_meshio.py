"""Mesh loading: every format, textures, scenes, and one clear error for each bad file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.cameras.conventions import intrinsics_from_fov, look_at
from cadnerf_core.errors import MeshError
from cadnerf_core.mesh.meshio import load_mesh, merge_meshes, normalise_mesh, texture_image
from cadnerf_core.mesh.renderer import MeshRenderer

EVAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval"


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_each_format_written_by_trimesh_loads(tmp_path: Path, ext: str) -> None:
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    path = tmp_path / f"box.{ext}"
    box.export(path)
    mesh = load_mesh(path)
    assert isinstance(mesh, trimesh.Trimesh)
    assert mesh.faces.shape[1] == 3 and len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.bounds, box.bounds, atol=1e-6)


def _write_textured_quad(folder: Path) -> None:
    """An OBJ quad (one 4-sided face) with an MTL and a texture, all with spaces in names."""
    folder.mkdir(parents=True, exist_ok=True)
    texture = np.zeros((8, 8, 3), dtype=np.uint8)
    texture[:4, :4] = (255, 0, 0)  # top-left
    texture[:4, 4:] = (0, 255, 0)  # top-right
    texture[4:, :4] = (0, 0, 255)  # bottom-left
    texture[4:, 4:] = (255, 255, 0)  # bottom-right
    Image.fromarray(texture).save(folder / "quad texture.png")
    (folder / "quad material.mtl").write_text(
        "newmtl paint\nKd 1 1 1\nmap_Kd quad texture.png\n")
    (folder / "my quad.obj").write_text(
        "mtllib quad material.mtl\n"
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl paint\nf 1/1 2/2 3/3 4/4\n")


def test_obj_with_mtl_texture_and_spaces_is_triangulated_and_textured(tmp_path: Path) -> None:
    _write_textured_quad(tmp_path / "a folder")
    mesh = load_mesh(tmp_path / "a folder" / "my quad.obj")
    assert len(mesh.faces) == 2  # the quad, triangulated
    assert isinstance(mesh.visual, trimesh.visual.TextureVisuals)
    image = texture_image(mesh)
    assert image is not None and image.size == (8, 8)


def test_uv_mesh_without_mtl_picks_up_the_texture_beside_it(tmp_path: Path) -> None:
    _write_textured_quad(tmp_path)
    obj = (tmp_path / "my quad.obj").read_text().replace("mtllib quad material.mtl\n", "")
    (tmp_path / "quad.obj").write_text(obj.replace("usemtl paint\n", ""))
    (tmp_path / "quad material.mtl").unlink()
    mesh = load_mesh(tmp_path / "quad.obj")
    image = texture_image(mesh)
    assert image is not None and image.size == (8, 8)


def test_glb_scene_parts_are_merged_with_their_transforms(tmp_path: Path) -> None:
    scene = trimesh.Scene()
    red = trimesh.creation.box((1.0, 1.0, 1.0))
    red.visual.face_colors = (255, 0, 0, 255)
    blue = trimesh.creation.icosphere(1, radius=0.5)
    blue.visual.face_colors = (0, 0, 255, 255)
    scene.add_geometry(red)
    scene.add_geometry(blue, transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    scene.export(tmp_path / "parts.glb")
    mesh = load_mesh(tmp_path / "parts.glb")
    assert len(mesh.faces) == len(red.faces) + len(blue.faces)
    assert mesh.bounds[1, 0] == pytest.approx(3.5, abs=1e-6)
    assert isinstance(mesh.visual, trimesh.visual.ColorVisuals)
    colours = mesh.visual.face_colors[:, :3]
    assert {(255, 0, 0), (0, 0, 255)} <= {tuple(int(c) for c in row) for row in colours}


def test_merge_keeps_textures_of_textured_parts(tmp_path: Path) -> None:
    _write_textured_quad(tmp_path)
    quad = load_mesh(tmp_path / "my quad.obj")
    other = quad.copy()
    other.apply_translation([3.0, 0.0, 0.0])
    merged = merge_meshes([quad, other])
    assert len(merged.faces) == 4
    assert isinstance(merged.visual, trimesh.visual.TextureVisuals)
    assert merged.visual.uv is not None and len(merged.visual.uv) == len(merged.vertices)


def _bad_file(tmp_path: Path, case: str) -> Path:
    if case == "missing":
        return tmp_path / "nothing here.obj"
    if case == "empty":
        (tmp_path / "empty.ply").touch()
        return tmp_path / "empty.ply"
    if case == "unsupported":
        (tmp_path / "notes.txt").write_text("v 0 0 0\n")
        return tmp_path / "notes.txt"
    if case == "garbage":
        (tmp_path / "garbage.glb").write_bytes(b"this is not a gltf binary at all")
        return tmp_path / "garbage.glb"
    if case == "points":
        trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(tmp_path / "pts.ply")
        return tmp_path / "pts.ply"
    (tmp_path / "no faces.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    return tmp_path / "no faces.obj"


@pytest.mark.parametrize("case", ["missing", "empty", "unsupported", "garbage", "points",
                                  "no_faces"])
def test_bad_files_raise_one_mesh_error_naming_the_file(tmp_path: Path, case: str) -> None:
    path = _bad_file(tmp_path, case)
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    message = str(info.value)
    assert path.name in message and "\n" not in message
    assert info.value.item == str(path)


def test_normalise_mesh_centres_scales_and_turns_z_up_to_y_up() -> None:
    mesh = trimesh.creation.box((2.0, 4.0, 10.0))  # tallest along z
    mesh.apply_translation([5.0, -3.0, 7.0])
    out = normalise_mesh(mesh, up="z")
    np.testing.assert_allclose(out.bounds.mean(axis=0), 0.0, atol=1e-12)
    assert np.linalg.norm(out.vertices, axis=1).max() == pytest.approx(1.0)
    extents = out.bounds[1] - out.bounds[0]
    assert np.argmax(extents) == 1  # z is now y
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), [5.0, -3.0, 7.0])  # input untouched
    same = normalise_mesh(mesh, up="y")
    assert np.argmax(same.bounds[1] - same.bounds[0]) == 2


@pytest.mark.skipif(not (EVAL / "meshes").is_dir(), reason="shared eval meshes absent")
@pytest.mark.parametrize("name", ["spot/spot_triangulated.obj", "fuze/fuze.obj", "Duck/Duck.glb",
                                  "fsu_kerolamp/kerolamp.ply"])
def test_real_meshes_load(name: str) -> None:
    mesh = load_mesh(EVAL / "meshes" / name)
    assert len(mesh.faces) >= 1000
    if name.endswith((".obj", ".glb")):
        image = texture_image(mesh)  # a real texture, not trimesh's placeholder
        assert image is not None and min(image.size) >= 256


def test_merge_of_textured_and_coloured_parts_keeps_both_colours() -> None:
    quad = trimesh.Trimesh(vertices=[[-1, -1, 0], [0, -1, 0], [0, 1, 0], [-1, 1, 0]],
                           faces=[[0, 1, 2], [0, 2, 3]], process=False)
    red = Image.fromarray(np.full((8, 8, 3), (255, 0, 0), dtype=np.uint8))
    quad.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]], image=red)
    box = trimesh.creation.box((0.8, 0.8, 0.1))
    box.apply_translation([0.6, 0.0, 0.0])
    box.visual.face_colors = (0, 0, 255, 255)
    merged = merge_meshes([quad, box])
    K = intrinsics_from_fov(40.0, 48)
    rgb = MeshRenderer(merged).render(K, look_at(np.array([0.0, 0.0, 4.0])), 48, 48).rgb
    left, right = rgb[24, 14], rgb[24, 34]
    assert left[0] > 0.3 and left[1] < 0.05 and left[2] < 0.05
    assert right[2] > 0.3 and right[0] < 0.05 and right[1] < 0.05
