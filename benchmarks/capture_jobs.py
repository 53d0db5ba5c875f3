"""One capture's job in the capture benchmark, and its row.

``run_capture`` runs a whole ``preview`` job, as ``cadnerf reconstruct`` runs it;
``start_capture`` only what a job does before training (``pipeline.run_intake``: masks, the
photos' matches, the mapper, retrieval and fusion; then ``pipeline.robust_start``: the short
silhouette fits that pick the hypothesis training starts from), for iterating on camera code
in minutes. Both score the cameras against the capture's reference: per stage the median
rotation error after similarity alignment of the camera centres (``cameras.pose_errors``),
the focal length's error, the photos the mapper registered, and the verified pairs whose
rotation is right or wrong (``capture_spacing.score_pairs``).
"""

from __future__ import annotations

import contextlib
import logging
import re
import shutil
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.capture_set import Capture
from benchmarks.capture_spacing import score_pairs
from benchmarks.harness import PRESET, run_job
from benchmarks.lookalikes import exclude_overrides

log = logging.getLogger("benchmarks.captures")

VARIANTS: dict[str, dict[str, Any]] = {
    "matches": {},
    "silhouettes": {"retrieval.matches.enabled": False},
}
"""The job's configuration per variant: the photos' matches used (the default), or not."""
RIGHT_DEG = 10.0
"""Largest error of a pair's rotation counted right."""
REGISTERED = re.compile(r"mapper: (\d+) of (\d+) photos registered")
MAPPER_RAN = re.compile(r"mapper: (accepted|not used)")


def registered_photos(lines: Sequence[str], fusion: dict[str, Any] | None) -> int | None:
    """How many photos the job's mapper registered, from its log lines (``mapper.map_photos``
    logs it; a mapper that ran and logged no count registered none) or, failing that, the
    photos the mapper started (``fusion.start`` "mapper"); None where no mapper ran."""
    counts = [int(found.group(1)) for line in lines if (found := REGISTERED.search(line))]
    if counts:
        return counts[-1]
    if fusion and fusion.get("start") == "mapper":
        return len(fusion.get("photos", []))
    return 0 if any(MAPPER_RAN.search(line) for line in lines) else None


def start_kind(fusion: dict[str, Any] | None) -> str:
    """Where the started cameras come from: "mapper" (its cameras placed in the CAD frame),
    "fused" (the retrieved cameras moved by the pairs' rotations) or "retrieved"."""
    if fusion and fusion.get("start") == "mapper":
        return "mapper"
    return "fused" if fusion and fusion.get("photos") else "retrieved"


def pair_rotations(pairs: Sequence[Any]) -> list[tuple[int, int, np.ndarray]]:
    """(i, j, R) of the verified pairs that gave a rotation (``matches.PairMatch``)."""
    return [(int(p.i), int(p.j), np.asarray(p.rotation)) for p in pairs
            if p.rotation is not None]


def _median_error(c2w: np.ndarray, truth: np.ndarray) -> float:
    from cadnerf_core.cameras import pose_errors

    return float(np.median(pose_errors(c2w, truth)[0]))


def score_row(capture: Capture, kept: list[int], retrieved: np.ndarray, started: np.ndarray,
              refined: np.ndarray | None, focal_px: np.ndarray,
              pairs: Sequence[Any]) -> dict[str, Any]:
    """The row's scores: per stage the median rotation error (degrees) of the kept photos,
    whether the walk went the other way (``textured_walks.mirrored``), the focal length's
    error (share; None where the reference has none), pairs right and wrong, and of them those
    the cameras stage uses (``prior.plausible``: near the retrieved cameras)."""
    from benchmarks.textured_walks import mirrored
    from cadnerf_core.cameras.prior import plausible_at

    truth = capture.c2w[kept]
    focal = None
    if capture.focal is not None:
        focal = float(np.median(focal_px / capture.focal[kept] - 1.0))
    score = score_pairs(pair_rotations(pairs), capture.c2w, RIGHT_DEG)
    used = score_pairs(pair_rotations(plausible_at(dict(zip(kept, retrieved, strict=True)),
                                                   [p for p in pairs if p.i in kept
                                                    and p.j in kept])),
                       capture.c2w, RIGHT_DEG)
    last = started if refined is None else refined
    return {"retrieved": _median_error(retrieved, truth),
            "started": _median_error(started, truth),
            "refined": None if refined is None else _median_error(refined, truth),
            "mirrored": mirrored(last, truth), "focal": focal,
            "pairs": score.right + score.wrong, "pairs_right": score.right,
            "pairs_wrong": score.wrong, "used_right": used.right, "used_wrong": used.wrong}


def _base_row(capture: Capture, variant: str, mode: str) -> dict[str, Any]:
    return {"capture": capture.name, "variant": variant, "mode": mode,
            "photos": len(capture.photos), "spacing": capture.spacing,
            "exif": capture.exif_35mm is not None, "frames": list(capture.frames)}


