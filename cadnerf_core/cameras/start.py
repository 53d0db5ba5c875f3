"""A robust start: several retrieval hypotheses, each given a short coarse silhouette fit.

Retrieval commits to one model, one walking direction and one view per photo; a start 20 to
40 degrees off is often more than pose refinement can undo. With ``RetrievalConfig.hypotheses``
above 1, the retrieved walk and the next best walks (other models, the other direction) each
get phase one and a cut-down phase two on small crops
(``hypothesis_size``, ``hypothesis_steps``); the hypothesis whose rendered silhouettes agree
best with the masks at its refined poses is the one the job trains from.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from cadnerf_core.config import PipelineConfig
from cadnerf_core.config_bounds import MAX_SEED
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library
    from cadnerf_core.retrieval.result import RetrievalResult

log = logging.getLogger(__name__)

SEED_STEP = 101  # between the seeds of a hypothesis's fits (each phase adds 1 to 3 to its own)
UNFUSED_MARGIN = 0.1
"""By how much a hypothesis the pairs did not join (the retrieval kept unfused, or a walk whose
cameras every pair contradicts) must out-fit every fused hypothesis to be the start.
Fusing turns the cameras away from where a look-alike model's silhouettes put them, so even
right pairs cost the fused cameras a little fit; pairs matched wrongly (that still agree with
each other) cost them much more (``docs/presets.md``)."""


def coarse_config(config: PipelineConfig) -> PipelineConfig:
    """The job's configuration cut down to a hypothesis's coarse fit: small crops, few steps,
    the poses learned at ``retrieval.hypothesis_pose_lr``, no colour phase."""
    rcfg = config.retrieval
    data = config.model_dump()
    data["image_size"] = rcfg.hypothesis_size
    data["phase1"]["steps"] = max(1, rcfg.hypothesis_steps // 2)
    data["phase2"]["steps"] = rcfg.hypothesis_steps
    data["phase2"]["rays"] = min(config.phase2.rays, 512)
    data["phase2"]["pose_lr"] = rcfg.hypothesis_pose_lr
    data["render"]["samples_per_ray"] = min(config.render.samples_per_ray, 24)
    return PipelineConfig.model_validate(data)


def silhouette_iou(opacity: np.ndarray, mask: np.ndarray) -> float:
    """IoU of a rendered opacity [H, W] (above 0.5) with a mask [H, W] bool."""
    rendered = opacity > 0.5
    union = int((rendered | mask).sum())
    return float((rendered & mask).sum() / union) if union else 0.0


def fit_hypothesis(hypothesis: RetrievalResult, photos: Sequence[Any],
                   masks: Sequence[np.ndarray], library: Library, config: PipelineConfig,
                   device: torch.device, learn_focal: bool,
                   progress: Progress | None = None) -> float:
    """One hypothesis's score: the mean over ``hypothesis_seeds`` coarse fits
    (``coarse_fit``), each from its own seed, less ``discard_penalty`` per discarded photo
    (shared over all photos), as retrieval's own objective counts a discard.

    Args:
        photos, masks: every photo of the job (``intake.photos.Photo``) and its mask.
        progress: checked for cancelling between the fits' steps (its reports go nowhere).
    """
    seeds = config.retrieval.hypothesis_seeds
    fits = [coarse_fit(hypothesis, photos, masks, library,
                       config.model_copy(update={"seed": (config.seed + SEED_STEP * k)
                                                 % (MAX_SEED + 1)}), device, learn_focal,
                       progress)
            for k in range(seeds)]
    discarded = len(hypothesis.matches) - len(hypothesis.kept)
    penalty = config.retrieval.discard_penalty * discarded / len(hypothesis.matches)
    return float(np.mean(fits)) - penalty


def coarse_fit(hypothesis: RetrievalResult, photos: Sequence[Any],
               masks: Sequence[np.ndarray], library: Library, config: PipelineConfig,
               device: torch.device, learn_focal: bool,
               progress: Progress | None = None) -> float:
    """One coarse fit of a hypothesis (``coarse_config``, seeded by ``config.seed``): the mean
    silhouette IoU over its kept photos at their refined poses (``progress``: its steps'
    reports and cancel checks)."""
    from cadnerf_core.intake.photos import canonical_views
    from cadnerf_core.library.occupancy import sample_occupancy
    from cadnerf_core.nerf import phases
    from cadnerf_core.nerf.grid import grid_from_occupancy
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.nerf.state import TrainData, TrainState

    cfg = coarse_config(config)
    kept = hypothesis.kept
    size = cfg.image_size
    rgb, crops, _ = canonical_views([photos[m.index] for m in kept],
                                    [masks[m.index] for m in kept], size, library.spec.margin)
    K = np.stack([m.K_canon for m in kept]).astype(np.float64)
    K[:, :2] *= size / kept[0].box.size  # K_canon is for the job's crop size
    data = TrainData.from_numpy(rgb, crops, K, device)
    grid = None
    if cfg.use_cad_init:
        occupancy = library.occupancy(hypothesis.model_id)
        grid = grid_from_occupancy(occupancy.query, cfg.render.grid_resolution, cfg.render.bound,
                                   cfg.render.grid_dilation, device=device)
        sampler = partial(sample_occupancy, occupancy, near_surface=cfg.phase1.near_surface,
                          rng=np.random.default_rng(cfg.seed))
        state = TrainState.create(cfg, np.stack([m.c2w for m in kept]), device, grid,
                                  learn_focal)
        phases.run_phase1(state, sampler, progress)
    else:
        state = TrainState.create(cfg, np.stack([m.c2w for m in kept]), device, None,
                                  learn_focal)
    phases.run_phase2(state, data, progress)
    model = TrainedModel(state)
    with torch.no_grad():
        K_fit = state.poses.intrinsics(data.K).cpu().numpy()
    ious = [silhouette_iou(model.render_image(c2w, K_fit[i], size, size)[1], crops[i])
            for i, c2w in enumerate(model.c2w)]
    return float(np.mean(ious))


def _against_texture(hypothesis: RetrievalResult, threshold: float) -> bool:
    """Whether ``hypothesis`` walks against the direction the photos' texture (their matched
    points' turns and how their colours move) says with at least ``threshold`` of evidence:
    a short silhouette fit, blind to a mirrored walk, must not choose it by a few
    thousandths of IoU (0: never)."""
    evidence = hypothesis.direction_evidence
    return threshold > 0 and abs(evidence) >= threshold and evidence * hypothesis.direction < 0


def _key(model_id: str, direction: int, perspective: str) -> tuple[str, int, str]:
    return model_id, int(direction), perspective


def choose_start(retrieval: RetrievalResult, photos: Sequence[Any], masks: Sequence[np.ndarray],
                 library: Library, config: PipelineConfig, device: torch.device,
                 learn_focal: bool, progress: Progress,
                 recorded: Sequence[dict[str, Any]] = ()) -> RetrievalResult:
    """The hypothesis to train from: ``retrieval`` itself when it has no alternatives, else
    the best coarse fit among it and its alternatives, with every fit's score recorded
    (``RetrievalResult.hypotheses``) and the retrieval's ``focal_known``. Reports stage
    "retrieval" after each fit (cancellable).
    ``recorded``: the fits of an earlier run of the same job; when they cover the same
    hypotheses their choice is kept without fitting again (a resumed job).
    """
    import dataclasses

    candidates = [retrieval, *[h for h in retrieval.alternatives if len(h.kept) >= 2
                               and not _against_texture(h, config.retrieval.start_evidence)]]
    if len(candidates) < 2:
        return retrieval
    keys = [_key(h.model_id, h.direction, h.perspective) for h in candidates]
    if [_key(r["model_id"], r["direction"], r["perspective"]) for r in recorded] == keys:
        best = next((i for i, r in enumerate(recorded) if r.get("chosen")), 0)
        return dataclasses.replace(candidates[best], alternatives=[], hypotheses=list(recorded),
                                   direction_ambiguous=retrieval.direction_ambiguous,
                                   focal_known=retrieval.focal_known,
                                   too_small=retrieval.too_small)
    scores, seconds = [], []
    # The fits' own steps only check for cancelling (and so let the bar move between the
    # stage's reports); their phases' counts are not the stage's.
    checks = Progress(cancel=progress.cancel)
    for i, hypothesis in enumerate(candidates):
        start = time.perf_counter()
        scores.append(fit_hypothesis(hypothesis, photos, masks, library, config, device,
                                     learn_focal, checks))
        seconds.append(time.perf_counter() - start)
        log.info("start hypothesis %d: %s, direction %+d, retrieval score %.3f, fit %.3f", i,
                 hypothesis.model_id, hypothesis.direction, hypothesis.score, scores[-1])
        progress.step("retrieval", i + 1, len(candidates))
    # The fits are blind to a mirrored walk: its slight lead says nothing, unless the pairs
    # joined its cameras and none of the retrieved walk's.
    eligible = [i for i, h in enumerate(candidates)
                if not (_mirrors(h, retrieval)
                        and scores[i] - scores[0] < config.retrieval.mirror_margin
                        and not (_fused(h) and not _fused(retrieval)))]
    fused = [scores[i] for i, h in enumerate(candidates) if _fused(h)]
    eligible = [i for i in eligible if not fused or _fused(candidates[i])
                or scores[i] >= max(fused) + UNFUSED_MARGIN]
    best = max(eligible, key=lambda i: scores[i])
    record = [{"model_id": h.model_id, "direction": h.direction,
               "perspective": h.perspective, "fused": _fused(h),
               "score": h.score,
               "fit": s, "seconds": t, "chosen": i == best}
              for i, (h, s, t) in enumerate(zip(candidates, scores, seconds, strict=True))]
    chosen = candidates[best]
    if best:
        log.info("starting from hypothesis %d (%s) rather than the retrieved walk", best,
                 chosen.model_id)
    # A fit does not settle a direction retrieval had to guess: on such walks, taken both ways
    # round, the start had 12 of 22 the right way round against 9 for the guess alone
    # (``benchmarks.bench_starts``), so the result still says the direction is a guess.
    return dataclasses.replace(chosen, alternatives=[], hypotheses=record,
                               direction_ambiguous=retrieval.direction_ambiguous,
                               focal_known=retrieval.focal_known,
                               too_small=retrieval.too_small)


def _fused(hypothesis: RetrievalResult) -> bool:
    """Whether the pairs' rotations joined some of ``hypothesis``'s cameras (``fusion.fuse``):
    its cameras agree with the photos' matches, where an unfused one's contradict all of them
    (``prior.plausible``) or were set aside."""
    return bool((hypothesis.fusion or {}).get("photos"))


def _set_aside(hypothesis: RetrievalResult) -> bool:
    """Whether ``hypothesis`` is the retrieval kept unfused (``fusion.fuse_hypotheses``)."""
    return bool((hypothesis.fusion or {}).get("set_aside"))


def _mirrors(hypothesis: RetrievalResult, retrieved: RetrievalResult) -> bool:
    """Whether ``hypothesis`` is the retrieved model walked the other way round."""
    return (hypothesis.model_id == retrieved.model_id
            and hypothesis.direction == -retrieved.direction)
