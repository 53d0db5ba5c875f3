"""CAD model and pose retrieval from photo masks.

Each photo's mask is cropped canonically (as the library's silhouettes were), compared by IoU
with every silhouette of every model at once (``scoring``), the model is chosen by votes, and one
library view per photo is found by a pose solver (``posesearch``); the views give the cameras
(``cameras``). Where the photos' focal length is known, both silhouette sets may be searched.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from cadnerf_core.cameras.matches import (
    PairMatch,
    inlier_table,
    match_photos,
    reindexed,
    too_small,
    walk_evidence,
)
from cadnerf_core.config import RetrievalConfig
from cadnerf_core.errors import InputError
from cadnerf_core.intake.crop import CropBox, apply_crop
from cadnerf_core.intake.photos import canonical_masks
from cadnerf_core.job_warnings import direction_guess_hint, order_guess_warning, reorder_warning
from cadnerf_core.progress import Progress
from cadnerf_core.retrieval.cameras import angle_mismatch, photo_match, share_focal
from cadnerf_core.retrieval.posesearch import PoseSearchResult
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult
from cadnerf_core.retrieval.scoring import azimuth_bins, iou_table, vote_models
from cadnerf_core.retrieval.walks import alternatives, choose_walk

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library
    from cadnerf_core.retrieval.ordering import OrderChoice

T = TypeVar("T")

log = logging.getLogger(__name__)

TOP_MODELS = 5  # models listed in a result, best first
APPEARANCE_SIZE = 128  # side of the crops the texture direction cue looks at
FOCAL_GUESS = 1.2
"""Focal length per pixel of the longer side assumed for matching photos whose own is unknown
(COLMAP's default: about 45 degrees across); the sign of a turn does not depend on it."""


def direction_evidence(images: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                       boxes: Sequence[CropBox]) -> float:
    """Texture evidence for the walking direction (``direction.walk_direction_evidence``) of
    photos [H_i, W_i, 3] float in [0, 1], composited on white inside their masks and cropped
    by their canonical boxes at ``APPEARANCE_SIZE``."""
    from cadnerf_core.cameras.direction import walk_direction_evidence

    rgbs, crops = _appearance_crops(images, masks, boxes)
    return walk_direction_evidence(rgbs, crops)


def _appearance_crops(images: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                      boxes: Sequence[CropBox]) -> tuple[np.ndarray, np.ndarray]:
    """The photos composited on white inside their masks and cropped by their canonical boxes
    at ``APPEARANCE_SIZE``, with the masks' crops. Returns [P, S, S, 3] float, [P, S, S] bool."""
    rgbs, crops = [], []
    for image, mask, b in zip(images, masks, boxes, strict=True):
        box = CropBox(b.x0, b.y0, b.side, APPEARANCE_SIZE)
        alpha = apply_crop(mask.astype(np.float32), box)[..., None]
        rgb = apply_crop(np.asarray(image, dtype=np.float32), box, fill=1.0)
        rgbs.append(np.clip(rgb * alpha + (1.0 - alpha), 0.0, 1.0))
        crops.append(alpha[..., 0] > 0.5)
    return np.stack(rgbs), np.stack(crops)


def photo_pairs(images: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                focals: Sequence[float | None] | None,
                config: RetrievalConfig,
                check: Callable[[], None] | None = None) -> list[PairMatch]:
    """Verified matches between every pair of photos (``matches.match_photos``), each photo's
    camera centred, its focal length its own where known, else the median of the known ones,
    else ``FOCAL_GUESS``. Returns the ``matches.PairMatch`` list."""
    known = [f for f in focals or [] if f is not None]
    intrinsics = []
    for i, mask in enumerate(masks):
        height, width = mask.shape[:2]
        own = focals[i] if focals is not None else None
        focal = own or (float(np.median(known)) if known else FOCAL_GUESS * max(height, width))
        intrinsics.append(np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0],
                                    [0.0, 0.0, 1.0]]))
    return match_photos(images, masks, intrinsics, config.matches, check)


