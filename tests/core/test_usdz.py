"""mesh.usdz for AR Quick Look: the mesh, its material and texture as USD reads them back, a
package USD's validators accept, and an export that goes on without USD."""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from cadnerf_core.export import usdz
from cadnerf_core.export.mesh import write_obj
from cadnerf_core.export.texture import ROUGHNESS, TexturedMesh, bake_texture, decimate
from cadnerf_core.jobfolder import MESH_TEXTURE, MESH_USDZ, JobFolder


@pytest.fixture(scope="module")
def baked() -> TexturedMesh:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    return bake_texture(decimate(sphere, 2000),
                        lambda p, d: np.clip(p + 0.5, 0, 1).astype(np.float32), 64)


@pytest.fixture(scope="module")
def written(baked: TexturedMesh, tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("pxr", reason="Pixar's USD (usd-core) is not installed")
    folder = JobFolder(tmp_path_factory.mktemp("usdz"))
    write_obj(folder, baked)
    assert usdz.write_usdz(folder.file(MESH_USDZ), baked, folder.file(MESH_TEXTURE))
    return folder.file(MESH_USDZ)


@pytest.fixture(scope="module")
def stage(written: Path) -> Any:
    from pxr import Usd

    opened = Usd.Stage.Open(str(written))
    assert opened is not None
    return opened


def test_the_mesh_keeps_its_points_faces_and_uvs(stage: Any, baked: TexturedMesh) -> None:
    from pxr import UsdGeom

    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 1
    mesh = meshes[0]
    assert np.allclose(np.array(mesh.GetPointsAttr().Get()), baked.vertices, atol=1e-6)
    counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
    assert len(counts) == len(baked.faces) and (counts == 3).all()
    indices = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert (indices == baked.faces).all()
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.vertex
    assert np.allclose(np.array(st.Get()), baked.uv, atol=1e-6)
    assert len(mesh.GetNormalsAttr().Get()) == len(baked.vertices)


def test_y_up_in_the_glbs_units(stage: Any) -> None:
    from pxr import UsdGeom

    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == usdz.ROOT


def test_a_non_metallic_material_reads_the_texture_in_the_package(stage: Any,
                                                                 written: Path) -> None:
    from pxr import UsdGeom, UsdShade

    mesh = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    material, _ = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
    assert material
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    assert surface.GetInput("metallic").Get() == 0.0
    assert surface.GetInput("roughness").Get() == pytest.approx(ROUGHNESS)
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    texture = UsdShade.Shader(source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture"
    assert texture.GetInput("sourceColorSpace").Get() == "sRGB"
    path = texture.GetInput("file").Get().path
    with zipfile.ZipFile(written) as package:
        names = package.namelist()
    assert names[0].endswith(".usdc") and path in names and path.endswith(MESH_TEXTURE)


def test_usds_validators_find_no_error(stage: Any) -> None:
    from pxr import UsdUtils

    if hasattr(UsdUtils, "ComplianceChecker"):  # older USD: the ARKit rules
        checker = UsdUtils.ComplianceChecker(arkit=True)
        checker.CheckCompliance(stage.GetRootLayer().identifier)
        assert checker.GetErrors() == [] and checker.GetFailedChecks() == []
        return
    from pxr import UsdValidation  # USD 25.05 and later: every registered validator

    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    errors = [(e.GetName(), e.GetMessage()) for e in context.Validate(stage)
              if e.GetType() == UsdValidation.ValidationErrorType.Error]
    assert errors == []


def test_without_usd_the_file_is_skipped_with_a_reason(
        tmp_path: Path, baked: TexturedMesh, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(usdz, "usd_available", lambda: False)
    with caplog.at_level(logging.WARNING, logger=usdz.__name__):
        assert not usdz.write_usdz(tmp_path / MESH_USDZ, baked, tmp_path / MESH_TEXTURE)
    assert not (tmp_path / MESH_USDZ).exists()
    assert "usd-core" in caplog.text
