"""The mesh a job exports against the object's own surface: distances, F-score and pieces.

Each evaluation mesh's 40-degree walk (6 photos at 128 px, the unseen benchmark's) goes
through a ``preview`` job, the mesh's look-alikes left out of the library. The job's surface
(``export.mesh.surface``: marching cubes, small pieces dropped, decimated) is compared with the
object's mesh as the walk renders it (normalised to the unit sphere), mapped into the job's
frame by the evaluation's own fit (``evaluation.frame.frame_mapping``, photometric: the
mapping its held-out views are rendered with). Distances are in units of the object's
bounding-sphere radius, between 30 000 points sampled on each surface: accuracy (job surface to
object), completeness (object to job surface), Chamfer (their mean) and the F-score at 5 % of
the radius (harmonic mean of the shares of points within it, both ways); where the cameras put
the surface, and after ICP with scale from there (the shape alone: the mesh's unit is
arbitrary, and a focal length off by some share scales the whole reconstruction). Each surface is
scored twice: as exported (pieces under ``MIN_PIECE_SHARE`` of the largest dropped) and with
every piece kept, each with its pieces and the time xatlas takes to unwrap it.

QUICK: the three quick meshes.

Usage: ``python -m benchmarks.bench_mesh [--quick]``.
"""

from __future__ import annotations

import logging
import shutil
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import (
    ABSENT,
    LIBRARY_DIR,
    MESHES,
    QUICK_MESHES,
    VIEWS,
    WORK_ROOT,
    eval_meshes,
    evaluate_walk,
    fov_walk,
    mesh_file,
    mesh_up,
    section_head,
    torch_threads,
)

log = logging.getLogger(__name__)

FOV = 40.0
SAMPLES = 30_000
F_THRESHOLD = 0.05  # of the bounding-sphere radius
WORK_DIR = WORK_ROOT / "bench_mesh"


def _distances(a: np.ndarray, b: np.ndarray, threshold: float) -> dict[str, float]:
    from scipy.spatial import cKDTree

    to_truth, to_ours = cKDTree(b).query(a)[0], cKDTree(a).query(b)[0]
    precision, recall = float((to_truth < threshold).mean()), float((to_ours < threshold).mean())
    f_score = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return {"accuracy": float(to_truth.mean()), "completeness": float(to_ours.mean()),
            "chamfer": float((to_truth.mean() + to_ours.mean()) / 2.0), "f_score": f_score}


def surface_scores(ours: Any, truth: Any, threshold: float = F_THRESHOLD,
                   samples: int = SAMPLES) -> dict[str, float]:
    """Accuracy, completeness, Chamfer and F-score of surface ``ours`` against ``truth``
    (trimesh meshes in one frame; distances in its units), where the cameras put it
    (``placed_*``) and after ICP with scale from there (the shape alone, as a user who scales
    the mesh sees it: the unit is arbitrary, and a focal length off by some share scales it)."""
    import trimesh
    from trimesh.registration import icp

    a = np.asarray(trimesh.sample.sample_surface(ours, samples, seed=0)[0])
    b = np.asarray(trimesh.sample.sample_surface(truth, samples, seed=1)[0])
    placed = _distances(a, b, threshold)
    _, moved, _ = icp(a, b, max_iterations=100, scale=True)
    shape = _distances(np.asarray(moved), b, threshold)
    return {**{f"placed_{k}": v for k, v in placed.items()}, **shape}


def pieces(mesh: Any) -> int:
    """Connected pieces of a mesh (``export.mesh.piece_labels``)."""
    from cadnerf_core.export.mesh import piece_labels

    labels = piece_labels(mesh)
    return int(labels.max()) + 1 if len(labels) else 0


def unwrap_seconds(mesh: Any, size: int) -> float:
    """Seconds xatlas takes to chart the mesh for a ``size`` texture as the export charts it
    (its child process)."""
    from cadnerf_core.export.atlas import unwrap
    from cadnerf_core.export.texture import PADDING

    start = time.perf_counter()
    unwrap(np.asarray(mesh.vertices), np.asarray(mesh.faces), size, PADDING)
    return time.perf_counter() - start


def score_job(name: str, job: Path, walk: Path) -> dict[str, Any]:
    """The job's surface as exported and with every piece kept, against the object's."""
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.frame import frame_mapping
    from cadnerf_core.evaluation.jobio import first_views, read_job_cameras
    from cadnerf_core.export.mesh import MIN_PIECE_SHARE, occupancy_grid, surface
    from cadnerf_core.mesh.meshio import load_mesh, normalise_mesh
    from cadnerf_core.nerf.model import TrainedModel

    model = TrainedModel.load(job, "cpu")
    data = first_views(load_dataset(walk), VIEWS)
    cams = read_job_cameras(job, model)
    to_job = frame_mapping(model, data, cams, "photometric", "estimated")
    truth = normalise_mesh(load_mesh(mesh_file(MESHES / name)), up=mesh_up(name))
    grid = occupancy_grid(model)
    size = model.state.config.export.texture_size
    row: dict[str, Any] = {}
    for label, share in (("exported", MIN_PIECE_SHARE), ("all", 0.0)):
        ours = surface(model, grid, share)
        # Into the object's frame: x = R^T (y - t) / scale.
        ours.vertices = (np.asarray(ours.vertices) - to_job.t) @ to_job.R / to_job.scale
        row[label] = {**surface_scores(ours, truth), "pieces": pieces(ours),
                      "faces": len(ours.faces), "unwrap_s": unwrap_seconds(ours, size)}
    return row


