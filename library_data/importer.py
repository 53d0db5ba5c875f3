"""Adding users' CAD files to a built library, and removing models from it.

An imported mesh is normalised (bbox centre at 0, max |v| = 1, +Y up) and made watertight: a
closed, consistently oriented mesh is kept as it is (its occupancy uses the winding number, so
overlapping closed parts count as their union); anything else is rebuilt from a solid voxel
grid with marching cubes. The model is written into a hidden staging folder and renamed into
place, and the manifest is replaced atomically, so a failure leaves the library untouched.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh
from scipy import ndimage
from skimage.measure import marching_cubes

from cadnerf_core.errors import InputError, MeshError
from cadnerf_core.library import format as fmt
from cadnerf_core.library.format import LibrarySpec, ModelEntry
from cadnerf_core.mesh.meshio import SUPPORTED_EXTENSIONS, load_mesh, normalise_mesh
from library_data.build import write_model

log = logging.getLogger(__name__)

IMPORT_LICENCE = "unknown (user import)"
_ID_PATTERN = re.compile(r"^[a-z0-9][a-z0-9_-]{0,63}$")
_SHAPENET_PATHS = ("models/model_normalized.obj", "model_normalized.obj")
_MAX_GROWTH = 4  # voxels the shell may grow to seal holes (holes up to about twice as wide)
_PAD = _MAX_GROWTH + 2  # empty voxels around the grid: growth and marching cubes stay inside


def resolve_source(path: Path) -> Path:
    """The mesh file to import: ``path`` itself, or the mesh inside a ShapeNet model folder.

    Raises:
        MeshError: naming the folder when it holds no single mesh file.
    """
    path = Path(path)
    if not path.is_dir():
        return path
    for relative in _SHAPENET_PATHS:
        if (path / relative).is_file():
            return path / relative
    meshes = sorted(p for p in path.iterdir() if p.suffix.lower() in SUPPORTED_EXTENSIONS)
    if len(meshes) != 1:
        raise MeshError(f"expected one mesh file (or {_SHAPENET_PATHS[0]}) in the folder, "
                        f"found {len(meshes)}", item=str(path))
    return meshes[0]


def _fill_shell(shell: np.ndarray) -> np.ndarray:
    """Solid voxels of a surface's voxel shell, sealing holes up to a few voxels wide.

    The shell is dilated k = 1, 2, 3, 4 times until filling the enclosed space adds a volume of
    at least a quarter of the shell's (a closed surface encloses something); the fill is then
    eroded k times, which returns the surface to where it was.

    Args:
        shell: [X, Y, Z] bool, with at least ``_PAD`` empty voxels on every side.
    Returns:
        [X, Y, Z] bool solid (at least the shell itself).
    """
    structure = ndimage.generate_binary_structure(3, 1)
    filled, grown, k = shell, shell, 0
    for k in range(1, _MAX_GROWTH + 1):
        grown = ndimage.binary_dilation(shell, structure, iterations=k)
        filled = ndimage.binary_fill_holes(grown)
        if filled.sum() - grown.sum() > 0.25 * shell.sum():
            break
    return ndimage.binary_erosion(filled, structure, iterations=k) | shell


def reconstruct_watertight(mesh: trimesh.Trimesh, grid_size: int = 128) -> trimesh.Trimesh:
    """A closed surface around an open or broken mesh, by voxelising it.

    Surface samples mark a shell of voxels; the shell is grown until it seals the surface's gaps,
    the enclosed space is filled and the growth taken back (``_fill_shell``); marching cubes on
    the lightly smoothed solid gives the mesh.

    Args:
        mesh: normalised mesh (inside the unit sphere).
        grid_size: voxels across [-1, 1].
    Returns:
        Watertight mesh, normalised again.
    Raises:
        MeshError: when the result is not watertight.
    """
    pitch = 2.0 / grid_size
    count = int(min(2_000_000, max(10_000, mesh.area / (0.4 * pitch) ** 2)))
    samples, _ = trimesh.sample.sample_surface(mesh, count, seed=0)
    points = np.concatenate([samples, mesh.vertices])
    index = np.clip(np.floor((points + 1.0) / pitch).astype(np.int64), 0, grid_size - 1) + _PAD
    shell = np.zeros((grid_size + 2 * _PAD,) * 3, dtype=bool)
    shell[index[:, 0], index[:, 1], index[:, 2]] = True
    solid = _fill_shell(shell)
    volume = ndimage.gaussian_filter(solid.astype(np.float32), sigma=0.7)
    vertices, faces, _, _ = marching_cubes(volume, level=0.5)
    vertices = -1.0 + (vertices - _PAD + 0.5) * pitch
    result = trimesh.Trimesh(vertices, faces, process=True)
    if result.volume < 0:
        result.invert()
    if not result.is_watertight:
        raise MeshError("could not make the mesh watertight")
    return normalise_mesh(result)


def _fix_modelnet_header(path: Path, scratch: Path) -> Path:
    """ModelNet's OFF files often glue the counts to the keyword ("OFF490 518 0"): a copy with
    the header split in ``scratch``, or ``path`` itself when it needs no fix."""
    if path.suffix.lower() != ".off" or not path.is_file():
        return path
    with open(path, "rb") as handle:
        first = handle.readline()
    if not re.match(rb"^OFF\s*\d", first) or first.strip() == b"OFF":
        return path
    fixed = scratch / path.name
    fixed.write_bytes(b"OFF\n" + first[3:].lstrip() + path.read_bytes()[len(first):])
    return fixed


def prepare_mesh(path: Path, up: Literal["y", "z"] = "y",
                 grid_size: int = 128) -> tuple[trimesh.Trimesh, str]:
    """Load, normalise and make watertight a mesh file.

    Args:
        path: mesh file (OBJ, OFF, PLY, STL, GLB) or ShapeNet model folder.
        up: the file's up axis.
        grid_size: voxel resolution when the mesh must be rebuilt.
    Returns:
        The mesh (geometry only) and the occupancy rule to use with it.
    Raises:
        MeshError: naming the file when it cannot be read or used.
    """
    source = resolve_source(path)
    with tempfile.TemporaryDirectory() as scratch:
        loaded = normalise_mesh(load_mesh(_fix_modelnet_header(source, Path(scratch))), up)
    mesh = trimesh.Trimesh(loaded.vertices, loaded.faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    if len(mesh.faces) == 0:
        raise MeshError("the mesh has no non-degenerate triangles", item=str(source))
    if mesh.is_watertight and mesh.is_winding_consistent:
        if mesh.volume < 0:
            mesh.invert()
        return mesh, "winding"
    log.info("%s is not watertight: rebuilding it from a %d^3 voxel grid", source.name, grid_size)
    return reconstruct_watertight(mesh, grid_size), "parity"


def slug(text: str) -> str:
    """A model id made from a file or folder name."""
    cleaned = re.sub(r"[^a-z0-9_-]+", "_", text.lower()).strip("_-")
    return cleaned[:64] or "model"


def _load_entries(root: Path) -> tuple[dict, LibrarySpec, list[ModelEntry]]:
    """Manifest data, spec and models of a library folder (LibraryError when there is none)."""
    data = fmt.read_manifest(root)
    return data, LibrarySpec.from_dict(data["spec"]), [ModelEntry(**m) for m in data["models"]]


def add_model(root: Path, path: Path, category: str, model_id: str | None = None,
              up: Literal["y", "z"] = "y", licence: str = IMPORT_LICENCE) -> ModelEntry:
    """Import a mesh into the library at ``root`` and list it in the manifest.

    Args:
        root: built library folder.
        path: mesh file, or a ShapeNet model folder.
        category: object category, e.g. "chair".
        model_id: id (default: from the file or folder name).
        up: the file's up axis ("y" or "z").
        licence: licence of the geometry, kept in the manifest.
    Returns:
        The new model's entry.
    Raises:
        InputError: for a bad id or category, or an id already in use.
        MeshError: naming the file when it cannot be read or made usable.
        LibraryError: when ``root`` holds no library.
    """
    root, path = Path(root), Path(path)
    data, spec, entries = _load_entries(root)
    name = model_id or slug(path.stem if path.is_file() else path.name)
    if not _ID_PATTERN.match(name):
        raise InputError("ids use lowercase letters, digits, '_' and '-' (at most 64)", item=name)
    if not category.strip():
        raise InputError("the category must not be empty", item="--category")
    if any(e.id == name for e in entries):
        raise InputError("a model with this id is already in the library", item=name,
                         hint="choose another --id or remove it first")
    mesh, rule = prepare_mesh(path, up, spec.grid_size)
    staging = root / f".{name}.adding-{os.getpid()}"
    target = root / name
    try:
        checksums = write_model(staging, mesh, spec, rule)
        os.rename(staging, target)
        entry = ModelEntry(name, category.strip(), "object", f"import:{resolve_source(path).name}",
                           licence, len(mesh.faces), checksums)
        fmt.write_manifest(root, spec, [*entries, entry], data.get("build", {}))
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        shutil.rmtree(target, ignore_errors=True)
        raise
    log.info("added %s (%s, %d triangles) to %s", name, category, len(mesh.faces), root)
    return entry


def remove_model(root: Path, model_id: str) -> None:
    """Remove a model from the library: manifest first (atomically), then its folder.

    Raises:
        InputError: when the library has no such model.
    """
    root = Path(root)
    data, spec, entries = _load_entries(root)
    kept = [e for e in entries if e.id != model_id]
    if len(kept) == len(entries):
        raise InputError("no such model in the library", item=model_id,
                         hint="see `cadnerf library list`")
    fmt.write_manifest(root, spec, kept, data.get("build", {}))
    shutil.rmtree(root / model_id, ignore_errors=True)