def retrieve(masks: Sequence[np.ndarray], names: Sequence[str], library: Library,
             config: RetrievalConfig | None = None, progress: Progress | None = None,
             images: Sequence[np.ndarray] | None = None,
             focals: Sequence[float | None] | None = None,
             crop_size: int | None = None,
             pairs: list[PairMatch] | None = None) -> RetrievalResult:
    """Retrieve the CAD model and a library pose for every photo.

    Args:
        masks: P full-photo masks [H_i, W_i] bool, in walking order (or in any order:
            ``config.order``).
        names: P photo names.
        library: the loaded library.
        config: solver settings (defaults when None).
        progress: reports stage "retrieval" (2 steps a silhouette set searched) and checks
            for cancellation.
        images: the P photos [H_i, W_i, 3] float in [0, 1], optional: their texture helps
            the DP choose the walking direction (``RetrievalConfig.appearance_weight``).
        focals: the P photos' focal lengths in pixels where known (EXIF), else None; with
            ``shared_focal`` the known ones set the shared focal length.
        crop_size: side in pixels of the canonical crop each match's ``K_canon`` and ``box``
            refer to: the job's ``image_size``, its NeRF's crops (None: the library's
            silhouette size; IoU is always computed at the library's size).
        pairs: the photos' verified matches (``photo_pairs``) when already made (a job's
            cache); None: matched here when ``config.matches`` asks for them.
    Returns:
        The RetrievalResult, its matches in the photos' given order; ``order`` says the
        walking order used.
    """
    config = config or RetrievalConfig()
    allowed = allowed_models(library, config.exclude_models)
    seen = _look(masks, images, focals, library, config, pairs)
    found = _retrieve_seen(seen, masks, names, library, allowed, config, progress, focals,
                           crop_size)
    matched = images is not None and config.solver == "dp" and config.matches.enabled
    return dataclasses.replace(found, too_small=too_small(masks, config.matches.context)) \
        if matched else found


def _retrieve_seen(seen: _Seen, masks: Sequence[np.ndarray], names: Sequence[str],
                   library: Library, allowed: np.ndarray, config: RetrievalConfig,
                   progress: Progress | None, focals: Sequence[float | None] | None,
                   crop_size: int | None) -> RetrievalResult:
    """``retrieve`` from what was ``seen`` of the photos: their walking order searched where
    ``config.order`` asks for it."""
    if config.order != "walk" and len(masks) > 3:  # three photos make one cycle either way
        choice = _order(seen, library, allowed, config, progress)
        walk = config.model_copy(update={"order": "walk"})
        found = _retrieve(seen.in_order(choice.order), [names[i] for i in choice.order],
                          library, allowed, walk, progress, _pick(focals, choice.order),
                          crop_size)
        if choice.reordered and config.order == "auto":
            log.info("%s", reorder_warning([names[i] for i in choice.order]))
        lead = choice.lead
        guess = lead is not None and lead < config.order_ambiguity_margin * len(masks)
        if guess:
            log.info("%s (lead %.3f IoU)",
                     order_guess_warning([names[i] for i in choice.order]), lead)
        return found.in_given_order(choice.order, config.order, choice.reordered, seen.pairs,
                                    lead, guess)
    return _retrieve(seen, names, library, allowed, config, progress, focals, crop_size)


@dataclass
class _Seen:
    """What retrieval reads off the photos whatever their order, computed once: each photo's
    size, canonical mask crop and box, its appearance crops (None without the photos) and the
    matches between every pair."""

    sizes: list[tuple[int, int]]  # (height, width) of each photo
    crops: np.ndarray  # canonical masks [P, S, S]
    boxes: list[CropBox]  # photo -> canonical crop
    appearance: tuple[np.ndarray, np.ndarray] | None  # ``_appearance_crops``
    pairs: list[PairMatch]

    def in_order(self, order: Sequence[int]) -> _Seen:
        """The same photos taken in ``order`` (the pairs renumbered)."""
        position = [int(k) for k in np.argsort(order)]  # photo -> its place in the walk
        appearance = None if self.appearance is None else (
            self.appearance[0][list(order)], self.appearance[1][list(order)])
        return _Seen([self.sizes[i] for i in order], self.crops[list(order)],
                     [self.boxes[i] for i in order], appearance,
                     reindexed(self.pairs, position))


def _look(masks: Sequence[np.ndarray], images: Sequence[np.ndarray] | None,
          focals: Sequence[float | None] | None, library: Library,
          config: RetrievalConfig, known: list[PairMatch] | None = None) -> _Seen:
    """``_Seen`` of the photos: crops at the library's silhouette size; the appearance crops
    and the matches where the photos are given (the matches only for the DP, when enabled)."""
    spec = library.spec  # both silhouette sets share the crop size and margin
    crops, boxes = canonical_masks(masks, spec.silhouette_size, spec.margin)
    appearance = None if images is None else _appearance_crops(images, masks, boxes)
    pairs: list[PairMatch] = []
    if images is not None and config.solver == "dp" and config.matches.enabled:
        pairs = known if known is not None else photo_pairs(images, masks, focals, config)
        log.info("matches: %d inliers over %d pairs", sum(p.inliers for p in pairs),
                 len(pairs))
    return _Seen([mask.shape[:2] for mask in masks], crops, boxes, appearance, pairs)


