"""Checks on a usable mask that still looks doubtful: warnings, not errors.

Each warning names the photo and says what to do (crop, retake, or upload a mask), since the
user cannot tell from a failed job that the object was cut badly. A mask that is unusable
(too little or too much of the photo) is refused earlier, in ``masks.check_cover``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from cadnerf_core.intake.resize import shrunk_mask

ALMOST_EMPTY = 0.03  # of the photo: the object is small (under 1% is refused outright)
ALMOST_FULL = 0.80  # of the photo: little background is left to tell the object by
EDGE_TOUCH = 0.02  # of an image edge's pixels in the mask: the object runs off that edge
MAX_EDGES = 3  # touching this many edges or more: the object is cut off or it is background
AREA_RATIO = 3.0  # cover this many times above or below the set's median: unlike the others
SECOND_OBJECT = 0.25  # a second component at least this fraction of the largest one's area
SECOND_MIN_COVER = 0.005  # ... and of the photo, so that specks do not count
CHECK_SIDE = 512  # masks are checked on a copy about this many pixels on its longer side
MIN_PHOTOS_FOR_MEDIAN = 3  # fewer photos: no median to compare with
UPLOAD = "or upload a mask for it (white = object, black = background)"


def median_cover(masks: Sequence[np.ndarray]) -> float | None:
    """The median fraction of its photo that a mask covers; None under 3 masks."""
    if len(masks) < MIN_PHOTOS_FOR_MEDIAN:
        return None
    return float(np.median([float(m.mean()) for m in masks]))


def edges_touched(mask: np.ndarray) -> list[str]:
    """The image edges (top, bottom, left, right) along which the mask [H, W] bool covers
    more than ``EDGE_TOUCH`` of the pixels."""
    edges = {"top": mask[0], "bottom": mask[-1], "left": mask[:, 0], "right": mask[:, -1]}
    return [name for name, line in edges.items() if float(line.mean()) > EDGE_TOUCH]


def second_object(kept: np.ndarray) -> bool:
    """True when, besides its largest component, ``kept`` [h, w] bool holds another one at
    least ``SECOND_OBJECT`` of its area and ``SECOND_MIN_COVER`` of the image."""
    labels, count = ndimage.label(kept, structure=np.ones((3, 3), dtype=bool))
    if count < 2:
        return False
    sizes = np.sort(np.bincount(labels.ravel())[1:])[::-1]
    return bool(sizes[1] >= SECOND_OBJECT * sizes[0]
                and sizes[1] >= SECOND_MIN_COVER * kept.size)


def mask_warnings(name: str, mask: np.ndarray, kept: np.ndarray | None = None,
                  median: float | None = None) -> list[str]:
    """What looks wrong with one photo's mask, each line naming the photo and what to do.

    Args:
        name: the photo's name.
        mask: [H, W] bool, the mask that will be used.
        kept: [h, w] bool, everything background removal kept before one component was chosen
            (an uploaded mask itself); None skips the second-object check.
        median: the set's median cover (``median_cover``); None skips the comparison.
    Returns:
        Warnings, empty when the mask looks fine.
    """
    cover = float(mask.mean())
    found: list[str] = []
    if cover < ALMOST_EMPTY:
        found.append(f"{name}: the object covers only {100 * cover:.1f}% of the photo: crop "
                     f"the photo closer around it or retake it from nearer, {UPLOAD}")
    if cover > ALMOST_FULL:
        found.append(f"{name}: the mask covers {100 * cover:.0f}% of the photo, so the "
                     f"background was probably kept: retake it with space around the object, "
                     f"{UPLOAD}")
    edges = edges_touched(shrunk_mask(mask, CHECK_SIDE))
    if len(edges) >= MAX_EDGES:
        found.append(f"{name}: the mask runs off the {', '.join(edges)} edges of the photo: "
                     f"retake it with the whole object in view, {UPLOAD}")
    if median is not None and median > 0 and not (
            median / AREA_RATIO <= cover <= median * AREA_RATIO):
        found.append(f"{name}: the mask covers {100 * cover:.1f}% of the photo against "
                     f"{100 * median:.1f}% for the set's median: check its overlay; crop or "
                     f"retake it at the others' distance, {UPLOAD}")
    if kept is not None and second_object(shrunk_mask(kept, CHECK_SIDE)):
        found.append(f"{name}: a second object of similar size was found beside the one kept: "
                     f"check its overlay; crop the photo to the object or retake it, {UPLOAD}")
    return found
