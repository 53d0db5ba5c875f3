"""The benchmarks' shared harness: where things are, the one walk renderer, the one job runner.

Every benchmark that needs one of these imports it from here:

- the places and fixed settings (``ROOT``, ``EVAL_ROOT``, ``LIBRARY_DIR``, ``PRESET``, the
  walks' ``SIZE``/``SEED``/``VIEWS``/``TEST_VIEWS``, ``QUICK_MESHES`` and ``QUICK_OVERRIDES``);
- ``render_walk``: a synthetic walk round one mesh of ``../shared/eval/meshes`` (``load_walk``
  loads it, ``fov_walk`` names its folder by field of view and keeps it; the textured phone
  walks of ``benchmarks.textured_walks`` are another picture of a walk, on a floor);
- ``run_job``: one whole job on photos, timed, with what it wrote read back, and
  ``evaluate_walk``: one whole job on a rendered walk, scored on its held-out views
  (``evaluation.evaluate.evaluate_dataset``), the mesh's look-alikes left out of the library
  unless the protocol keeps them;
- ``rotation_error``: the score of a retrieval's cameras against the walk's;
- ``section_head``: an area's heading and the command behind it.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from benchmarks.lookalikes import Protocol, exclude_overrides

if TYPE_CHECKING:
    from cadnerf_core.evaluation.dataset import Dataset
    from cadnerf_core.evaluation.evaluate import EvalReport
    from cadnerf_core.jobresult import JobResult
    from cadnerf_core.library.format import Library
    from cadnerf_core.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EVAL_ROOT = ROOT / ".." / "shared" / "eval"
MESHES = EVAL_ROOT / "meshes"
CAPTURES = EVAL_ROOT / "captures"
PHOTOS = EVAL_ROOT / "photos"  # real photo sets
LIBRARY_DIR = ROOT / "library_data" / "build"
WORK_ROOT = ROOT / "out"
PRESET = "preview"
DEVICE = "cpu"
SIZE = 128  # side of a rendered walk's photos
SEED = 0
VIEWS = 6  # photos a walk
TEST_VIEWS = 12  # held-out views a scored walk
LIBRARY_FOV = 40.0  # the library's own horizontal field of view
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".off", ".stl")
# Meshes whose files are Z-up (checked by rendering them); the others are Y-up.
Z_UP = frozenset({"YcbMustardBottle", "YcbPowerDrill", "ycb_mug", "fuze", "os_plane"})
QUICK_MESHES = ("armchair", "CesiumMilkTruck", "ycb_mug")
# QUICK: the preview networks on 48 px crops with short phases (ours, the paper is silent),
# held-out views scored at 64 px: every job must take seconds for the run to fit in minutes.
QUICK_OVERRIDES: dict[str, Any] = {
    "image_size": 48, "phase1.steps": 60, "phase1.batch_points": 1024,
    "phase2.steps": 60, "phase2.rays": 256, "phase3.steps": 120, "phase3.rays": 256,
    "render.samples_per_ray": 24, "export.orbit_frames": 2, "export.orbit_size": 32,
    "export.novel_views": 0, "export.mesh_resolution": 16,
}


ABSENT = "Not run: `../shared/eval` is absent."


def section_head(title: str, module: str, quick: bool, note: str = "") -> list[str]:
    """The first lines of an area's markdown section: its heading and the command behind it
    (``module``: e.g. ``bench_order``), ``note`` run on after the command."""
    return [f"## {title}", "",
            f"Command: `python -m benchmarks.{module}{' --quick' if quick else ''}`{note}", ""]


def eval_meshes() -> tuple[str, ...]:
    """The names of the evaluation set's meshes, sorted (none without ``../shared/eval``)."""
    return tuple(sorted(p.name for p in MESHES.iterdir() if p.is_dir())) \
        if MESHES.is_dir() else ()


