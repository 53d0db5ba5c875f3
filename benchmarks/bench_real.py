"""Whole jobs on real phone photos: how far the refined cameras end from the photos' own poses.

The espresso set of ``../shared/eval/photos`` (7 photos of a Pixel phone, 27 mm EXIF, shipped
masks, in the order of their metadata azimuths) carries coarse poses in its metadata (azimuth
and elevation per photo). Each run is a ``preview`` job as ``cadnerf reconstruct`` runs it;
its retrieved and its refined cameras (the trained model's) are compared with the metadata
poses: median rotation error over the kept photos after similarity alignment of the camera
centres. Runs: the set's look-alike left out of the library (the headline) and in, the
photos' SIFT matches on (the default: the walking direction, and the epipolar loss in the
pose windows). The column "pairs with a turn" counts the matched pairs whose turn is known;
with ``retrieval.matches.enabled`` false the same jobs gave the same cameras and PSNR (one
pair, 126 inliers, whose turn neither voted on the direction nor changed the training). A
third run, leave-out, also matches what stands round the object (``retrieval.matches.context``
at ``CONTEXT``; off by default): the placemat and floor that the camera walks round.

QUICK: not run (three whole jobs, about 30 minutes on 2 cores).

Usage: ``python -m benchmarks.bench_real [--quick]`` prints the section.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.lookalikes import PROTOCOLS, Protocol, exclude_overrides
from benchmarks.retrieval_real import real_set_photos
from benchmarks.retrieval_walks import EVAL_ROOT

ROOT = Path(__file__).resolve().parents[1]
LIBRARY_DIR = ROOT / "library_data" / "build"
SET = "ners_espresso"
PRESET = "preview"
CONTEXT = 0.5  # ``retrieval.matches.context`` of the lever's row (off by default)


def job_cameras(protocol: Protocol, library: Any,
                extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """One job on the set (``extra``: configuration values set besides the protocol's): its
    model, rotation errors (retrieved, refined) against the metadata poses, matched pairs
    used, training PSNR and time."""
    from cadnerf_cli.reconstruct_cmd import stage_inputs
    from cadnerf_core.cameras import pose_errors
    from cadnerf_core.config import resolve_config
    from cadnerf_core.evaluation.jobio import read_job_cameras
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.pipeline import run_job

    photos, masks, truth = real_set_photos(SET)
    assert truth is not None, f"{SET} has no metadata poses"
    job = Path(tempfile.mkdtemp(prefix="bench_real_"))
    try:
        stage_inputs(photos, masks, job)
        JobFolder(job).write_config(resolve_config(PRESET, {**exclude_overrides(SET, protocol),
                                                            **(extra or {})}))
        run_job(job, library, device="cpu")
        cams = read_job_cameras(job, TrainedModel.load(job, "cpu"))
        retrieval = JobFolder(job).read_retrieval() or {}
        metrics = JobFolder(job).read_metrics() or {}
    finally:
        shutil.rmtree(job, ignore_errors=True)
    gt = truth[cams.kept]
    pairs = [p for p in retrieval.get("photo_pairs", []) if p.get("turn_deg") is not None]
    return {"model": cams.model_id, "kept": len(cams.kept),
            "retrieved": float(np.median(pose_errors(cams.retrieved, gt)[0])),
            "refined": float(np.median(pose_errors(cams.refined, gt)[0])),
            "pairs": len(pairs), "psnr": float(metrics.get("mean_psnr", float("nan")))}


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the benchmark. Returns its markdown section."""
    head = ["## Real photos: refined cameras", "",
            f"Command: `python -m benchmarks.bench_real{' --quick' if quick else ''}`", ""]
    if not (EVAL_ROOT / "photos" / SET).is_dir():
        return "\n".join([*head, "Not run: `../shared/eval/photos` is absent.", ""])
    if quick:
        return "\n".join([*head, "Not run in QUICK: three whole jobs (about 30 minutes on 2 "
                          "cores); run without `--quick`.", ""])
    from cadnerf_core.library.format import load_library

    library = load_library(library_dir)
    rows = ["| protocol | model | kept | retrieved (deg) | refined (deg) | pairs with a turn | "
            "training PSNR (dB) |", "|---|---|---:|---:|---:|---:|---:|"]
    runs: list[tuple[str, Protocol, dict[str, Any]]] = [
        (protocol, protocol, {}) for protocol in PROTOCOLS]
    runs.append((f"leave-out, matches round the object (context {CONTEXT})", "leave-out",
                 {"retrieval.matches.context": CONTEXT}))
    for label, protocol, extra in runs:
        r = job_cameras(protocol, library, extra)
        rows.append(f"| {label} | {r['model']} | {r['kept']} | {r['retrieved']:.1f} | "
                    f"**{r['refined']:.1f}** | {r['pairs']} | {r['psnr']:.2f} |")
    return "\n".join([
        *head, f"`{SET}` (7 photos, shipped masks, EXIF focal length), preset `{PRESET}`, "
        "CPU: each job's retrieved and refined cameras against the set's coarse metadata "
        "poses (median rotation error over the kept photos after similarity alignment of the "
        "camera centres). leave-out: the set's look-alike (`benchmarks.lookalikes`) excluded "
        "from the library; with look-alike: the whole library.",
        "", *rows, ""])


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick``: not run)."""
    from benchmarks.run import area_main

    return area_main(run, "CAD-NeRF real-photo cameras benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())
