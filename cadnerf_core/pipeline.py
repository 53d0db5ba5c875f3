"""One job, end to end: intake -> masks -> retrieval -> three training phases -> export.

A job is a folder whose layout ``cadnerf_core.jobfolder`` owns. ``run_job`` reads the photos,
their uploaded masks and the resolved config through it, and writes every artifact there. A
checkpoint is saved after each training phase; calling ``run_job`` again on the same folder
continues after the last finished phase (intake and retrieval are re-run: they are
deterministic and take seconds).
"""

from __future__ import annotations

import dataclasses
import logging
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cadnerf_core.config import PipelineConfig
from cadnerf_core.errors import InputError
from cadnerf_core.intake import apply_crop
from cadnerf_core.job_warnings import job_warnings
from cadnerf_core.jobfolder import CONFIG, INPUTS, OVERLAY_SIDE, JobFolder
from cadnerf_core.jobresult import JobResult
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    import torch

    from cadnerf_core.library import Library
    from cadnerf_core.nerf import TrainData, TrainState
    from cadnerf_core.retrieval import RetrievalResult

log = logging.getLogger(__name__)

@dataclass
class Intake:
    """Photos, masks and the retrieval of one job."""

    names: list[str]
    photos: list[Any]  # cadnerf_core.intake.photos.Photo
    masks: list[np.ndarray]  # [H_i, W_i] bool
    retrieval: RetrievalResult
    doubts: list[np.ndarray | None] | None = None  # per photo, ``MaskResult.doubt``


def read_job_config(job_dir: Path) -> PipelineConfig:
    """The job's resolved configuration (``JobFolder.read_config``; missing: the default preset).

    Raises:
        InputError: ``config.json`` is unreadable or not a valid configuration.
    """
    try:
        return JobFolder(job_dir).read_config()
    except ValueError as exc:  # json and pydantic errors are ValueErrors
        raise InputError(f"invalid configuration: {exc}", item=CONFIG) from exc


def run_intake(job_dir: Path, library: Library, config: PipelineConfig,
               progress: Progress, mask_model: Path | None = None) -> Intake:
    """Read photos and masks, remove backgrounds where needed (``mask_model``: the ONNX model
    of the learned method, None for the built-in one), keep the masks with their overlays,
    sources and warnings, and retrieve model and poses."""
    from cadnerf_core.cameras import job_pairs, place_cameras
    from cadnerf_core.intake import (
        downscaled,
        load_photo,
        mask_overlay,
        photo_masks,
        shrunk_mask,
        with_focal,
    )
    from cadnerf_core.retrieval import retrieve

    folder = JobFolder(job_dir)
    inputs = folder.photos()
    if not inputs:
        raise InputError(f"no photos in {INPUTS}/", item=str(folder.file(INPUTS)),
                         hint="add 3 to 10 ordered photos")
    photos = [load_photo(entry.path, entry.index, entry.mask) for entry in inputs]
    names = [entry.name for entry in inputs]
    found = photo_masks(photos, config.masks.method, model_path=mask_model, progress=progress)
    masks = [result.mask for result in found]
    progress.check()  # before any output: a cancelled or deleted job writes nothing more
    folder.write_masks(inputs, found, (  # overlays are small: milliseconds, not 12 megapixels
        mask_overlay(downscaled(p.rgb, OVERLAY_SIDE), shrunk_mask(m, OVERLAY_SIDE))
        for p, m in zip(photos, masks, strict=True)))
    photos = with_focal(photos, config.retrieval.focal_35mm)  # where EXIF says nothing
    images, focals = [p.rgb for p in photos], [p.focal_pixels for p in photos]
    pairs = job_pairs(folder, inputs, images, masks, focals, config.retrieval,
                      config.masks.method, progress.check)
    progress.check()
    retrieval = retrieve(masks, names, library, config.retrieval, progress, images, focals,
                         crop_size=config.image_size, pairs=pairs)
    progress.check()
    known = any(p.focal_pixels is not None for p in photos)
    if pairs is not None:
        retrieval = place_cameras(retrieval, pairs, photos, config, known)
    retrieval = dataclasses.replace(retrieval, focal_known=known)
    summary = retrieval.to_json()
    folder.write_retrieval(summary)
    warnings = job_warnings(summary, names, [w for result in found for w in result.warnings])
    for warning in warnings:
        log.info("warning: %s", warning)
    folder.write_warnings(warnings)
    if len(retrieval.kept) < 2:
        raise InputError("fewer than two photos could be matched to the retrieved model",
                         item=INPUTS, hint="use 3 to 10 photos walking around the object")
    return Intake(names, photos, masks, retrieval, [result.doubt for result in found])


