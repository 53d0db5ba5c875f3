"""Export benchmark: time and size of what a finished job writes, at the ``preview`` preset.

One ``preview`` job (6 photos of a library model, 128 px training crops, CPU) is trained with
``run_job``; ``metrics.json`` then holds the export's own timings (views, orbit, textured mesh,
files for other tools). On the same trained model the benchmark also times, apart:

- the orbit and views at the output size ``preview`` had before it named one (128 px, 60
  frames at 30 fps, 2 s) against today's (``export.orbit_size``, ``orbit_frames`` at
  ``orbit_fps``), so the cost of the sharper, longer orbit is a difference of two runs;
- the mesh in steps: density grid and marching cubes, decimation, UV unwrap and texture bake,
  and the one colour query per vertex a vertex-coloured mesh needs instead of the bake.

Usage: ``python -m benchmarks.bench_export [--threads N] [--model ID] [--library DIR]
[--work DIR [--export-only]]`` (``--threads 2``: the two-core figure). With ``--work`` the
job folder is kept there, and a later run with the same folder resumes the job from its
checkpoints: only the export runs again, with the same trained fields. ``--export-only``
exports the last checkpoint of a job cut short (see ``measure``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import LIBRARY_DIR, run_job

MODEL = "mug"
N_PHOTOS = 6
PHOTO_SIZE = 256
BEFORE = {"orbit_size": 128, "orbit_frames": 60, "orbit_fps": 30}
"""The preview preset's orbit before it named an output size (the training size, 2 s)."""


def write_photos(job_dir: Path, library: Any, model_id: str) -> None:
    """``N_PHOTOS`` RGBA renders of a library model walking round it, and the preview config."""
    from PIL import Image

    from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
    from cadnerf_core.config import resolve_config
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.mesh.renderer import MeshRenderer

    renderer = MeshRenderer(library.mesh(model_id))
    K = intrinsics_from_fov(40.0, PHOTO_SIZE)
    folder = JobFolder(job_dir)
    for i in range(N_PHOTOS):
        view = renderer.render(K, orbit_pose(15.0 + 45.0 * i, 20.0, 4.0), PHOTO_SIZE, PHOTO_SIZE)
        rgba = np.dstack([(view.rgb * 255).astype(np.uint8), view.mask.astype(np.uint8) * 255])
        Image.fromarray(rgba, "RGBA").save(folder.new_photo_path(i, "photo", "png"))
    folder.write_config(resolve_config("preview"))


def timed(fn: Any, *args: Any) -> tuple[Any, tuple[float, float]]:
    """``fn(*args)`` and its (wall, CPU) seconds. On a machine others load, the process's CPU
    time stays near what the step costs alone, where wall time does not."""
    start, cpu = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, (time.perf_counter() - start, time.process_time() - cpu)


def time_orbit_and_views(job_dir: Path, model: Any, data: Any, export: dict[str, Any],
                         out: Path) -> tuple[tuple[float, float], tuple[float, float]]:
    """(wall, CPU) seconds of ``render_views`` and ``render_orbit`` with ``export`` settings,
    into ``out``."""
    from cadnerf_core.export.renders import render_orbit, render_views
    from cadnerf_core.progress import Progress

    config = model.state.config
    model.state.config = config.model_copy(
        update={"export": config.export.model_copy(update=export)})
    out.mkdir(parents=True, exist_ok=True)  # the writers only fill an existing job folder
    try:
        _, views_s = timed(render_views, out, model, data, Progress(), 1)
        _, orbit_s = timed(render_orbit, out, model, data, Progress(), 0, 1)
    finally:
        model.state.config = config
    return views_s, orbit_s


def time_mesh_steps(model: Any) -> dict[str, Any]:
    """Seconds of each step of the textured mesh, and of a vertex-coloured mesh's colour query."""
    from cadnerf_core.export.mesh import drop_small_pieces, extract_mesh, occupancy_grid
    from cadnerf_core.export.texture import bake_texture, decimate

    ecfg, bound = model.state.config.export, model.state.config.render.bound
    values, grid_s = timed(occupancy_grid, model)
    whole = extract_mesh(values, bound, ecfg.mesh_level)
    surface, drop_s = timed(drop_small_pieces, whole)
    normals = np.asarray(surface.vertex_normals, np.float32)
    _, vertex_colours_s = timed(model.colors, np.asarray(surface.vertices, np.float32), -normals)
    small, decimate_s = timed(decimate, surface, ecfg.mesh_faces)
    baked, bake_s = timed(bake_texture, small, model.colors, ecfg.texture_size)
    return {"grid_s": grid_s, "drop_s": drop_s, "vertex_colours_s": vertex_colours_s,
            "decimate_s": decimate_s, "bake_s": bake_s,
            **time_children(small, baked, ecfg.texture_size),
            "faces": len(small.faces), "faces_before": len(surface.faces)}


