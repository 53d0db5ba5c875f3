"""Building the library folder: meshes, pre-rendered silhouettes, occupancy grids, manifest.

A build writes into a temporary sibling folder and renames it into place at the end, so an
interrupted build never leaves a half library. Models are processed in parallel by worker
processes: forked when torch is not loaded (building needs no torch), spawned otherwise.
"""

from __future__ import annotations

import hashlib
import logging
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from cadnerf_core.errors import LibraryError
from cadnerf_core.intake.crop import apply_crop, canonical_box
from cadnerf_core.library import format as fmt
from cadnerf_core.library.format import LibrarySpec, ModelEntry
from cadnerf_core.library.occupancy import compute_occupancy
from cadnerf_core.mesh.renderer import MeshRenderer
from library_data.catalog import LICENCE, MODELS, SOURCE, find_model

log = logging.getLogger(__name__)

DEFAULT_OUT = Path(__file__).resolve().parent / "build"
_PACKAGE = Path(__file__).resolve().parent
# The code a built library depends on: a change to any of these makes it stale.
_LIBRARY_SOURCES = ("parts.py", "basic.py", "furniture.py", "household.py", "gadgets.py",
                    "vehicles.py", "animals.py", "apparel.py", "tools.py", "catalog.py",
                    "build.py")
_CORE_SOURCES = ("library.py", "occupancy.py", "crop.py", "renderer.py", "meshio.py", "cameras.py")


def code_version() -> str:
    """sha256 (first 16 hex digits) of the sources that determine a built library."""
    digest = hashlib.sha256()
    core = _PACKAGE.parent / "cadnerf_core"
    paths = [_PACKAGE / name for name in _LIBRARY_SOURCES] + [core / n for n in _CORE_SOURCES]
    for path in paths:
        if path.is_file():
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def render_silhouettes(mesh: trimesh.Trimesh, spec: LibrarySpec) -> tuple[np.ndarray, np.ndarray]:
    """Canonical-crop silhouettes of a mesh from every library pose.

    Args:
        mesh: normalised mesh.
        spec: library settings (poses, camera, sizes, margin).
    Returns:
        masks [V, S, S] bool; boxes [V, 3] (x0, y0, side) of each crop in render pixels.
    Raises:
        LibraryError: when a view shows nothing of the mesh.
    """
    poses, _ = spec.poses()
    K, size = spec.K_render(), spec.render_size
    # Embree ray casting: the same pixel-centre rule as render_silhouette_polygons and, measured
    # on the parametric models and a 110k-triangle import, 2 to 10 times faster.
    renderer = MeshRenderer(mesh)
    masks = np.zeros((len(poses), spec.silhouette_size, spec.silhouette_size), dtype=bool)
    boxes = np.zeros((len(poses), 3))
    for v, c2w in enumerate(poses):
        render = renderer.silhouette(K, c2w, size, size)
        if not render.any():
            raise LibraryError(f"view {v} of the mesh is empty; is the mesh normalised?")
        box = canonical_box(render, spec.silhouette_size, spec.margin)
        masks[v] = apply_crop(render, box)
        boxes[v] = (box.x0, box.y0, box.side)
    return masks, boxes


def write_model(folder: Path, mesh: trimesh.Trimesh, spec: LibrarySpec,
                rule: str = "parity") -> dict[str, str]:
    """Write a model's folder: mesh, silhouettes, occupancy.

    Args:
        folder: the model's folder (created; must not exist).
        mesh: normalised watertight mesh.
        spec: library settings.
        rule: occupancy rule ("parity" or "winding", see ``compute_occupancy``).
    Returns:
        sha256 of each written file, by file name.
    """
    folder.mkdir(parents=True)
    plain = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    plain.export(folder / fmt.MESH_FILE, file_type="ply")
    masks, boxes = render_silhouettes(plain, spec)
    near_spec = spec.near_spec()
    near = render_silhouettes(plain, near_spec) if near_spec is not None else None
    fmt.save_npz(folder / fmt.SILHOUETTES_FILE, fmt.pack_silhouettes(masks, boxes, near))
    grid = compute_occupancy(plain, spec.grid_size, rule)
    fmt.save_npz(folder / fmt.OCCUPANCY_FILE, grid.pack())
    return {name: fmt.sha256_file(folder / name) for name in fmt.MODEL_FILES}


def _build_parametric(model_id: str, spec: LibrarySpec, root: Path) -> ModelEntry:
    """Worker: build one parametric model into ``root / model_id``."""
    model = find_model(model_id)
    mesh = model.mesh()
    checksums = write_model(root / model.id, mesh, spec)
    return ModelEntry(model.id, model.category, model.kind, SOURCE, LICENCE, len(mesh.faces),
                      checksums)