def run_mesh(name: str, library: Any, work: Path) -> dict[str, Any]:
    """One job on the mesh's walk, scored. Returns its row."""
    walk = fov_walk(name, FOV, work)
    job = walk.parent / f"job_{walk.name}"
    shutil.rmtree(job, ignore_errors=True)
    report = evaluate_walk(walk, VIEWS, library, name, {}, job, device="cpu")
    row = {"mesh": name, "model": report.model_id, "psnr": report.image.psnr,
           "rot": report.pose_refined.rotation_deg, **score_job(name, job, walk)}
    log.info("%s: Chamfer %.3f exported, %.3f all kept; F %.3f / %.3f; pieces %d / %d", name,
             row["exported"]["chamfer"], row["all"]["chamfer"], row["exported"]["f_score"],
             row["all"]["f_score"], row["exported"]["pieces"], row["all"]["pieces"])
    return row


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The per-mesh table and the medians."""
    lines = ["| mesh | model | PSNR (dB) | rotation (deg) | Chamfer where the cameras put it | "
             "Chamfer, shape | F-score, shape | Chamfer, shape, every piece | F-score, shape, "
             "every piece | pieces (every piece) | unwrap s (every piece) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        e, a = r["exported"], r["all"]
        lines.append(f"| {r['mesh']} | {r['model']} | {r['psnr']:.2f} | {r['rot']:.1f} | "
                     f"{e['placed_chamfer']:.3f} | {e['chamfer']:.3f} | {e['f_score']:.3f} | "
                     f"{a['chamfer']:.3f} | {a['f_score']:.3f} | {e['pieces']} ({a['pieces']}) "
                     f"| {e['unwrap_s']:.1f} ({a['unwrap_s']:.1f}) |")

    def median(label: str, key: str) -> float:
        return statistics.median(r[label][key] for r in rows)
    lines += ["", f"- Over the {len(rows)} meshes, medians as exported: Chamfer distance "
              f"**{median('exported', 'chamfer'):.3f}** of the radius (shape; "
              f"{median('exported', 'placed_chamfer'):.3f} where the cameras put it), F-score "
              f"at {F_THRESHOLD:.0%} of the radius **{median('exported', 'f_score'):.3f}**.",
              f"- Every piece kept instead: Chamfer {median('all', 'chamfer'):.3f}, F-score "
              f"{median('all', 'f_score'):.3f}; pieces {sum(r['all']['pieces'] for r in rows)} "
              f"in all against {sum(r['exported']['pieces'] for r in rows)}; xatlas "
              f"{sum(r['all']['unwrap_s'] for r in rows):.1f} s in all against "
              f"{sum(r['exported']['unwrap_s'] for r in rows):.1f} s."]
    return lines


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the benchmark. Returns its markdown section."""
    from cadnerf_core.export.mesh import MIN_PIECE_SHARE
    from cadnerf_core.library.format import load_library

    head = section_head("The mesh against the object's surface", "bench_mesh", quick,
                        f": `preview` jobs on the 40-degree walks ({VIEWS} photos, 128 px, "
                        "leave-out), one at a time, 2 torch threads. Distances in units of the "
                        "object's bounding-sphere radius; exported: pieces under "
                        f"{MIN_PIECE_SHARE:.0%} of the largest piece's area dropped.")
    if not MESHES.is_dir():
        return "\n".join([*head, ABSENT, ""])
    library = load_library(library_dir)
    names = QUICK_MESHES if quick else eval_meshes()
    shutil.rmtree(WORK_DIR, ignore_errors=True)
    with torch_threads(2):
        rows = [run_mesh(name, library, WORK_DIR) for name in names]
    shutil.rmtree(WORK_DIR, ignore_errors=True)
    if not quick:
        _record(rows)
    return "\n".join([*head, *table(rows), ""])


def _record(rows: list[dict[str, Any]]) -> None:
    """The headline figure: the median F-score of the shapes as exported."""
    from benchmarks.results import Result, cpu_cores, record, today

    record(Result("mesh_f_score", f"mesh F-score at {F_THRESHOLD:.0%} of the object's radius, "
                  f"{len(rows)} unseen meshes, 6 photos at 128 px, `preview`",
                  statistics.median(r["exported"]["f_score"] for r in rows), "(median)", 3,
                  f"leave-out, shape after ICP, {cpu_cores()}",
                  ".venv/bin/python -m benchmarks.run --only mesh --out docs/benchmarks.md",
                  today()))


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    from benchmarks.run import area_main

    return area_main(run, __doc__.splitlines()[0] if __doc__ else "", argv)


if __name__ == "__main__":
    sys.exit(main())
