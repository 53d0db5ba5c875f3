"""`cadnerf library add/remove`: round trips, repairs, rejections that leave nothing behind."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from cadnerf_core.errors import InputError, MeshError
from cadnerf_core.library.format import MANIFEST, LibrarySpec, load_library
from cadnerf_core.mesh.meshio import Z_UP_TO_Y_UP
from library_data.build import build_library
from library_data.importer import add_model, prepare_mesh, remove_model, resolve_source

EVAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval"


@pytest.fixture()
def library_copy(tiny_library_dir: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(tiny_library_dir, tmp_path / "library"))


def _listing(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir())


@pytest.mark.parametrize("suffix", ["stl", "off"])
def test_add_then_remove_round_trip(library_copy: Path, tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"Box Shape.{suffix}"
    trimesh.creation.box(extents=(2.0, 1.0, 0.5)).export(path)
    entry = add_model(library_copy, path, "box")
    assert entry.id == "box_shape" and entry.source == f"import:{path.name}"
    lib = load_library(library_copy)
    assert [m.id for m in lib.models][-1] == "box_shape"
    m, slab = lib.index("box_shape"), lib.index("cuboid_slab")  # cuboid_slab is 2 : 1 : 0.5
    assert np.mean(lib.silhouettes[m] == lib.silhouettes[slab]) > 0.97
    assert lib.occupancy("box_shape").values.mean() > 0.05
    remove_model(library_copy, "box_shape")
    assert "box_shape" not in _listing(library_copy)
    assert [e.id for e in load_library(library_copy).models] == ["chair_wood", "mug", "cuboid_slab"]


def test_open_mesh_is_made_watertight(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3)
    sphere.update_faces(np.arange(len(sphere.faces)) >= 6)  # a small hole
    assert not sphere.is_watertight
    path = tmp_path / "open.ply"
    sphere.export(path)
    mesh, rule = prepare_mesh(path, grid_size=48)
    assert rule == "parity" and mesh.is_watertight
    assert mesh.volume == pytest.approx(4 / 3 * np.pi, rel=0.1)  # filled, not a shell


def test_z_up_files_are_turned(tmp_path: Path) -> None:
    tall = trimesh.creation.box(extents=(0.2, 0.3, 2.0))  # tall along +Z
    path = tmp_path / "tall.stl"
    tall.export(path)
    mesh, _ = prepare_mesh(path, up="z")
    assert np.argmax(mesh.extents) == 1
    assert np.allclose(Z_UP_TO_Y_UP[:3, :3] @ [0, 0, 1], [0, 1, 0])


def test_broken_file_is_rejected_and_nothing_is_left(library_copy: Path, tmp_path: Path) -> None:
    before, listing = (library_copy / MANIFEST).read_bytes(), _listing(library_copy)
    for name, content in (("junk.stl", b"this is not a mesh"), ("empty.obj", b"")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(MeshError) as info:
            add_model(library_copy, tmp_path / name, "thing")
        assert name in str(info.value) and "\n" not in str(info.value)
    assert (library_copy / MANIFEST).read_bytes() == before
    assert _listing(library_copy) == listing


def test_duplicate_or_bad_id_is_rejected(library_copy: Path, tmp_path: Path) -> None:
    path = tmp_path / "b.stl"
    trimesh.creation.box().export(path)
    with pytest.raises(InputError, match="already in the library"):
        add_model(library_copy, path, "box", model_id="mug")
    with pytest.raises(InputError, match="lowercase"):
        add_model(library_copy, path, "box", model_id="../escape")
    with pytest.raises(InputError, match="no such model"):
        remove_model(library_copy, "ghost")


def test_modelnet_off_and_shapenet_folder(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    body = "\n".join(" ".join(map(str, v)) for v in box.vertices)
    faces = "\n".join("3 " + " ".join(map(str, f)) for f in box.faces)
    glued = tmp_path / "chair_0001.off"
    glued.write_text(f"OFF{len(box.vertices)} {len(box.faces)} 0\n{body}\n{faces}\n")
    mesh, rule = prepare_mesh(glued)
    assert rule == "winding" and len(mesh.faces) == 12
    shapenet = tmp_path / "1a2b3c" / "models"
    shapenet.mkdir(parents=True)
    box.export(shapenet / "model_normalized.obj")
    assert resolve_source(tmp_path / "1a2b3c") == shapenet / "model_normalized.obj"


def test_imported_models_survive_a_rebuild(library_copy: Path, tmp_path: Path) -> None:
    path = tmp_path / "crate.stl"
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(path)
    add_model(library_copy, path, "crate")
    from cadnerf_core.library.format import LibrarySpec

    spec = LibrarySpec(n_azimuths=4, elevations=(0.0,), silhouette_size=16, grid_size=16)
    build_library(library_copy, spec, jobs=1, model_ids=["sphere"])
    lib = load_library(library_copy)
    assert [m.id for m in lib.models] == ["sphere", "crate"]
    assert lib.silhouettes.shape == (2, 4, 16, 16)


def test_cli_list_add_remove(library_copy: Path, tmp_path: Path) -> None:
    from cadnerf_cli.main import app

    runner = CliRunner()
    result = runner.invoke(app, ["library", "list", "--json", "--library", str(library_copy)])
    assert result.exit_code == 0
    assert [m["id"] for m in json.loads(result.stdout)["models"]] == [
        "chair_wood", "mug", "cuboid_slab"]
    (tmp_path / "bad.off").write_text("OFF\n3 1 0\n0 0 0\n")
    result = runner.invoke(app, ["library", "add", str(tmp_path / "bad.off"), "--category", "x",
                                 "--library", str(library_copy)])
    assert result.exit_code == 1 and "bad.off" in result.output
    path = tmp_path / "cube.stl"
    trimesh.creation.box().export(path)
    result = runner.invoke(app, ["library", "add", str(path), "--category", "box", "--id", "c1",
                                 "--library", str(library_copy)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["library", "remove", "c1", "--library", str(library_copy)])
    assert result.exit_code == 0 and "c1" not in _listing(library_copy)


@pytest.mark.skipif(not (EVAL / "meshes" / "Duck").is_dir(), reason="../shared/eval absent")
def test_add_a_real_glb(library_copy: Path) -> None:
    entry = add_model(library_copy, EVAL / "meshes" / "Duck" / "Duck.glb", "duck")
    lib = load_library(library_copy)
    assert lib.mesh(entry.id).is_watertight
    assert lib.silhouettes[lib.index("duck")].mean() > 0.1


@pytest.mark.parametrize(("args", "n_azimuths", "elevations"), [
    ([], 36, (0.0, 7.5, 15.0, 22.5, 30.0, 37.5, 45.0, 52.5, 60.0)),
    (["--poses", "180"], 20, LibrarySpec().elevations),
    (["--elevations", "0,7.5,15"], 36, (0.0, 7.5, 15.0)),
    (["--elevations", "0,30", "--poses", "40"], 20, (0.0, 30.0)),
])
def test_cli_build_passes_the_pose_set(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                       args: list[str], n_azimuths: int,
                                       elevations: tuple[float, ...]) -> None:
    import library_data.build as build_module
    from cadnerf_cli.main import app

    seen: dict[str, LibrarySpec] = {}

    def fake_build(out: Path, spec: LibrarySpec, **kwargs: object) -> object:
        seen["spec"] = spec
        return build_module.BuildResult(root=out, built=True, n_models=0, seconds=0.0)

    monkeypatch.setattr(build_module, "build_library", fake_build)
    result = CliRunner().invoke(app, ["library", "build", "--out", str(tmp_path / "l"), *args])
    assert result.exit_code == 0, result.output
    spec = seen["spec"]
    assert spec.n_azimuths == n_azimuths
    assert spec.elevations == elevations


@pytest.mark.parametrize("args", [["--elevations", "0,x"], ["--elevations", "0,0"],
                                  ["--elevations", "95"], ["--poses", "7"]])
def test_cli_build_rejects_a_bad_pose_set(tmp_path: Path, args: list[str]) -> None:
    from cadnerf_cli.main import app

    result = CliRunner().invoke(app, ["library", "build", "--out", str(tmp_path / "l"), *args])
    assert result.exit_code == 2
    assert "error: --" in result.output
    assert not (tmp_path / "l").exists()