def time_children(small: Any, baked: Any, size: int) -> dict[str, float]:
    """Wall seconds of the export's native steps in their child processes (as a job runs them)
    and in this process (USD's first call here pays its start-up, as a worker's first job
    would)."""
    from PIL import Image

    from cadnerf_core.export import atlas, usdz
    from cadnerf_core.export.texture import PADDING

    vertices, faces = np.asarray(small.vertices), np.asarray(small.faces)
    out: dict[str, float] = {}
    _, (out["xatlas_child_s"], _) = timed(atlas.unwrap, vertices, faces, size, PADDING)
    _, (out["xatlas_here_s"], _) = timed(atlas.xatlas_atlas, vertices, faces, size, PADDING)
    with tempfile.TemporaryDirectory(prefix="bench_usdz_") as folder:
        texture = Path(folder) / "mesh_texture.png"
        Image.fromarray(baked.texture).save(texture)
        _, (out["usdz_child_s"], _) = timed(usdz.write_usdz, Path(folder) / "a.usdz", baked,
                                            texture)
        _, (out["usdz_here_s"], _) = timed(usdz.write_usdz_here, Path(folder) / "b.usdz",
                                           baked, texture)
    return out


def sizes(job_dir: Path) -> dict[str, int]:
    """Bytes of the new outputs (``mesh.usdz`` where it was written)."""
    from cadnerf_core.jobfolder import (
        BUNDLE,
        COLMAP_POINTS,
        MESH,
        MESH_OBJ,
        MESH_TEXTURE,
        MESH_USDZ,
        ORBIT_GIF,
        ORBIT_VIDEO,
        JobFolder,
    )

    folder = JobFolder(job_dir)
    return {name: folder.file(name).stat().st_size for name in
            (ORBIT_VIDEO, ORBIT_GIF, MESH, MESH_OBJ, MESH_TEXTURE, MESH_USDZ, COLMAP_POINTS,
             BUNDLE) if folder.file(name).is_file()}


def measure(library_dir: Path, model_id: str, work: Path,
            export_only: bool = False) -> dict[str, Any]:
    """Train one preview job and time its export. Returns the figures.

    Args:
        export_only: export the job's last checkpoint (``--work`` with a job cut short) instead
            of finishing its training: the renders then show unfinished colours, but their
            cost (the density's samples, the output sizes) is what the benchmark measures.
    """
    from cadnerf_core.config import resolve_config
    from cadnerf_core.export.artifacts import export_job
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.library.format import load_library
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.pipeline import read_job_config, run_intake, training_data
    from cadnerf_core.progress import Progress

    library = load_library(library_dir)
    job_dir = work / "job"
    if not JobFolder(job_dir).has_config():
        write_photos(job_dir, library, model_id)
    if not export_only:
        run_job(job_dir, library)
    model = TrainedModel.load(job_dir, "cpu")
    config = read_job_config(job_dir)
    intake = run_intake(job_dir, library, config, Progress(), None)
    data = training_data(intake, config, library.spec.margin, model.state.device)
    if export_only:  # the job may predate the preset's export settings: today's apply
        export = resolve_config("preview").export
        model.state.config = model.state.config.model_copy(update={"export": export})
        config = config.model_copy(update={"export": export})
        export_job(job_dir, model, intake.retrieval, intake.photos, data, Progress())
    metrics = JobFolder(job_dir).read_metrics() or {}
    now = {k: getattr(config.export, k) for k in BEFORE}
    before_views, before_orbit = time_orbit_and_views(job_dir, model, data, BEFORE, work / "a")
    after_views, after_orbit = time_orbit_and_views(job_dir, model, data, now, work / "b")
    return {"timings": metrics.get("timings_s", {}), "now": now,
            "views_before_s": before_views, "views_after_s": after_views,
            "orbit_before_s": before_orbit, "orbit_after_s": after_orbit,
            "mesh": time_mesh_steps(model), "sizes": sizes(job_dir),
            "texture_size": config.export.texture_size, "export_only": export_only,
            "resumed_after_phase": int(model.extra.get("resumed_after_phase", 3)
                                       if not export_only else _last_phase(job_dir))}


def _last_phase(job_dir: Path) -> int:
    """The last phase checkpointed in a job folder (0: none)."""
    from cadnerf_core.nerf.checkpoint import last_checkpoint

    found = last_checkpoint(job_dir)
    return 0 if found is None else found[0]


def _pair(seconds: tuple[float, float]) -> str:
    """``wall s (CPU s)``."""
    return f"{seconds[0]:.1f} s ({seconds[1]:.1f})"


