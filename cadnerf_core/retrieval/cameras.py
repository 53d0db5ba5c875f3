"""A photo's camera from its library match, and one focal length shared by a walk.

A photo matched to view v of model m gets the camera ``c2w = library.poses[v]``, intrinsics
``K_canon`` in the canonical crop, and ``K_photo`` in its own pixels: exact, since both crops are
affine maps of pixel coordinates. With ``shared_focal`` the photos then share one focal length
(one camera walked round the object), each camera moved in or out so the object keeps its size.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from cadnerf_core.intake.crop import CropBox, crop_intrinsics, uncrop_intrinsics
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library


def photo_match(library: Library, m: int, p: int, name: str, view: int, discarded: bool,
                iou: float, box: CropBox) -> PhotoMatch:
    """Photo ``p``'s match to view ``view`` of library model ``m``: the view's pose, its
    intrinsics in the canonical crop ``box`` and in the photo's own pixels."""
    K_canon = library.canonical_K(m, view, box.size)
    azimuth, elevation = (float(x) for x in library.az_el[view])
    return PhotoMatch(p, name, view, azimuth, elevation, iou, discarded,
                      library.poses[view].copy(), K_canon, box, uncrop_intrinsics(K_canon, box))


FOCAL_SCALE_LIMITS = (0.5, 2.0)  # most a shared focal length moves a camera in or out


def share_focal(matches: Sequence[PhotoMatch], sizes: Sequence[tuple[int, int]],
                known: Sequence[float | None] | None = None) -> list[PhotoMatch]:
    """One focal length for every photo (``RetrievalConfig.shared_focal``).

    Args:
        matches: every photo's match, its focal length its own.
        sizes: (height, width) of every photo, in the matches' order.
        known: focal lengths in pixels the photos bring (their EXIF), None where unknown.
    Returns:
        The matches with one focal length per pixel of the photo's longer side: the median of
        the kept photos' known focal lengths where any is known, else of their matches'. Each
        camera is moved along its ray to the object's centre by the factor its focal length
        changed, so the object keeps its size in the photo (principal point and rotation
        unchanged; the factor limited to ``FOCAL_SCALE_LIMITS``).
    """
    kept = [m for m in matches if not m.discarded]
    given = [f / max(sizes[m.index]) for m in kept
             if known is not None and (f := known[m.index]) is not None]
    if len(kept) < 2 and not given:
        return list(matches)
    focal = float(np.median(given or [m.K_photo[0, 0] / max(sizes[m.index]) for m in kept]))
    out = []
    for m in matches:
        scale = float(np.clip(focal * max(sizes[m.index]) / m.K_photo[0, 0],
                              *FOCAL_SCALE_LIMITS))
        K_photo = m.K_photo.copy()
        K_photo[0, 0] *= scale
        K_photo[1, 1] *= scale
        c2w = m.c2w.copy()
        c2w[:3, 3] *= scale
        out.append(dataclasses.replace(m, c2w=c2w, K_photo=K_photo,
                                       K_canon=crop_intrinsics(K_photo, m.box)))
    return out


def angle_mismatch(result: RetrievalResult, library: Library,
                   focals: Sequence[float | None] | None) -> float:
    """How far the photos' perspective is from their matched views' (``perspective`` "auto").

    The median over the kept photos with a known focal length of |log(a_photo / a_view)|, a
    being the angle the object's canonical crop spans: crop side over focal length, in the
    photo and in the matched view's render. inf when no kept photo has a known focal length."""
    m = library.index(result.model_id)
    size = library.spec.silhouette_size
    logs = [abs(math.log((match.box.side / focal)
                         / (library.crop_box(m, match.view, size).side / library.K_render[0, 0])))
            for match in result.kept
            if focals is not None and (focal := focals[match.index]) is not None]
    return float(np.median(logs)) if logs else math.inf
