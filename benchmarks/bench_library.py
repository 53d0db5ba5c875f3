"""CAD mini library: build time, load time, watertightness, occupancy accuracy, imports.

Run: ``.venv/bin/python -m benchmarks.bench_library [--quick]`` (quick: occupancy agreement
on 8 models instead of all; everything else is the same).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.harness import LIBRARY_DIR as SHIPPED
from benchmarks.harness import MESHES, ROOT, section_head
from cadnerf_core.errors import LibraryError
from cadnerf_core.library.format import MANIFEST, load_library, read_manifest

IMPORTS = ("teapot/teapot.obj", "fsu_big_dodge/big_dodge.ply", "Duck/Duck.glb")
QUICK_MODELS = ("chair_office", "mug", "bookshelf", "bicycle", "car_suv", "lamp", "cylinder",
                "sphere")
CLI = [sys.executable, "-m", "cadnerf_cli.main", "library"]


def _timed(command: list[str]) -> tuple[float, str]:
    """Wall seconds and output of a command (raises if it fails)."""
    start = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=900,
                          check=False)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed: {done.stderr.strip()[-500:]}")
    return seconds, done.stdout.strip()


def _load_times(root: Path) -> tuple[float, float]:
    """Seconds to load the library and unpack its silhouettes: in a fresh interpreter (imports
    included), and the median of 5 loads once the imports are done (as in the worker)."""
    script = (
        "import time; t0 = time.perf_counter()\n"
        "from cadnerf_core.library.format import load_library\n"
        f"lib = load_library({str(root)!r}); lib.silhouettes\n"
        "first = time.perf_counter() - t0; times = []\n"
        "for _ in range(5):\n"
        "    t = time.perf_counter()\n"
        f"    load_library({str(root)!r}).silhouettes\n"
        "    times.append(time.perf_counter() - t)\n"
        "print(first, sorted(times)[2])\n")
    _, out = _timed([sys.executable, "-c", script])
    first, warm = (float(x) for x in out.split())
    return first, warm


def _agreement(root: Path, model_ids: list[str]) -> list[tuple[str, float, bool]]:
    """Per model: agreement of the stored grid with ``Trimesh.contains`` on 100k points, and
    whether the stored mesh is watertight."""
    library = load_library(root)
    rng = np.random.default_rng(0)
    rows = []
    for model_id in model_ids:
        mesh = library.mesh(model_id)
        points = rng.uniform(-1.0, 1.0, (100_000, 3))
        agree = float(np.mean(library.occupancy(model_id).query(points) == mesh.contains(points)))
        rows.append((model_id, agree, bool(mesh.is_watertight)))
    return rows


def _import_id(relative: str) -> str:
    """Library id of an imported eval mesh: prefixed, as the shipped library has a teapot."""
    return f"imported_{Path(relative).stem.lower()}"


def _imports(root: Path) -> list[str]:
    """Table rows for ``cadnerf library add`` on real meshes of three formats."""
    rows, added = [], []
    for relative in IMPORTS:
        path = MESHES / relative
        if not path.is_file():
            rows.append(f"| {relative} | skipped (../shared/eval absent) | | |")
            continue
        model_id = _import_id(relative)
        seconds, out = _timed([*CLI, "add", str(path), "--category", "import", "--id", model_id,
                               "--library", str(root)])
        rows.append(f"| {relative} | {seconds:.1f} | `{out}` |")
        added.append(len(rows) - 1)
    library = load_library(root)
    for row, relative in zip(added, [r for r in IMPORTS if (MESHES / r).is_file()],
                             strict=True):
        watertight = library.mesh(_import_id(relative)).is_watertight
        rows[row] += f" {'yes' if watertight else 'NO'} |"
    return rows


def _determinism(root: Path) -> str:
    """Whether the shipped library (same code) has the same checksums as this build."""
    try:
        shipped = read_manifest(SHIPPED)
    except LibraryError:
        return "Determinism: no shipped library at library_data/build to compare with."
    built = read_manifest(root)
    if shipped["build"] != built["build"]:
        return "Determinism: the shipped library was built by other code; not compared."
    ours = {m["id"]: m["checksums"] for m in built["models"]}
    same = sum(ours.get(m["id"]) == m["checksums"] for m in shipped["models"]
               if m["source"].startswith("parametric"))
    return (f"Determinism: {same}/{len(ours)} models byte-identical (sha256 of mesh, "
            "silhouettes and occupancy) to library_data/build, built in another process.")


def run(quick: bool) -> str:
    """Markdown section with the library's figures."""
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) / "library"
        build_s, build_out = _timed([*CLI, "build", "--out", str(out), "--jobs", "2"])
        first, warm = _load_times(out)
        data = json.loads((out / MANIFEST).read_text())
        ids = [m["id"] for m in data["models"]]
        agreement = _agreement(out, [i for i in ids if i in QUICK_MODELS] if quick else ids)
        watertight = sum(w for _, _, w in agreement)
        determinism = _determinism(out)
        import_root = Path(scratch) / "imports"
        shutil.copytree(out, import_root)
        import_rows = _imports(import_root)
    scores = np.array([a for _, a, _ in agreement])
    worst = sorted(agreement, key=lambda r: r[1])[:3]
    objects = sum(m["kind"] == "object" for m in data["models"])
    categories = len({m["category"] for m in data["models"] if m["kind"] == "object"})
    spec = data["spec"]
    views = spec["n_azimuths"] * len(spec["elevations"])
    return "\n".join([
        *section_head("CAD mini library", "bench_library", quick,
                      f". {len(ids)} models ({objects} objects in {categories} categories, "
                      f"{len(ids) - objects} basic shapes), {views} poses each, "
                      f"{spec['grid_size']}^3 occupancy. 2 CPU cores shared with other work."),
        "| figure | value | target |",
        "| --- | ---: | ---: |",
        f"| `cadnerf library build --jobs 2` (fresh process) | {build_s:.1f} s | < 180 s |",
        f"| load + unpack silhouettes, fresh interpreter (imports incl. torch) | {first:.2f} s | |",
        f"| load + unpack silhouettes, imports done (median of 5) | {warm:.3f} s | < 1 s |",
        f"| watertight meshes (of the {len(agreement)} checked) | {watertight} | all |",
        f"| occupancy vs `Trimesh.contains`, 100k points, {len(agreement)} models: min / mean "
        f"| {scores.min():.4f} / {scores.mean():.4f} | >= 0.995 |",
        f"| models >= 0.995 | {int(np.sum(scores >= 0.995))}/{len(scores)} | all |",
        "",
        "Lowest agreement: " + ", ".join(f"{i} {a:.4f}" for i, a, _ in worst) + ".",
        "",
        f"Build output: `{build_out}`.",
        "",
        determinism,
        "",
        "`cadnerf library add FILE --category import` on real meshes (fresh process each; "
        f"normalise, make watertight, {views} renders, occupancy):",
        "",
        "| file | seconds | output | watertight |",
        "| --- | ---: | --- | --- |",
        *import_rows,
        "",
    ])


if __name__ == "__main__":
    from benchmarks.run import area_main

    sys.exit(area_main(run, __doc__ or "", library=False, quick_help="occupancy check on 8 models"))