def mesh_file(folder: Path) -> Path:
    """The mesh file in one of the evaluation set's mesh folders."""
    found = sorted(p for p in folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if not found:
        raise FileNotFoundError(f"no mesh file in {folder}")
    return found[0]


def mesh_up(name: str) -> Literal["y", "z"]:
    """The up axis of the evaluation mesh ``name``'s file."""
    return "z" if name in Z_UP else "y"


def render_walk(name: str, folder: Path, views: int = VIEWS, *, size: int = SIZE,
                seed: int = SEED, once: bool = False, **options: Any) -> Path:
    """Render a walk of ``views`` photos round the evaluation mesh ``name`` into ``folder``.

    Args:
        name: a folder of ``../shared/eval/meshes``.
        folder: the dataset folder to write.
        views, size, seed: photos, their side in pixels, the seed of every random choice.
        once: keep a walk already rendered there (one with its test split, where asked for).
        options: ``render_dataset``'s other arguments (``direction``, ``fov_deg``,
            ``test_views``, ``elevation_range``, ``distance``).
    Returns:
        ``folder``.
    """
    from cadnerf_core.evaluation.dataset import render_dataset

    done = folder / ("transforms_test.json" if options.get("test_views") else "transforms.json")
    if once and done.is_file():
        return folder
    return render_dataset(mesh_file(MESHES / name), folder, views, size, seed, up=mesh_up(name),
                          **options)


def fov_walk(name: str, fov: float, work: Path, views: int = VIEWS,
             direction: int | None = None) -> Path:
    """The walk of ``views`` photos of mesh ``name`` at ``fov`` degrees across with its
    held-out views (the object filling the same share of the frame), in its own folder under
    ``work``, rendered once; ``direction`` +1 / -1: walked counter-clockwise / clockwise
    (None: the seed's way)."""
    folder = work / name / (f"fov{fov:g}" if views == VIEWS else f"fov{fov:g}_{views}views")
    if direction is not None:
        folder = folder.with_name(f"{folder.name}_{'ccw' if direction > 0 else 'cw'}")
    return render_walk(name, folder, views, once=True, test_views=TEST_VIEWS, fov_deg=fov,
                       direction=direction)


def load_walk(name: str, folder: Path, views: int = VIEWS, **options: Any) -> Dataset:
    """``render_walk``, loaded (``evaluation.dataset.load_dataset``)."""
    from cadnerf_core.evaluation.dataset import load_dataset

    return load_dataset(render_walk(name, folder, views, **options))


def rotation_error(result: Any, c2w_gt: np.ndarray, only: set[int] | None = None) -> float:
    """Median rotation error (degrees) of a retrieval's kept photos (of those in ``only``, if
    given) after similarity alignment.

    Args:
        result: a ``RetrievalResult``.
        c2w_gt: [P, 4, 4] the photos' true cameras.
        only: photo indices to score (None: every kept photo).
    """
    from cadnerf_core.cameras.conventions import pose_errors

    kept = [m for m in result.matches if not m.discarded and (only is None or m.index in only)]
    pred = np.stack([m.c2w for m in kept])
    rot, _ = pose_errors(pred, c2w_gt[[m.index for m in kept]])
    return float(np.median(rot))


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run with ``threads`` torch CPU threads (None: as set), restoring the count after: one
    thread a job where jobs share the cores, so OpenMP does not oversubscribe them."""
    import torch

    previous = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@dataclass(frozen=True)
class JobRun:
    """One job run by ``run_job``: its folder, wall seconds, and what it wrote."""

    job: Path
    seconds: float
    summary: JobResult  # ``pipeline.run_job``'s return value (its ``result.json``)
    retrieval: dict[str, Any]  # retrieval.json ({} where absent)
    metrics: dict[str, Any]  # metrics.json ({} where absent)


def run_job(job: Path, library: Library, *, photos: list[Path] | None = None,
            masks: list[Path] | None = None, config: Any = None, device: str = DEVICE,
            progress: Progress | None = None) -> JobRun:
    """Run one whole job in ``job``, as ``cadnerf reconstruct`` runs it.

    Args:
        job: the job folder (already holding its photos and config where these are None).
        library: the loaded CAD library.
        photos, masks: photos to stage in walking order, and one mask each (None: the job's
            own masks).
        config: the job's ``PipelineConfig`` to write (None: the one in the folder).
        device: the training device.
        progress: forwarded to the pipeline.
    Returns:
        The run.
    """
    from cadnerf_cli.reconstruct_cmd import stage_inputs
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.pipeline import run_job as pipeline_run_job

    folder = JobFolder(job)
    if photos is not None:
        stage_inputs(photos, masks, job)
    if config is not None:
        folder.write_config(config)
    start = time.perf_counter()
    summary = pipeline_run_job(job, library, progress, device)
    seconds = time.perf_counter() - start
    return JobRun(job, seconds, summary, folder.read_retrieval() or {},
                  folder.read_metrics() or {})


def evaluate_walk(walk: Path, views: int, library: Library, name: str,
                  overrides: dict[str, Any], job_dir: Path, *,
                  protocol: Protocol = "leave-out", preset: str = PRESET,
                  **options: Any) -> EvalReport:
    """Run one job on the first ``views`` photos of a rendered walk and score it on the walk's
    held-out views.

    Args:
        walk: a walk with a test split (``render_walk(..., test_views=...)``).
        views: photos the job gets.
        library: the loaded CAD library.
        name: the mesh the walk shows (whose look-alikes ``protocol`` leaves out or keeps).
        overrides: the job's configuration values over ``preset``'s.
        job_dir: the job folder to create.
        protocol: ``benchmarks.lookalikes``: leave the look-alikes out or keep them.
        options: ``evaluate_dataset``'s other arguments (``device``, ``eval_size``,
            ``exif_focal``, ``lpips_net``, ``intrinsics``, ``align``, ``progress``).
    Returns:
        ``evaluate_dataset``'s report.
    """
    from cadnerf_core.evaluation.evaluate import evaluate_dataset

    return evaluate_dataset(walk, views, library, preset=preset,
                            overrides={**exclude_overrides(name, protocol), **overrides},
                            job_dir=job_dir, **options)