def training_data(intake: Intake, config: PipelineConfig, margin: float,
                  device: torch.device, size: int | None = None) -> TrainData:
    """Canonical crops (on white), masks, crop intrinsics and loss weights of the kept photos
    (``intake.photos.doubt_weights``: pixels where a learned mask is in doubt weigh
    ``masks.doubt_weight``), ``size`` pixels a side (None: the job's ``image_size``, the crops
    retrieval's ``K_canon`` refer to)."""
    from cadnerf_core.intake.crop import crop_intrinsics, uncrop_intrinsics
    from cadnerf_core.intake.photos import canonical_views, doubt_weights
    from cadnerf_core.nerf import TrainData
    from cadnerf_core.nerf.epipolar import match_terms

    kept = intake.retrieval.kept
    photos = [intake.photos[m.index] for m in kept]
    masks = [intake.masks[m.index] for m in kept]
    rgb, crops, boxes = canonical_views(photos, masks, size or config.image_size, margin)
    doubts = [None if intake.doubts is None else intake.doubts[m.index] for m in kept]
    weights = doubt_weights(doubts, [mask.shape for mask in masks], boxes,
                            config.masks.doubt_weight)
    scene = None
    if config.scene_mode:
        scene = np.stack([np.clip(apply_crop(p.rgb.astype(np.float32), box, fill=1.0), 0, 1)
                          for p, box in zip(photos, boxes, strict=True)])
    K = np.stack([m.K_canon if box == m.box else crop_intrinsics(
        uncrop_intrinsics(m.K_canon, m.box), box) for m, box in zip(kept, boxes, strict=True)])
    terms = match_terms(intake.retrieval.pairs, [m.index for m in kept], boxes,
                        config.retrieval.matches.min_inliers, device,
                        np.stack([m.c2w for m in kept]))
    return TrainData.from_numpy(rgb, crops, K, device, scene, weights, terms)