def _retrieve(seen: _Seen, names: Sequence[str], library: Library, allowed: np.ndarray,
              config: RetrievalConfig, progress: Progress | None,
              focals: Sequence[float | None] | None, crop_size: int | None) -> RetrievalResult:
    """``retrieve`` of photos in walking order, from what was ``seen`` of them."""
    from cadnerf_core.cameras.direction import walk_direction_evidence

    evidence = 0.0
    n_photos = len(seen.sizes)
    if seen.appearance is not None and config.solver == "dp" and config.appearance_weight > 0:
        evidence = walk_direction_evidence(*seen.appearance)
        if seen.pairs:
            turns = walk_evidence(seen.pairs, n_photos, config.matches)
            log.info("walking-direction evidence: matches %+.2f, texture %+.2f", turns,
                     evidence)
            evidence += turns
    photos = _Photos(names, seen.sizes, seen.crops, seen.boxes, evidence, focals,
                     crop_size or library.spec.silhouette_size, allowed,
                     seen.pairs)

    near = library.near
    known = [f for f in focals or [] if f is not None]
    wanted = config.perspective
    if wanted != "auto" or near is None or not known:
        single = "far" if wanted == "auto" else wanted
        chosen = _retrieve_from(photos, library.view_set(single), config, progress, single,
                                (0, 2))
        if wanted == "auto" and near is not None and config.hypotheses > 1:
            # No focal length to choose the set by: the near set's best walk (a wide lens
            # near the object) is the first alternative, for the start's fits to judge.
            wide = _retrieve_from(photos, near, config.model_copy(update={"hypotheses": 1}),
                                  None, "near", (0, 2))
            others = [wide, *chosen.alternatives][:config.hypotheses - 1]
            chosen = dataclasses.replace(chosen, alternatives=others)
    else:
        results = [_retrieve_from(photos, lib, config, progress, label, steps)
                   for lib, label, steps in ((library, "far", (0, 4)), (near, "near", (2, 4)))]
        mismatch = [angle_mismatch(r, lib, focals)
                    for r, lib in zip(results, (library, near), strict=True)]
        chosen = results[int(np.argmin(mismatch))]
        log.info("perspective: %s (photos' angle against the matched views': far %.3f, "
                 "near %.3f)", chosen.perspective, *mismatch)
    if chosen.direction_ambiguous:
        log.info("%s (lead %.3f IoU, texture evidence %+.2f)",
                 direction_guess_hint(chosen.direction), chosen.direction_lead,
                    chosen.direction_evidence)
    return chosen


def _pick(items: Sequence[T] | None, order: Sequence[int]) -> list[T] | None:
    """``items`` in ``order`` (None stays None)."""
    return None if items is None else [items[i] for i in order]


def _order(seen: _Seen, library: Library, allowed: np.ndarray, config: RetrievalConfig,
           progress: Progress | None) -> OrderChoice:
    """The order to walk the photos in (``config.order`` "any" or "auto"), searched on the
    silhouette set ``config.perspective`` names (the far one when "auto") among the most voted
    models, with the photos' likeness (colours, outlines, and the matches between them where
    the object has texture) as the prior that neighbours look alike."""
    from cadnerf_core.retrieval.ordering import choose_order

    views = library.view_set("near" if config.perspective == "near" else "far")
    silhouettes = views.silhouettes
    if len(allowed) < len(silhouettes):
        silhouettes = silhouettes[allowed]
    iou = iou_table(seen.crops, silhouettes)
    _, ranking = vote_models(iou)
    similarity = _likeness(seen) if config.similarity_weight > 0 else None
    az_index = azimuth_bins(views.az_el, views.spec.n_azimuths)
    candidates = [m for m, _, _ in ranking[:TOP_MODELS]]
    return choose_order(iou, candidates, az_index, views.spec.n_azimuths, config.order,
                        config.order_margin, config.spread_weight, similarity,
                        config.similarity_weight, progress.check if progress else None)


def _likeness(seen: _Seen) -> np.ndarray | None:
    """How alike the photos look (the order search's prior that neighbours look alike): their
    colours and outlines (``ordering.neighbour_similarity``), and the matches between them
    where the object has texture. None without the photos."""
    from cadnerf_core.retrieval.ordering import neighbour_similarity, standardised

    if seen.appearance is None:
        return None
    similarity = neighbour_similarity(list(seen.appearance[0]), list(seen.appearance[1]))
    if any(p.inliers for p in seen.pairs):  # shared points: the surest sign of neighbours
        shared = np.log1p(inlier_table(seen.pairs, len(seen.sizes)))
        similarity = similarity + standardised(shared)
    return similarity