NO_FITS = {"retrieval.hypotheses": 1}
"""``--no-fits``: the retrieved walk alone, no start hypotheses given a silhouette fit."""


def _config(capture: Capture, variant: str, fits: bool = True) -> Any:
    from cadnerf_core.config import internal_config

    return internal_config(PRESET, {**exclude_overrides(capture.name), **capture.overrides,
                                    **VARIANTS[variant], **({} if fits else NO_FITS)})


def run_capture(capture: Capture, library: Any, variant: str) -> dict[str, Any]:
    """One whole ``preview`` job on the capture. Returns its row (``score_row``, the model,
    kept photos, registered photos, PSNR, seconds, fused photos)."""
    from cadnerf_core.cameras.pairs_io import from_arrays
    from cadnerf_core.evaluation.jobio import read_job_cameras
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.nerf.model import TrainedModel

    job = Path(tempfile.mkdtemp(prefix="bench_captures_"))
    try:
        run = run_job(job, library, photos=capture.photos, masks=capture.masks,
                      config=_config(capture, variant))
        cams = read_job_cameras(job, TrainedModel.load(job, "cpu"))
        folder = JobFolder(job)
        lines = folder.log_path.read_text().splitlines() if folder.log_path.is_file() else []
        stored = folder.read_match_cache()
        pairs = [] if stored is None else (from_arrays(stored, str(stored["key"])) or [])
    finally:
        shutil.rmtree(job, ignore_errors=True)
    retrieval = run.retrieval
    by_index = {int(m["index"]): m for m in retrieval["matches"]}
    retrieved = np.array([by_index[k].get("c2w_retrieved", by_index[k]["c2w"])
                          for k in cams.kept], dtype=np.float64)
    fusion = retrieval.get("fusion") or {}
    return {**_base_row(capture, variant, "full"), "model": cams.model_id,
            "kept": len(cams.kept), "registered": registered_photos(lines, fusion),
            "start": start_kind(fusion),
            **score_row(capture, cams.kept, retrieved, cams.retrieved, cams.refined,
                        cams.K_photo[:, 0, 0], pairs),
            "psnr": float(run.metrics.get("mean_psnr", float("nan"))),
            "seconds": run.seconds, "fused": len(fusion.get("photos", []))}


@contextlib.contextmanager
def core_log() -> Iterator[list[str]]:
    """The core's log messages (INFO and up) while the block runs, as a job's log keeps them."""
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    handler = Keep(logging.INFO)
    root = logging.getLogger("cadnerf_core")
    previous = root.level
    root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)
    try:
        yield lines
    finally:
        root.removeHandler(handler)
        root.setLevel(previous)


def start_capture(capture: Capture, library: Any, variant: str,
                  fits: bool = True) -> dict[str, Any]:
    """A job on the capture up to the cameras training would start from (no training):
    ``run_intake`` then ``robust_start``, as ``pipeline.run_job`` calls them (``fits`` False:
    one hypothesis, ``NO_FITS``, so none is fitted). Returns its row (``score_row`` without
    refined cameras; the focal length is the started one)."""
    from cadnerf_cli.reconstruct_cmd import stage_inputs
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.nerf.model import resolve_device
    from cadnerf_core.pipeline import read_job_config, robust_start, run_intake
    from cadnerf_core.progress import Progress

    job = Path(tempfile.mkdtemp(prefix="bench_captures_start_"))
    try:
        stage_inputs(capture.photos, capture.masks, job)
        JobFolder(job).write_config(_config(capture, variant, fits))
        config = read_job_config(job)
        start = time.perf_counter()
        with core_log() as lines:
            intake = run_intake(job, library, config, Progress())
            learn_focal = all(p.focal_pixels is None for p in intake.photos)
            intake = robust_start(job, intake, library, config, resolve_device("cpu"),
                                  learn_focal, Progress(), [])
        seconds = time.perf_counter() - start
    finally:
        shutil.rmtree(job, ignore_errors=True)
    retrieval = intake.retrieval
    kept = [m.index for m in retrieval.kept]
    started = np.stack([m.c2w for m in retrieval.kept])
    retrieved = np.stack([m.c2w if m.c2w_retrieved is None else m.c2w_retrieved
                          for m in retrieval.kept])
    focal_px = np.array([m.K_photo[0, 0] for m in retrieval.kept])
    fusion = retrieval.fusion or {}
    return {**_base_row(capture, variant, "cameras" if fits else "cameras-no-fits"),
            "model": retrieval.model_id,
            "kept": len(kept), "registered": registered_photos(lines, fusion),
            "start": start_kind(fusion),
            **score_row(capture, kept, retrieved, started, None, focal_px, retrieval.pairs),
            "psnr": None, "seconds": seconds, "fused": len(fusion.get("photos", []))}
