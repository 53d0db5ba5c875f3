"""The library format and loader, on the session's tiny library."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cadnerf_core.errors import LibraryError
from cadnerf_core.intake.crop import apply_crop, canonical_box
from cadnerf_core.library.format import (
    MANIFEST,
    OCCUPANCY_FILE,
    SILHOUETTES_FILE,
    load_library,
    save_npz,
)
from cadnerf_core.mesh.renderer import render_silhouette_polygons


@pytest.fixture()
def library_copy(tiny_library_dir: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(tiny_library_dir, tmp_path / "library"))


def test_loaded_library_has_everything(tiny_library: Any) -> None:
    lib = tiny_library
    spec = lib.spec
    assert [m.id for m in lib.models] == ["chair_wood", "mug", "cuboid_slab"]
    assert lib.poses.shape == (16, 4, 4) and lib.az_el.shape == (16, 2)
    assert np.allclose(lib.az_el[:2], [[0, 0], [0, 30]])  # azimuth-major
    assert lib.silhouettes.shape == (3, 16, 32, 32) and lib.silhouettes.dtype == bool
    assert lib.boxes.shape == (3, 16, 3)
    assert lib.K_render.shape == (3, 3) and lib.K_render[0, 2] == spec.render_size / 2
    assert lib.index("mug") == 1
    with pytest.raises(KeyError, match="nope"):
        lib.index("nope")
    for entry in lib.models:
        assert entry.n_triangles > 0 and len(entry.checksums) == 3
        assert entry.source == "parametric:cadnerf" and entry.licence.startswith("MIT")


def test_silhouettes_match_a_fresh_render(tiny_library: Any) -> None:
    lib = tiny_library
    mesh = lib.mesh("mug")
    assert mesh.is_watertight
    size = lib.spec.render_size
    for v in (0, 5, 11):
        render = render_silhouette_polygons(mesh, lib.K_render, lib.poses[v], size, size)
        box = canonical_box(render, lib.spec.silhouette_size, lib.spec.margin)
        assert np.allclose(lib.boxes[1, v], (box.x0, box.y0, box.side))
        crop = apply_crop(render, box)
        assert np.mean(crop == lib.silhouettes[1, v]) > 0.99


def test_the_near_set_sees_the_same_poses_from_nearer(tiny_library: Any) -> None:
    lib = tiny_library
    near = lib.near
    assert near is not None and near.near is None
    assert near.spec.distance == lib.spec.near_distance == 2.2
    assert near.spec.fov_deg == lib.spec.near_fov_deg
    assert near.silhouettes.shape == lib.silhouettes.shape and near.models is lib.models
    # Same directions, nearer cameras.
    assert np.allclose(near.poses[:, :3, :3], lib.poses[:, :3, :3])
    assert np.allclose(near.poses[:, :3, 3] * lib.spec.distance / near.spec.distance,
                       lib.poses[:, :3, 3])
    mesh = lib.mesh("chair_wood")
    size = near.spec.render_size
    for v in (3, 12):
        render = render_silhouette_polygons(mesh, near.K_render, near.poses[v], size, size)
        box = canonical_box(render, near.spec.silhouette_size, near.spec.margin)
        assert np.allclose(near.boxes[0, v], (box.x0, box.y0, box.side))
        assert np.mean(apply_crop(render, box) == near.silhouettes[0, v]) > 0.99
    # Perspective: the near silhouettes differ from the far ones.
    assert np.mean(near.silhouettes != lib.silhouettes) > 0.005
    assert near.occupancy("mug") is lib.occupancy("mug")
    assert lib.view_set("near") is near and near.view_set("far") is lib
    assert near.view_set("near") is near and lib.view_set("far") is lib


def test_a_library_built_before_the_near_set_loads_without_one(library_copy: Path) -> None:
    from cadnerf_core.library.format import NEAR_SUFFIX, load_npz, sha256_file

    manifest = json.loads((library_copy / MANIFEST).read_text())
    for key in ("near_distance", "near_fov_deg"):
        manifest["spec"].pop(key)
    for entry in manifest["models"]:
        path = library_copy / entry["id"] / SILHOUETTES_FILE
        arrays = {k: v for k, v in load_npz(path).items() if not k.endswith(NEAR_SUFFIX)}
        save_npz(path, arrays)
        entry["checksums"][SILHOUETTES_FILE] = sha256_file(path)
    (library_copy / MANIFEST).write_text(json.dumps(manifest))
    old = load_library(library_copy)
    assert old.spec.near_distance is None and old.near is None
    assert old.silhouettes.shape == (3, 16, 32, 32)


def test_a_near_set_missing_from_its_file_is_named(library_copy: Path) -> None:
    from cadnerf_core.library.format import NEAR_SUFFIX, load_npz, sha256_file

    manifest = json.loads((library_copy / MANIFEST).read_text())
    entry = manifest["models"][1]
    path = library_copy / entry["id"] / SILHOUETTES_FILE
    save_npz(path, {k: v for k, v in load_npz(path).items() if not k.endswith(NEAR_SUFFIX)})
    entry["checksums"][SILHOUETTES_FILE] = sha256_file(path)
    (library_copy / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(LibraryError, match=r"mug.*near set.*cadnerf library build"):
        load_library(library_copy)


def test_canonical_intrinsics_frame_the_model_with_the_margin(tiny_library: Any) -> None:
    lib = tiny_library
    mesh = lib.mesh("chair_wood")
    for v in (0, 9):
        size = 80
        K = lib.canonical_K(0, v, size)
        w2c = np.linalg.inv(lib.poses[v])
        cam = mesh.vertices @ w2c[:3, :3].T + w2c[:3, 3]
        uv = cam @ K.T
        uv = uv[:, :2] / uv[:, 2:]
        extent = uv.max(0) - uv.min(0)
        centre = (uv.max(0) + uv.min(0)) / 2
        assert np.allclose(centre, size / 2, atol=1.5)
        assert extent.max() == pytest.approx(size * (1 - 2 * lib.spec.margin), abs=2.0)


def test_occupancy_of_a_model(tiny_library: Any) -> None:
    grid = tiny_library.occupancy("cuboid_slab")
    assert grid.values.shape == (32, 32, 32)
    assert grid.query(np.zeros((1, 3)))[0] and not grid.query(np.full((1, 3), 0.95))[0]
    assert tiny_library.occupancy("cuboid_slab") is grid  # cached


def test_damaged_file_is_named(library_copy: Path) -> None:
    path = library_copy / "mug" / OCCUPANCY_FILE
    path.write_bytes(path.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(LibraryError) as info:
        load_library(library_copy)
    assert str(path) in str(info.value) and "cadnerf library build" in str(info.value)
    load_library(library_copy, verify=False)  # checksums skipped, silhouettes still fine


def test_missing_file_and_manifest_are_named(library_copy: Path) -> None:
    (library_copy / "chair_wood" / SILHOUETTES_FILE).unlink()
    with pytest.raises(LibraryError, match="chair_wood/silhouettes.npz is missing"):
        load_library(library_copy)
    (library_copy / MANIFEST).unlink()
    with pytest.raises(LibraryError, match="manifest.json is missing"):
        load_library(library_copy)


def test_other_format_version_is_refused(library_copy: Path) -> None:
    data = json.loads((library_copy / MANIFEST).read_text())
    data["format_version"] = 999
    (library_copy / MANIFEST).write_text(json.dumps(data))
    with pytest.raises(LibraryError, match="format version 999"):
        load_library(library_copy)


def test_npz_bytes_are_deterministic(tmp_path: Path) -> None:
    arrays: dict[str, np.ndarray] = {"b": np.arange(10, dtype=np.uint8), "a": np.eye(3)}
    save_npz(tmp_path / "one.npz", arrays)
    save_npz(tmp_path / "two.npz", dict(reversed(list(arrays.items()))))
    assert (tmp_path / "one.npz").read_bytes() == (tmp_path / "two.npz").read_bytes()
    with np.load(tmp_path / "one.npz") as data:
        assert np.array_equal(data["a"], np.eye(3))