def _peak_memory_mb(device: torch.device) -> dict[str, float]:
    import torch

    out = {"rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    if device.type == "cuda":
        out["cuda_peak_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
    return out


def _initial_state(library: Library, model_id: str, c2w_init: np.ndarray,
                   config: PipelineConfig, device: torch.device,
                   learn_focal: bool = False) -> TrainState:
    """Fresh networks; the skip grid from the CAD occupancy (full without CAD init)."""
    from cadnerf_core.nerf import TrainState, grid_from_occupancy

    rcfg = config.render
    grid = None
    if config.use_cad_init:
        grid = grid_from_occupancy(library.occupancy(model_id).query, rcfg.grid_resolution,
                                   rcfg.bound, rcfg.grid_dilation, device=device)
    return TrainState.create(config, c2w_init, device, grid, learn_focal)


def _resume(job_dir: Path, c2w_init: np.ndarray, config: PipelineConfig,
            device: torch.device) -> tuple[int, TrainState | None, dict[str, Any]]:
    """Last finished phase, its state and metadata, when its checkpoint fits this job."""
    from cadnerf_core.nerf.checkpoint import last_checkpoint, load_payload, restore_state

    found = last_checkpoint(job_dir)
    if found is None:
        return 0, None, {}
    payload = load_payload(found[1])
    init = payload["poses"]["c2w_init"].numpy()
    if init.shape != c2w_init.shape or not np.allclose(init, c2w_init, atol=1e-5) \
            or payload["config"] != config.model_dump(mode="json"):
        log.warning("checkpoints do not match this job's inputs or config: starting over")
        return 0, None, {}
    log.info("resuming after phase %d", found[0])
    return found[0], restore_state(payload, device, config), dict(payload.get("extra", {}))


def phase3_data(intake: Intake, config: PipelineConfig, margin: float, device: torch.device,
                data: TrainData) -> TrainData:
    """What phase three learns colour from: ``data`` itself, or the same photos' crops at
    ``phase3.image_size`` where that is set and differs from the job's ``image_size``."""
    size = config.phase3.image_size
    if not size or size == config.image_size:
        return data
    return training_data(intake, config, margin, device, size)


def _run_phase(phase: int, state: TrainState, library: Library, model_id: str,
               data: TrainData, progress: Progress) -> None:
    from cadnerf_core.library import sample_occupancy
    from cadnerf_core.nerf import phases

    cfg = state.config
    if phase == 1:
        if cfg.use_cad_init:
            rng = np.random.default_rng(cfg.seed)
            phases.run_phase1(state, partial(sample_occupancy, library.occupancy(model_id),
                                              near_surface=cfg.phase1.near_surface, rng=rng),
                              progress)
    elif phase == 2:
        phases.run_phase2(state, data, progress)
    else:
        phases.run_phase3(state, data, progress)


def train(job_dir: Path, library: Library, retrieval: RetrievalResult, data: TrainData,
          config: PipelineConfig, device: torch.device, progress: Progress,
          learn_focal: bool = False,
          colour_data: Callable[[], TrainData] | None = None) -> tuple[TrainState, dict[str, Any]]:
    """The three phases, resuming after the last checkpointed one; a checkpoint after each.
    ``learn_focal``: the photos' focal length is unknown, refined with the poses.
    ``colour_data``: builds what phase three learns from (``phase3_data``; None: ``data``),
    called only when phase three runs.

    Returns:
        The trained state, and metadata (names, timings and peak memory per phase).
    """
    import torch

    from cadnerf_core.nerf import save_checkpoint

    kept = retrieval.kept
    c2w_init = np.stack([m.c2w for m in kept])
    done, resumed, old = _resume(job_dir, c2w_init, config, device)
    state = resumed or _initial_state(library, retrieval.model_id, c2w_init, config, device,
                                      learn_focal)
    extra: dict[str, Any] = {"model_id": retrieval.model_id, "names": [m.name for m in kept],
                             "timings": old.get("timings", {}), "memory": old.get("memory", {}),
                             "resumed_after_phase": done,
                             "learn_focal": bool(old.get("learn_focal", learn_focal))}
    for phase in range(done + 1, 4):
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)
        start = time.perf_counter()
        _run_phase(phase, state, library, retrieval.model_id,
                   colour_data() if phase == 3 and colour_data is not None else data, progress)
        extra["timings"][f"phase{phase}_s"] = time.perf_counter() - start
        extra["memory"][f"phase{phase}"] = _peak_memory_mb(device)
        extra["focal_scale"] = state.focal_scale()
        progress.check()
        save_checkpoint(job_dir, phase, state, extra)
        log.info("phase %d done in %.1f s", phase, extra["timings"][f"phase{phase}_s"])
    return state, extra


def run_job(job_dir: Path, library: Library, progress: Progress | None = None,
            device: str = "auto", mask_model: Path | None = None) -> JobResult:
    """Run (or resume) a whole job in its folder.

    Args:
        job_dir: the job folder (photos, optional masks and config; ``JobFolder``).
        library: the loaded CAD library.
        progress: progress reporter and cancel check (stages masks, retrieval, phase1-3,
            render, export); raises JobCancelled between steps when cancelled.
        device: "auto" (CUDA if available), "cpu", "cuda", "cuda:1", ...
        mask_model: an ONNX background-removal model for the learned method (a runtime
            argument, not config: a client must not name files on the server); None: built-in.
    Returns:
        The job's result, as written to ``result.json`` (``jobresult.JobResult``).
    Raises:
        InputError: unusable photos, masks or configuration. JobCancelled: cancelled.
    """
    from cadnerf_core.export import export_job
    from cadnerf_core.nerf import TrainedModel, resolve_device

    job_dir = Path(job_dir)
    progress = progress or Progress()
    handler = _attach_log(job_dir)
    try:
        config = read_job_config(job_dir)
        if not JobFolder(job_dir).has_config():  # record what ran; an existing one is final
            JobFolder(job_dir).write_config(config)
        dev = resolve_device(device)
        start = time.perf_counter()
        intake, intake_s = start_job(job_dir, library, config, dev, progress, mask_model)
        start_s = time.perf_counter() - start - intake_s
        learn_focal = all(p.focal_pixels is None for p in intake.photos)
        if (intake.retrieval.fusion or {}).get("start") == "mapper":
            # The mapper's bundle adjustment fits every match; the silhouettes of a library
            # model that only resembles the object would pull its cameras off.
            config = config.model_copy(update={"optimise_poses": False})
            learn_focal = False
        data = training_data(intake, config, library.spec.margin, dev)
        state, extra = train(job_dir, library, intake.retrieval, data, config, dev, progress,
                             learn_focal, partial(phase3_data, intake, config,
                                                  library.spec.margin, dev, data))
        extra["timings"].update(intake_s=intake_s, start_s=start_s)
        model = TrainedModel(state, extra)
        retrieval, data = with_focal_scale(intake.retrieval, data, state.focal_scale())
        return export_job(job_dir, model, retrieval, intake.photos, data, progress,
                          intake.masks)
    finally:
        _detach_log(handler)


def start_job(job_dir: Path, library: Library, config: PipelineConfig, device: torch.device,
              progress: Progress, mask_model: Path | None = None) -> tuple[Intake, float]:
    """Intake, retrieval and the cameras stage of a job: the cameras training starts from.

    ``cadnerf retrieve`` calls it too, so it prints the cameras a job would start from.

    Args:
        job_dir: the job folder, its photos, masks and config written (``JobFolder``).
        library: the loaded CAD library.
        config: the job's resolved configuration.
        device: where the start's short silhouette fits run.
        progress: progress reporter and cancel check.
        mask_model: an ONNX background-removal model, None for the built-in one.
    Returns:
        The intake with its chosen start, and the seconds intake and retrieval took.
    """
    clock = time.perf_counter()
    recorded = (JobFolder(job_dir).read_retrieval() or {}).get("hypotheses", [])
    intake = run_intake(job_dir, library, config, progress, mask_model)
    intake_s = time.perf_counter() - clock
    learn_focal = all(p.focal_pixels is None for p in intake.photos)
    return robust_start(job_dir, intake, library, config, device, learn_focal, progress,
                        recorded), intake_s


def robust_start(job_dir: Path, intake: Intake, library: Library, config: PipelineConfig,
                 device: torch.device, learn_focal: bool, progress: Progress,
                 recorded: list[dict[str, Any]]) -> Intake:
    """The intake with the retrieval hypothesis whose short silhouette fit is best
    (``RetrievalConfig.hypotheses``; ``cameras.start``), its ``retrieval.json`` rewritten with
    every fit's score; unchanged when retrieval gave no alternatives. ``recorded``: the fits
    an earlier run of this job wrote (kept when they cover the same hypotheses)."""
    if not intake.retrieval.alternatives:
        return intake
    from cadnerf_core.cameras import choose_start

    chosen = choose_start(intake.retrieval, intake.photos, intake.masks, library, config,
                          device, learn_focal, progress, recorded)
    JobFolder(job_dir).write_retrieval(chosen.to_json())
    return dataclasses.replace(intake, retrieval=chosen)


def with_focal_scale(retrieval: RetrievalResult, data: TrainData,
                     scale: float) -> tuple[RetrievalResult, TrainData]:
    """The retrieval's cameras and the training crops' intrinsics with their focal lengths
    times the learned ``scale`` (``Phase2Config.focal_bound``), so every view, the orbit and
    ``poses.json`` / ``transforms.json`` use the refined focal length."""
    from cadnerf_core.cameras import scale_focal

    if scale == 1.0:
        return retrieval, data
    matches = [dataclasses.replace(m, K_canon=scale_focal(m.K_canon, scale),
                                   K_photo=scale_focal(m.K_photo, scale))
               for m in retrieval.matches]
    K = data.K.clone()
    K[:, 0, 0] *= scale
    K[:, 1, 1] *= scale
    return (dataclasses.replace(retrieval, matches=matches),
            dataclasses.replace(data, K=K))


def _attach_log(job_dir: Path) -> logging.Handler:
    if not job_dir.is_dir():  # never created here: a deleted job must stay deleted
        raise InputError("the job folder does not exist", item=str(job_dir),
                         hint="create it with the photos in inputs/ first")
    handler = logging.FileHandler(JobFolder(job_dir).log_path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    handler.setLevel(logging.INFO)
    root = logging.getLogger("cadnerf_core")
    root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)
    return handler


def _detach_log(handler: logging.Handler) -> None:
    logging.getLogger("cadnerf_core").removeHandler(handler)
    handler.close()