def _rebuild_imported(entry: ModelEntry, mesh_path: Path, spec: LibrarySpec,
                      root: Path) -> ModelEntry:
    """Worker: re-render a model a user added, from its stored (already watertight) mesh."""
    mesh = trimesh.load(str(mesh_path), process=False, force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    checksums = write_model(root / entry.id, mesh, spec, rule="winding")
    return ModelEntry(entry.id, entry.category, entry.kind, entry.source, entry.licence,
                      len(mesh.faces), checksums)


def imported_entries(root: Path) -> list[ModelEntry]:
    """Models of an existing library that users added (not parametric), whose mesh is intact."""
    try:
        data = fmt.read_manifest(root)
        entries = [ModelEntry(**m) for m in data["models"]]
    except (LibraryError, KeyError, TypeError):
        return []
    keep = []
    for entry in entries:
        path = root / entry.id / fmt.MESH_FILE
        if entry.source != SOURCE and path.is_file() and (
                fmt.sha256_file(path) == entry.checksums.get(fmt.MESH_FILE)):
            keep.append(entry)
    return keep


def is_current(root: Path, spec: LibrarySpec, model_ids: list[str] | None = None) -> bool:
    """Whether ``root`` holds an intact library built by this code with ``spec``."""
    try:
        data = fmt.read_manifest(root)
        if data.get("build", {}).get("code_version") != code_version():
            return False
        if fmt.LibrarySpec.from_dict(data["spec"]) != spec:
            return False
        entries = [ModelEntry(**m) for m in data["models"]]
        wanted = model_ids if model_ids is not None else [m.id for m in MODELS]
        if not set(wanted) <= {e.id for e in entries}:
            return False
        for entry in entries:
            fmt.verify_model(root, entry)
    except (LibraryError, KeyError, TypeError, ValueError):
        return False
    return True


@dataclass(frozen=True)
class BuildResult:
    """What ``build_library`` did."""

    root: Path
    """The library folder."""
    built: bool
    """False when the library was current and left alone."""
    n_models: int
    """Models in the library."""
    seconds: float
    """Wall time of the call."""


def _swap_into_place(staging: Path, out: Path) -> None:
    """Replace ``out`` by the finished ``staging`` folder (two renames, then a cleanup)."""
    if out.exists():
        if not (out / fmt.MANIFEST).is_file() and any(out.iterdir()):
            raise LibraryError(f"refusing to replace {out}: it is not a library folder")
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.rename(out, old)
        os.rename(staging, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(staging, out)


def _run_tasks(spec: LibrarySpec, staging: Path, model_ids: list[str],
               imported: list[ModelEntry], source_root: Path, jobs: int) -> list[ModelEntry]:
    """Build every model, in parallel when ``jobs`` > 1; results in input order."""
    calls: list[tuple[Callable[..., ModelEntry], tuple[Any, ...]]] = [
        (_build_parametric, (i, spec, staging)) for i in model_ids]
    calls += [(_rebuild_imported, (e, source_root / e.id / fmt.MESH_FILE, spec, staging))
              for e in imported]
    if jobs <= 1 or len(calls) <= 1:
        return [function(*args) for function, args in calls]
    # Fork is fast and safe while torch is not loaded (the `cadnerf library build` process);
    # a process that already imported torch (tests, the worker) spawns fresh interpreters.
    context = multiprocessing.get_context("spawn" if "torch" in sys.modules else "fork")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        futures = [pool.submit(function, *args) for function, args in calls]
        return [future.result() for future in futures]


def build_library(out: Path = DEFAULT_OUT, spec: LibrarySpec | None = None,
                  jobs: int | None = None, if_stale: bool = False,
                  model_ids: list[str] | None = None) -> BuildResult:
    """Build (or rebuild) the library folder atomically.

    Models users added to an existing library at ``out`` are kept and re-rendered.

    Args:
        out: library folder to create or replace.
        spec: library settings (defaults: ``LibrarySpec()``).
        jobs: worker processes (default: CPU count).
        if_stale: do nothing when ``out`` is already current for this code and spec.
        model_ids: parametric models to include (default: all of ``catalog.MODELS``).
    Returns:
        BuildResult.
    Raises:
        LibraryError: when ``out`` exists but is not a library folder.
    """
    start = time.perf_counter()
    out, spec = Path(out), spec or LibrarySpec()
    ids = model_ids if model_ids is not None else [m.id for m in MODELS]
    if if_stale and is_current(out, spec, ids):
        log.info("library at %s is current; nothing to build", out)
        return BuildResult(out, False, len(fmt.read_manifest(out)["models"]),
                           time.perf_counter() - start)
    imported = [e for e in imported_entries(out) if e.id not in ids]
    staging = out.parent / f".{out.name}.building-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        workers = max(1, jobs if jobs is not None else (os.cpu_count() or 1))
        entries = _run_tasks(spec, staging, ids, imported, out, workers)
        fmt.write_manifest(staging, spec, entries, {"code_version": code_version()})
        _swap_into_place(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    seconds = time.perf_counter() - start
    log.info("built %d models into %s in %.1f s", len(entries), out, seconds)
    return BuildResult(out, True, len(entries), seconds)