def allowed_models(library: Library, exclude: Sequence[str]) -> np.ndarray:
    """Indices of the library models retrieval may choose: all but the ``exclude``d ids.

    Returns:
        [M'] int64, increasing.
    Raises:
        InputError: an id the library does not hold, or every model excluded.
    """
    known = {m.id for m in library.models}
    unknown = sorted(set(exclude) - known)
    if unknown:
        raise InputError(f"no model {', '.join(map(repr, unknown))} in the library",
                         item="retrieval.exclude_models",
                         hint=f"choose among {', '.join(sorted(known))}")
    allowed = np.array([i for i, m in enumerate(library.models) if m.id not in set(exclude)],
                       dtype=np.int64)
    if not len(allowed):
        raise InputError("every library model is excluded", item="retrieval.exclude_models")
    return allowed


@dataclass
class _Photos:
    """What retrieval needs of the photos, computed once for every silhouette set."""

    names: Sequence[str]
    sizes: list[tuple[int, int]]  # (height, width) of each photo
    crops: np.ndarray  # canonical masks [P, S, S]
    boxes: list[CropBox]  # photo -> canonical crop
    evidence: float  # texture evidence for the walking direction
    focals: Sequence[float | None] | None
    crop_size: int  # side of the crop that K_canon and box refer to
    allowed: np.ndarray  # [M'] library indices of the models that may be chosen
    pairs: list[PairMatch]  # the verified matches between photo pairs


def _retrieve_from(photos: _Photos, library: Library, config: RetrievalConfig,
                   progress: Progress | None, perspective: str,
                   steps: tuple[int, int]) -> RetrievalResult:
    """``retrieve`` against one silhouette set (``library`` is the set's own Library).
    ``steps``: (steps done before, total) of the "retrieval" stage; this search adds two."""
    spec = library.spec
    evidence = photos.evidence
    allowed = photos.allowed
    silhouettes = library.silhouettes
    if len(allowed) < len(silhouettes):
        silhouettes = silhouettes[allowed]
    iou = iou_table(photos.crops, silhouettes)  # [P, M', V]: model axis over ``allowed``
    voted, ranking = vote_models(iou)
    if progress is not None:
        progress.step("retrieval", steps[0] + 1, steps[1])
    az_index = azimuth_bins(library.az_el, spec.n_azimuths)
    m, found = choose_walk(iou, voted, ranking, az_index, spec.n_azimuths, config, evidence)
    ambiguous = (found.direction_lead is not None
                 and found.direction_lead < config.ambiguity_margin
                 and abs(evidence) < config.appearance_threshold)
    if ambiguous and found.direction < 0 and config.ambiguous_walk == "ccw":
        ccw = config.model_copy(update={"walk": "ccw"})
        lead = found.direction_lead
        m, found = choose_walk(iou, voted, ranking, az_index, spec.n_azimuths, ccw, evidence)
        found = dataclasses.replace(found, direction_lead=lead)
    models = [library.models[i] for i in allowed]
    top = [{"model_id": models[i].id, "category": models[i].category,
            "votes": votes, "score": score} for i, votes, score in ranking[:TOP_MODELS]]
    matches = _matches(photos, library, iou, m, found, config)
    log.info("retrieved %s (%s) with %s: %d of %d photos kept", models[m].id,
             models[m].category, config.solver, sum(not x.discarded for x in matches),
             len(matches))
    if progress is not None:
        progress.step("retrieval", steps[0] + 2, steps[1])
    others = [RetrievalResult(models[o].id, models[o].category, top,
                              _matches(photos, library, iou, o, walk, config), config.solver,
                              walk.direction, walk.score, evidence, perspective=perspective,
                              pairs=photos.pairs)
              for o, walk in alternatives(iou, ranking, az_index, spec.n_azimuths, config,
                                          evidence, (m, found.direction))]
    return RetrievalResult(models[m].id, models[m].category, top, matches, config.solver,
                           found.direction, found.score, evidence, found.direction_lead,
                           perspective=perspective, direction_ambiguous=ambiguous,
                           alternatives=others, pairs=photos.pairs)


def _matches(photos: _Photos, library: Library, iou: np.ndarray, m: int,
             found: PoseSearchResult, config: RetrievalConfig) -> list[PhotoMatch]:
    """Every photo's match to model ``m`` (an index into ``photos.allowed``) along the walk
    ``found``; a discarded photo keeps its own best view, flagged."""
    matches = []
    for p, view in enumerate(found.views):
        discarded = bool(view < 0)
        v = int(np.argmax(iou[p, m])) if discarded else int(view)
        b = photos.boxes[p]
        box = CropBox(b.x0, b.y0, b.side, photos.crop_size)
        matches.append(photo_match(library, int(photos.allowed[m]), p, photos.names[p], v,
                                   discarded, float(iou[p, m, v]), box))
    if config.shared_focal:
        matches = share_focal(matches, photos.sizes, photos.focals)
    return matches