def _sub(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    return a[0] - b[0], a[1] - b[1]


def report(f: dict[str, Any], threads: int) -> str:
    """The markdown section."""
    t, m, now = f["timings"], f["mesh"], f["now"]
    trained = ", ".join(f"{k.removesuffix('_s')} {t[k]:.0f} s" for k in
                        ("phase1_s", "phase2_s", "phase3_s") if k in t)
    if f["resumed_after_phase"] < 3 and f["export_only"]:
        trained = (f"exported after phase {f['resumed_after_phase']} of 3 (`--export-only`: "
                   "colours unfinished, render cost that of the density)")
    orbit = _sub(f["orbit_after_s"], f["orbit_before_s"])
    views = _sub(f["views_after_s"], f["views_before_s"])
    baked = (m["decimate_s"][0] + m["bake_s"][0], m["decimate_s"][1] + m["bake_s"][1])
    texture = _sub(baked, m["vertex_colours_s"])
    goal = (orbit[0] + texture[0], orbit[1] + texture[1])  # what the goal is set on
    total = (goal[0] + views[0], goal[1] + views[1])
    mib = {k: v / 2**20 for k, v in f["sizes"].items()}
    return "\n".join([
        "## Export (preview)", "",
        f"One `preview` job ({N_PHOTOS} photos of `{MODEL}`, CPU, torch threads: {threads}; "
        f"training: {trained or 'resumed'}); its export took {t.get('export_s', 0):.1f} s: "
        f"views {t.get('views_s', 0):.1f} s, orbit {t.get('orbit_s', 0):.1f} s, textured mesh "
        f"{t.get('mesh_s', 0):.1f} s, files for other tools and results.zip "
        f"{t.get('bundle_s', 0):.1f} s. Each part below: wall seconds (process CPU seconds, "
        "what it costs on an idle machine's cores together).", "",
        "| part | before | now | added |", "| --- | --- | --- | --- |",
        f"| orbit ({BEFORE['orbit_size']} px, {BEFORE['orbit_frames']} frames -> "
        f"{now['orbit_size']} px, {now['orbit_frames']} frames at {now['orbit_fps']} fps) | "
        f"{_pair(f['orbit_before_s'])} | {_pair(f['orbit_after_s'])} | {_pair(orbit)} |",
        f"| views/ (at {now['orbit_size']} px) | {_pair(f['views_before_s'])} | "
        f"{_pair(f['views_after_s'])} | {_pair(views)} |",
        f"| mesh colour: per-vertex query -> decimate ({m['faces_before']} -> {m['faces']} "
        f"faces) + unwrap + {f['texture_size']} px bake | {_pair(m['vertex_colours_s'])} | "
        f"{_pair(baked)} | {_pair(texture)} |",
        f"| texture bake + larger orbit (goal: under 30 s) | | | {_pair(goal)} |",
        f"| total added | | | {_pair(total)} |", "",
        f"Native steps in child processes (xatlas and USD hold the interpreter, which would "
        f"silence the worker's heartbeat): xatlas {m['xatlas_child_s']:.2f} s in its child, "
        f"{m['xatlas_here_s']:.2f} s in the job's process; `mesh.usdz` {m['usdz_child_s']:.2f} s "
        f"in its child, {m['usdz_here_s']:.2f} s in the job's process on its first USD call. "
        f"Dropping the surface's specks before decimation: {_pair(m['drop_s'])}.", "",
        "Sizes: " + ", ".join(f"`{k}` {v:.2f} MiB" for k, v in mib.items()) + ".", ""])


def run(quick: bool = False, threads: int | None = 2, library_dir: Path = LIBRARY_DIR,
        model_id: str = MODEL, work: Path | None = None, export_only: bool = False) -> str:
    """The markdown section (``quick`` changes nothing: one preview job is the smallest)."""
    import torch

    if threads:
        torch.set_num_threads(threads)
    if work is not None:
        figures = measure(library_dir, model_id, work, export_only)
    else:
        with tempfile.TemporaryDirectory(prefix="bench_export_") as folder:
            figures = measure(library_dir, model_id, Path(folder))
    return report(figures, torch.get_num_threads())


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    parser = argparse.ArgumentParser(description="CAD-NeRF export benchmark")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--model", default=MODEL, help="library model photographed")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    parser.add_argument("--work", type=Path, default=None,
                        help="keep the job folder here (a second run resumes it)")
    parser.add_argument("--export-only", action="store_true",
                        help="with --work: export the last checkpoint, training left unfinished")
    args = parser.parse_args(argv)
    sys.stdout.write(run(False, args.threads, args.library, args.model, args.work,
                         args.export_only))
    return 0


if __name__ == "__main__":
    sys.exit(main())
