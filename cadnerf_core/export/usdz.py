"""``mesh.usdz``: the textured mesh for iPhone and iPad AR Quick Look, written with Pixar's USD
(``usd-core``).

One ``UsdGeom.Mesh`` (points, triangles, vertex normals, one ``st`` texture coordinate per
vertex) bound to a ``UsdPreviewSurface`` (metallic 0, roughness as ``mesh.glb``'s) whose base
colour is a ``UsdUVTexture`` reading the baked PNG as sRGB. The stage is +Y up with
``metersPerUnit = 1``, the same scale a glTF viewer gives ``mesh.glb`` (glTF units are metres):
one unit is the object's bounding-sphere radius, so AR Quick Look shows it about 2 m across,
to be scaled by hand (the photos carry no scale). The package is made by
``UsdUtils.CreateNewARKitUsdzPackage``, texture inside, in a child process (``child``).

Without ``pxr`` importable the file is skipped with a logged reason; the rest of the export
does not depend on it.
"""

from __future__ import annotations

import importlib.util
import logging
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from cadnerf_core.export.child import Arrays, run_child, serve
from cadnerf_core.export.texture import ROUGHNESS, TexturedMesh
from cadnerf_core.jobfolder import MESH_TEXTURE, atomic_path

log = logging.getLogger(__name__)

ROOT = "/mesh"
"""The default prim (an Xform, kind component) holding the geometry and its material."""
TEXTURE_NAME = MESH_TEXTURE
"""The texture's name inside the package, relative to its root layer: the job folder's."""
USDZ_LIMIT_S = 60.0
"""Longest wait for USD's package; past it the job goes on without ``mesh.usdz``."""


def usd_available() -> bool:
    """Whether ``pxr`` (``usd-core``) is installed (not imported: the child uses it)."""
    return importlib.util.find_spec("pxr") is not None


def write_usd_layer(layer_path: Path, mesh: TexturedMesh, texture_name: str) -> None:
    """Write the mesh and its material as a USD layer (``.usdc`` or ``.usda``) that reads its
    texture at ``texture_name``, relative to the layer."""
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

    stage = Usd.Stage.CreateNew(str(layer_path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, ROOT)
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)

    vertices = np.ascontiguousarray(mesh.vertices, np.float32)
    faces = np.ascontiguousarray(mesh.faces, np.int32)
    normals = np.asarray(trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
                         .vertex_normals, np.float32)
    geom = UsdGeom.Mesh.Define(stage, f"{ROOT}/geometry")
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # triangles as they are
    geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)  # counter-clockwise from outside
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals)))
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    lo, hi = vertices.min(0), vertices.max(0)
    geom.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    st = UsdGeom.PrimvarsAPI(geom.GetPrim()).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(mesh.uv, np.float32)))  # v up, as USD

    material = UsdShade.Material.Define(stage, f"{ROOT}/material")
    surface = UsdShade.Shader.Define(stage, f"{ROOT}/material/surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(ROUGHNESS)
    surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(0)
    material.CreateSurfaceOutput().ConnectToSource(
        surface.CreateOutput("surface", Sdf.ValueTypeNames.Token))

    reader = UsdShade.Shader.Define(stage, f"{ROOT}/material/st_reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    st_name = material.CreateInput("frames:stPrimvarName", Sdf.ValueTypeNames.String)
    st_name.Set("st")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).ConnectToSource(st_name)

    texture = UsdShade.Shader.Define(stage, f"{ROOT}/material/base_color")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture_name))
    texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    texture.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    texture.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))

    UsdShade.MaterialBindingAPI.Apply(geom.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


def write_usdz(path: Path, mesh: TexturedMesh, texture_png: Path,
               check: Callable[[], None] | None = None) -> bool:
    """Write ``mesh.usdz`` (atomically) holding the mesh and ``texture_png``, in a child
    process (``child``: USD's thread pool can deadlock against the interpreter's lock).

    Args:
        check: called while the child works (a cancel raises, and ends the child).
    Returns:
        False, with the reason logged, where ``pxr`` is not installed or USD fails to write
        the package; True once written.
    """
    if not usd_available():
        log.warning("mesh.usdz skipped: Pixar's USD (pip package usd-core) is not installed")
        return False
    given = {"vertices": mesh.vertices, "faces": mesh.faces, "uv": mesh.uv,
             "texture_png": str(texture_png), "path": str(path)}
    done = run_child(__name__, given, USDZ_LIMIT_S, "USD (mesh.usdz)", check)
    if done is None or not bool(done["written"]):
        log.warning("mesh.usdz skipped: USD could not write the package")
        return False
    return True


def write_usdz_here(path: Path, mesh: TexturedMesh, texture_png: Path) -> bool:
    """``write_usdz``'s work, in this process (the child's)."""
    from pxr import Sdf, UsdUtils

    with tempfile.TemporaryDirectory(prefix="cadnerf-usdz-") as work:
        layer, package = Path(work) / "mesh.usdc", Path(work) / "mesh.usdz"
        shutil.copyfile(texture_png, Path(work) / TEXTURE_NAME)
        write_usd_layer(layer, mesh, TEXTURE_NAME)
        if (not UsdUtils.CreateNewARKitUsdzPackage(Sdf.AssetPath(str(layer)), str(package))
                or not package.is_file()):
            return False
        with atomic_path(path) as tmp:
            shutil.copyfile(package, tmp)
    return True


def _work(given: Arrays) -> dict[str, np.ndarray]:
    mesh = TexturedMesh(vertices=given["vertices"], faces=given["faces"], uv=given["uv"],
                        texture=np.zeros((1, 1, 3), np.uint8))  # the layer reads the PNG
    written = write_usdz_here(Path(str(given["path"])), mesh, Path(str(given["texture_png"])))
    return {"written": np.asarray(written)}


if __name__ == "__main__":
    serve(_work)
