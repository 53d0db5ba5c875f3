"""The cameras stage: every photo's camera from what the photos share and what retrieval found.

A controller over small estimators, in the order a job runs them (as glomap's and COLMAP's
controllers call theirs): the verified pairs (``matches``, before retrieval, which reads their
walking direction and order) feed COLMAP's mapper (``mapper``); where it registers the photos
their cameras are carried into the CAD frame (``placement``); otherwise the retrieved cameras
are fused with the pairs' rotations and with the mapper's cameras of the photos it did
register (``fusion``). Last, the start's hypotheses are given a
short silhouette fit and the best is kept (``start``). ``cadnerf retrieve`` and a job both go
through ``place_cameras`` and ``start.choose_start``, so they start from the same cameras.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cadnerf_core.config import PipelineConfig
    from cadnerf_core.retrieval.result import RetrievalResult

log = logging.getLogger(__name__)


def place_cameras(retrieval: RetrievalResult, pairs: list[Any], photos: list[Any],
                  config: PipelineConfig, focal_known: bool) -> RetrievalResult:
    """The retrieved cameras (and their hypotheses) started from what the photos' matches
    tell, the pairs far from the retrieved cameras left out (``prior.plausible``): the
    mapper's cameras where it registers every photo (``mapper.complete``), else the
    retrieved cameras fused with the pairs' rotations and, as one rigid set, the cameras of the
    photos the mapper did register (``fusion.fuse``); unchanged when neither is asked for.

    Args:
        retrieval: the silhouette retrieval (model, library views, hypotheses).
        pairs: the verified pairs (``matches.PairMatch``) of the photos.
        photos: the job's photos (``intake.photos.Photo``), in upload order.
        config: the job's configuration.
        focal_known: whether EXIF (or the client) gave the focal length.
    Returns:
        The retrieval with its cameras placed.
    """
    from cadnerf_core.cameras.fusion import fuse_hypotheses, pairs_at_focal
    from cadnerf_core.cameras.mapper import accept, complete, map_photos
    from cadnerf_core.cameras.placement import place_hypotheses
    from cadnerf_core.cameras.prior import plausible

    matches = config.retrieval.matches
    partial = None
    if matches.mapper:
        sizes = [(p.rgb.shape[1], p.rgb.shape[0]) for p in photos]
        start = photos[0].focal_pixels if focal_known else None
        focal = float(start or retrieval.matches[0].K_photo[0, 0])
        clock = time.perf_counter()
        # Pairs far from the retrieved cameras fold a reconstruction (``prior.PRIOR_DEG``).
        mapped = map_photos(plausible(retrieval, pairs), sizes, focal, focal_known,
                            matches.min_inliers)
        trusted = accept(mapped, max(sizes[0]))
        log.info("mapper: %s in %.1f s%s", "accepted" if trusted else "not used",
                 time.perf_counter() - clock, "" if mapped is None else
                 f" ({len(mapped.photos)} photos, {mapped.points} points, "
                 f"{mapped.reprojection_px:.2f} px, focal {mapped.focal:.0f} px, "
                 f"radial {mapped.radial:+.2f})")
        if trusted and mapped is not None and complete(mapped, len(photos)):
            placed = place_hypotheses(retrieval, mapped, focal_known)
            return placed if focal_known else pairs_at_focal(placed)
        partial = mapped if trusted else None
    if not matches.fuse:
        return retrieval
    retrieval = fuse_hypotheses(retrieval, matches.min_inliers, search_focal=not focal_known,
                                mapped=partial)
    return retrieval if focal_known else pairs_at_focal(retrieval)
