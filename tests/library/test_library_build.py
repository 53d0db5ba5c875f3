"""Building the library: --if-stale, atomic replacement, refusal to clobber other folders."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import library_data.build as build_module
from cadnerf_core.errors import LibraryError
from cadnerf_core.library.format import MANIFEST, LibrarySpec, read_manifest
from library_data.build import build_library, code_version, is_current

SPEC = LibrarySpec(n_azimuths=8, elevations=(0.0, 30.0), silhouette_size=32, grid_size=32)
MODELS = ["chair_wood", "mug", "cuboid_slab"]  # the tiny library's models (tests/conftest.py)


@pytest.fixture()
def library_copy(tiny_library_dir: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(tiny_library_dir, tmp_path / "library"))


def test_if_stale_leaves_a_current_library_alone(library_copy: Path) -> None:
    assert is_current(library_copy, SPEC, MODELS)
    before = (library_copy / MANIFEST).read_bytes()
    result = build_library(library_copy, SPEC, jobs=1, if_stale=True, model_ids=MODELS)
    assert not result.built and result.n_models == 3
    assert (library_copy / MANIFEST).read_bytes() == before
    assert read_manifest(library_copy)["build"]["code_version"] == code_version()


def test_staleness(library_copy: Path) -> None:
    assert not is_current(library_copy, LibrarySpec(), MODELS)  # another spec
    assert not is_current(library_copy, SPEC, [*MODELS, "sphere"])  # a model missing
    (library_copy / "mug" / "mesh.ply").write_bytes(b"damaged")
    assert not is_current(library_copy, SPEC, MODELS)
    assert not is_current(library_copy / "nowhere", SPEC, MODELS)


def test_rebuild_is_byte_identical(library_copy: Path, tmp_path: Path) -> None:
    result = build_library(tmp_path / "again", SPEC, jobs=2, model_ids=MODELS)
    assert result.built and result.n_models == 3
    assert (tmp_path / "again" / MANIFEST).read_bytes() == (library_copy / MANIFEST).read_bytes()


def test_interrupted_build_keeps_the_old_library(library_copy: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    before = (library_copy / MANIFEST).read_bytes()
    real = build_module._build_parametric

    def fail_on_mug(model_id: str, spec: LibrarySpec, root: Path):  # type: ignore[no-untyped-def]
        if model_id == "mug":
            raise KeyboardInterrupt
        return real(model_id, spec, root)

    monkeypatch.setattr(build_module, "_build_parametric", fail_on_mug)
    with pytest.raises(KeyboardInterrupt):
        build_library(library_copy, SPEC, jobs=1, model_ids=MODELS)
    assert (library_copy / MANIFEST).read_bytes() == before
    assert sorted(p.name for p in library_copy.parent.iterdir()) == ["library"]


def test_refuses_to_replace_a_folder_that_is_not_a_library(tmp_path: Path) -> None:
    (tmp_path / "precious").mkdir()
    (tmp_path / "precious" / "notes.txt").write_text("keep me")
    with pytest.raises(LibraryError, match="not a library"):
        build_library(tmp_path / "precious", SPEC, jobs=1, model_ids=["cuboid_slab"])
    assert (tmp_path / "precious" / "notes.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precious"]
