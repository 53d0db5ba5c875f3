"""Renderer speed: Embree colour renders, ray-cast and polygon silhouettes, dataset rendering.

Run: ``.venv/bin/python -m benchmarks.bench_renderer [--quick]``.
"""

from __future__ import annotations

import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from benchmarks.harness import MESHES, section_head
from cadnerf_core.cameras.conventions import intrinsics_from_fov, library_poses
from cadnerf_core.evaluation.dataset import render_dataset
from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
from cadnerf_core.mesh.renderer import MeshRenderer, render_silhouette_polygons

SIZE = 128


def _timings(fn: Callable[[int], object], repeats: int) -> tuple[float, float]:
    """Median and 90th percentile in milliseconds of ``fn(i)`` over ``repeats`` calls."""
    fn(0)  # warm-up
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        fn(i)
        times.append((time.perf_counter() - start) * 1000.0)
    return float(np.median(times)), float(np.percentile(times, 90))


def _meshes() -> list[tuple[str, trimesh.Trimesh]]:
    """The benchmark meshes: a synthetic ~50k-triangle sphere, and real meshes when present."""
    meshes = [("uv_sphere(count=[112, 112])", trimesh.creation.uv_sphere(count=[112, 112]))]
    for name in ("os_boot/boot.obj", "spot/spot_triangulated.obj"):
        path = MESHES / name
        if path.is_file():
            meshes.append((name, load_mesh(path)))
    return [(name, normalise_mesh(mesh)) for name, mesh in meshes]


def _bench_mesh(name: str, mesh: trimesh.Trimesh, repeats: int) -> str:
    """One table row: build, colour render, ray silhouette, polygon silhouette timings."""
    K = intrinsics_from_fov(40.0, SIZE)
    poses, _ = library_poses(20, (0, 15, 30, 45, 60), 4.0)
    start = time.perf_counter()
    renderer = MeshRenderer(mesh)
    build_ms = (time.perf_counter() - start) * 1000.0
    colour = _timings(lambda i: renderer.render(K, poses[i % len(poses)], SIZE, SIZE), repeats)
    rays = _timings(lambda i: renderer.silhouette(K, poses[i % len(poses)], SIZE, SIZE), repeats)
    polygons = _timings(
        lambda i: render_silhouette_polygons(mesh, K, poses[i % len(poses)], SIZE, SIZE), repeats)
    return (f"| {name} | {len(mesh.faces):,} | {build_ms:.0f} | {colour[0]:.1f} / {colour[1]:.1f}"
            f" | {rays[0]:.1f} / {rays[1]:.1f} | {polygons[0]:.1f} / {polygons[1]:.1f} |")


def _bench_dataset(n_views: int) -> str:
    """Seconds to write a spot dataset (load, auto distance, render, PNG writing)."""
    spot = MESHES / "spot" / "spot_triangulated.obj"
    if not spot.is_file():
        return "Dataset rendering: skipped (../shared/eval absent)."
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        render_dataset(spot, Path(folder), n_views=n_views, size=SIZE, seed=0)
        seconds = time.perf_counter() - start
    return (f"`render_dataset(spot, n_views={n_views}, size={SIZE})`, from mesh file to PNGs "
            f"and transforms.json: {seconds:.2f} s.")


def run(quick: bool) -> str:
    """Markdown section with the renderer's timings."""
    repeats = 10 if quick else 50
    rows = [_bench_mesh(name, mesh, repeats) for name, mesh in _meshes()]
    return "\n".join([
        *section_head("Mesh renderer", "bench_renderer", quick,
                      f" ({repeats} views per mesh cycling through the library poses, {SIZE}x"
                      f"{SIZE} px, fov 40, distance 4; CPU "
                      f"`{platform.processor() or platform.machine()}`, shared with other "
                      "processes). Times in ms, median / p90."),
        "| mesh | triangles | Embree build | colour render | ray silhouette | polygon silhouette |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
        *rows,
        "",
        _bench_dataset(6 if quick else 12),
        "",
    ])


if __name__ == "__main__":
    from benchmarks.run import area_main

    sys.exit(area_main(run, __doc__ or "", library=False, quick_help="fewer repetitions"))
