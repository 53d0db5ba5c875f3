"""Background removal: one bool mask per photo, where it came from, and what looks wrong.

A photo's own mask (its alpha, or one the user uploaded) wins. Otherwise, by default, a learned
salient-object network (the small U-2-Net, see ``saliency``) runs on a 320-pixel copy of the
photo, then again on the object's box cut from the full photo, framed three ways (its maps
averaged: ``saliency.closer_look``); GrabCut refines that map at a working size of
``WORK_SIDE`` pixels, seeded from its levels (sure and probable object and background).
Without the network, GrabCut alone is seeded from a band along the image border. Either way
the component nearest the centre (weighted by size) is kept, its holes filled
(a learned mask keeps open the holes the network calls background: the gap under a spout), and
the result scaled back to the photo's size. ``mask_checks`` then warns about doubtful masks.

A learned mask also says where it is in doubt: the pixels on which the refined cut and the
network's first look at the whole photo disagree (background seen through a gap that the close
look took for object, or parts the cut dropped). Training can weigh them less in its
silhouette losses (``MasksConfig.doubt_weight``, ``TrainData.weights``), so that the other
views decide the shape there; by default they count in full, as measured.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Generator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as futures_wait
from contextlib import closing
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any, Literal, TypeVar

import cv2
import numpy as np
from scipy import ndimage

from cadnerf_core.errors import InputError
from cadnerf_core.intake import saliency
from cadnerf_core.intake.limits import MAX_COVER, MIN_COVER, cover_problem
from cadnerf_core.intake.mask_checks import mask_warnings, median_cover
from cadnerf_core.intake.photos import Photo
from cadnerf_core.intake.resize import downscaled, fitted_size, resized_mask
from cadnerf_core.jobfolder import MaskSource
from cadnerf_core.progress import Progress

log = logging.getLogger(__name__)
_S = TypeVar("_S")
_T = TypeVar("_T")

GRABCUT_SIDE = 320  # border-seeded GrabCut runs on a copy about this many pixels on a side
WORK_SIDE = 512  # the learned map is refined at about this many pixels on the longer side
BAND_SIDES, BAND_TOP_BOTTOM = 0.10, 0.05  # sure-background band, fractions of width, height
CENTRE_SIGMA = 0.3  # of each side: the centre prior that picks the object's component
GRABCUT_ITERATIONS = 5  # GrabCut from the border band alone
# GrabCut refining a saliency map: the map's levels seed it well, so three rounds reach what
# five do (mean IoU on the real sets unchanged to 0.001) at 0.1 s less a photo.
REFINE_ITERATIONS = 3
# Saliency levels seeding GrabCut: below SURE_BACKGROUND sure background, below OBJECT
# probable background, below SURE_OBJECT probable object, above it sure object.
SURE_BACKGROUND, OBJECT, SURE_OBJECT = 0.1, 0.5, 0.9
MIN_AGREEMENT = 0.75  # IoU with the network's own mask below which GrabCut's cut is dropped
DOUBT_SIDE = 1024  # the doubt map is kept at about this many pixels on the longer side
# Photos masked at once, each pass of the network on its share of the cores: the single-threaded
# parts of one photo (resizing its crop, GrabCut, the masks' clean-up) overlap the network's
# pass on the other, where one photo at a time would leave a core idle meanwhile.
PHOTOS_AT_ONCE = 2
CHECK_EVERY_S = 0.25  # how often a cancelled job is looked for while photos are masked
MASK_HINT = "upload a mask for this photo (white = object, black = background)"

MaskMethod = Literal["auto", "learned", "grabcut"]


@dataclass
class MaskResult:
    """One photo's mask, where it came from, and what looks wrong with it."""

    mask: np.ndarray  # [H, W] bool, the photo's own size (after EXIF orientation)
    source: MaskSource
    warnings: list[str] = field(default_factory=list)  # each names the photo and what to do
    # [h, w] bool over the whole photo at about DOUBT_SIDE px (its aspect ratio): pixels
    # whose side is in doubt; None for a photo's own mask and for GrabCut alone.
    doubt: np.ndarray | None = None


def largest_component(mask: np.ndarray, weight: np.ndarray | None = None,
                      sal: np.ndarray | None = None) -> np.ndarray:
    """The largest 8-connected component of ``mask`` with its holes filled. [H, W] bool.

    Args:
        mask: [H, W] bool.
        weight: optional [H, W] per-pixel weight; the component of largest total weight wins.
        sal: optional [H, W] saliency in [0, 1]: a hole stays open where the map calls it
            background on average (the gap under a spout or between a handle and its body),
            and is filled where it calls it object.
    """
    labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return mask.copy()
    pixels = np.ones(mask.shape) if weight is None else weight
    sizes = ndimage.sum(pixels, labels, index=np.arange(1, count + 1))
    component = labels == int(np.argmax(sizes)) + 1
    filled = np.asarray(ndimage.binary_fill_holes(component), dtype=bool)
    if sal is None:
        return filled
    holes, n_holes = ndimage.label(filled & ~component)
    if n_holes == 0:
        return filled
    seen = ndimage.mean(sal, holes, index=np.arange(1, n_holes + 1))
    open_holes = np.flatnonzero(np.asarray(seen) <= OBJECT) + 1
    return filled & ~np.isin(holes, open_holes)


def border_band(shape: tuple[int, int]) -> np.ndarray:
    """Bool [H, W] band along the image edge taken as sure background.

    ``BAND_SIDES`` of the width on the left and right, ``BAND_TOP_BOTTOM`` of the height at the
    top and bottom: people frame an object centred, with more room beside it than above.
    """
    height, width = shape
    dx = max(2, round(BAND_SIDES * width))
    dy = max(2, round(BAND_TOP_BOTTOM * height))
    band = np.ones(shape, dtype=bool)
    band[dy:height - dy, dx:width - dx] = False
    return band


def centre_weight(shape: tuple[int, int]) -> np.ndarray:
    """Gaussian weight [H, W] peaking at the image centre (sigma = 0.3 of each side)."""
    height, width = shape
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.exp(-0.5 * (((x - width / 2) / (CENTRE_SIGMA * width)) ** 2
                          + ((y - height / 2) / (CENTRE_SIGMA * height)) ** 2))


def _run_grabcut(image: np.ndarray, seeds: np.ndarray,
                 iterations: int = GRABCUT_ITERATIONS) -> np.ndarray | None:
    """GrabCut from a seed map (cv2.GC_* labels). -> [h, w] bool of what it keeps, or None
    when the seeds lack an object or a background to learn colours from."""
    has_object = np.isin(seeds, (cv2.GC_FGD, cv2.GC_PR_FGD)).any()
    if not has_object or not np.isin(seeds, (cv2.GC_BGD, cv2.GC_PR_BGD)).any():
        return None
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # GrabCut's k-means: same photo, same mask
    cv2.grabCut(image, seeds, (0, 0, 1, 1), bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    return (seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)


def _grabcut(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GrabCut seeded from the border band. image [h, w, 3] uint8 -> (object, all kept) [h, w]
    bool: the band is sure background, the rest probable object; of what GrabCut keeps, the
    component with the most centre weight is the object."""
    seeds = np.full(image.shape[:2], cv2.GC_PR_FGD, dtype=np.uint8)
    seeds[border_band(image.shape[:2])] = cv2.GC_BGD
    found = _run_grabcut(image, seeds)
    if found is None:
        found = np.zeros(image.shape[:2], bool)
    return largest_component(found, centre_weight(image.shape[:2])), found


def refine_saliency(image: np.ndarray, sal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GrabCut seeded from a saliency map's levels, then the centre-weighted component.

    Args:
        image: [h, w, 3] uint8 working copy of the photo.
        sal: [h, w] float saliency in [0, 1].
    Returns:
        (object, all kept) [h, w] bool. The network's own mask (``sal > OBJECT``) is kept
        instead when GrabCut's cut agrees with it less than ``MIN_AGREEMENT`` (IoU).
    """
    weight = centre_weight(sal.shape)
    own = sal > OBJECT
    seeds = np.full(sal.shape, cv2.GC_PR_BGD, dtype=np.uint8)
    seeds[own] = cv2.GC_PR_FGD
    seeds[sal < SURE_BACKGROUND] = cv2.GC_BGD
    seeds[sal > SURE_OBJECT] = cv2.GC_FGD
    found = _run_grabcut(image, seeds, REFINE_ITERATIONS)
    if found is not None:
        cut = largest_component(found, weight, sal)
        union = (cut | own).sum()
        if union and (cut & own).sum() / union >= MIN_AGREEMENT:
            return cut, found
    return largest_component(own, weight, sal), own


def _learned(rgb: np.ndarray, session: Any, stop: threading.Event | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network's object: a first pass on the whole photo finds it; passes on its box
    (cut from the full photo, about ``WORK_SIDE`` pixels, ``saliency.closer_look``) see it
    closer, and GrabCut refines their map. The working resolution is spent on the object,
    not on the scene.

    Returns:
        mask [H, W] bool; the first pass's salient pixels [h, w] bool (the whole photo); and
        the doubt map (``doubt_map``) [h', w'] bool over the whole photo at ``DOUBT_SIDE``.
    """
    height, width = rgb.shape[:2]
    image = downscaled(rgb, WORK_SIDE)
    first = cv2.resize(saliency.predict(session, image), (image.shape[1], image.shape[0]))
    salient = first > OBJECT
    coarse = largest_component(salient, centre_weight(first.shape))
    doubt_size = fitted_size(rgb.shape, DOUBT_SIDE) or (width, height)
    if not coarse.any():
        return np.zeros((height, width), bool), salient, np.zeros(doubt_size[::-1], bool)
    crop, (top, bottom, left, right), sal = saliency.closer_look(session, rgb, coarse, WORK_SIDE,
                                                                  stop=stop)
    cut = refine_saliency(crop, sal)[0]
    mask = np.zeros((height, width), bool)
    mask[top:bottom, left:right] = resized_mask(cut, right - left, bottom - top)
    doubt = doubt_map(cut, first, (top / height, bottom / height, left / width, right / width),
                      doubt_size)
    return mask, salient, doubt


def doubt_map(cut: np.ndarray, first: np.ndarray, box: tuple[float, float, float, float],
              size: tuple[int, int]) -> np.ndarray:
    """Where a learned mask is in doubt: inside the object's box, the pixels on which the
    refined ``cut`` and the first pass's map (``first > OBJECT``) disagree.

    Args:
        cut: [hc, wc] bool, the refined object inside the box.
        first: [h, w] float, the first pass's map over the whole photo.
        box: (top, bottom, left, right) of the box, fractions of the photo's height, width.
        size: (width, height) of the map to return.
    Returns:
        [height, width] bool over the whole photo (outside the box: False).
    """
    width, height = size
    top, bottom = round(box[0] * height), round(box[1] * height)
    left, right = round(box[2] * width), round(box[3] * width)
    doubt = np.zeros((height, width), bool)
    if bottom <= top or right <= left:
        return doubt
    fh, fw = first.shape
    seen = cv2.resize(first[int(box[0] * fh):max(int(box[0] * fh) + 1, round(box[1] * fh)),
                            int(box[2] * fw):max(int(box[2] * fw) + 1, round(box[3] * fw))],
                      (right - left, bottom - top), interpolation=cv2.INTER_LINEAR) > OBJECT
    doubt[top:bottom, left:right] = resized_mask(cut, right - left, bottom - top) != seen
    return doubt


def check_cover(mask: np.ndarray, name: str, automatic: bool) -> None:
    """Raise InputError naming the photo when a mask covers too little or too much of it
    (``limits.MIN_COVER``, ``limits.MAX_COVER``: the same rule the service applies to uploaded
    masks at the door).

    Args:
        mask: [H, W] bool.
        name: the photo's name.
        automatic: the mask came from background removal (else it was uploaded or is the
            photo's own alpha, where only too little is refused).
    """
    cover = float(mask.mean())
    if not automatic and cover < MIN_COVER:
        raise InputError(f"the mask covers {100 * cover:.1f}% of the photo, too little of an "
                         "object", item=name, hint="check the mask")
    if automatic and cover < MIN_COVER:
        raise InputError(f"background removal found {100 * cover:.1f}% of the photo, too "
                         "little of an object", item=name, hint=MASK_HINT)
    if automatic and cover > MAX_COVER:
        raise InputError(f"background removal kept {100 * cover:.1f}% of the photo: it could "
                         "not tell the object from the background", item=name, hint=MASK_HINT)


def check_uploaded(mask: np.ndarray, name: str) -> None:
    """Raise InputError naming the photo when an uploaded mask [H, W] bool marks almost none
    or almost all of it (``limits.cover_problem``, the service's door check)."""
    problem = cover_problem(float(mask.mean()))
    if problem is not None:
        raise InputError(problem[0], item=name, hint=problem[1])


def found_mask(photo: Photo, method: Literal["grabcut", "learned"], session: Any = None,
               stop: threading.Event | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Find the object in a photo (its own mask, if any, is ignored here).

    Args:
        photo: the photo.
        method: "grabcut" (border-seeded) or "learned" (``session``: a saliency model from
            ``saliency.load_model``).
    Returns:
        mask [H, W] bool; everything the method kept before the object's component was
        chosen, [h, w] bool at its working size (for the second-object check); and where the
        mask is in doubt (``MaskResult.doubt``; None for GrabCut alone).
    Raises:
        InputError: naming the photo if the mask covers < 1% or > 95% of it.
    """
    height, width = photo.rgb.shape[:2]
    doubt = None
    if method == "learned":
        mask, kept, doubt = _learned(photo.rgb, session, stop)
    else:
        small, kept = _grabcut(downscaled(photo.rgb, GRABCUT_SIDE))
        mask = resized_mask(small, width, height)
    check_cover(mask, photo.name, automatic=True)
    return mask, kept, doubt


def remove_background(photo: Photo, method: Literal["grabcut", "learned"] = "grabcut",
                      model_path: Path | None = None) -> np.ndarray:
    """The object's mask [H, W] bool in one photo; see ``found_mask``. ``model_path``: a
    local ONNX saliency model for "learned" (None: the bundled one); never downloaded."""
    session = saliency.load_model(model_path) if method == "learned" else None
    return found_mask(photo, method, session)[0]


def resolve_method(method: MaskMethod, model_path: Path | None) -> Literal["learned", "grabcut"]:
    """The method that runs: "auto" is learned when a model is given or bundled, else GrabCut."""
    if method not in ("auto", "learned", "grabcut"):
        raise InputError(f"unknown background removal method {method!r}", item="masks",
                         hint="use 'auto', 'learned' or 'grabcut'")
    if method == "auto":
        return "learned" if model_path is not None or saliency.learned_available() else "grabcut"
    return method


def _one_mask(photo: Photo, chosen: Literal["learned", "grabcut"], session: Any,
              stop: threading.Event | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, MaskSource]:
    """One photo's mask, what the method kept, its doubt map and its source: the photo's own
    mask (checked) where it has one, else a found one (``found_mask``)."""
    if photo.mask is not None:
        if photo.mask_source in (None, "uploaded"):
            check_uploaded(photo.mask, photo.name)
        else:
            check_cover(photo.mask, photo.name, automatic=False)
        return photo.mask, photo.mask, None, photo.mask_source or "uploaded"
    mask, raw, doubt = found_mask(photo, chosen, session, stop)
    log.debug("%s: background removed (%s), %.1f%% kept", photo.name, chosen, 100 * mask.mean())
    return mask, raw, doubt, chosen


def in_order(work: Callable[[_S], _T], items: Sequence[_S], workers: int,
             check: Callable[[], None] | None = None, stop: threading.Event | None = None
             ) -> Generator[_T, None, None]:
    """``work`` on each item (a photo), yielded in the items' order, with up to ``workers``
    in hand at once. An item's error is raised when its turn comes, so the first bad photo in
    the given order is the one named; when the caller stops early (a cancelled job), the
    items not started are dropped and those running are waited for. ``check`` (raising to
    cancel) is called every ``CHECK_EVERY_S`` while an item runs; ``stop`` is set on the way
    out, for the running items to end early (``saliency.closer_look`` looks at it)."""
    if workers <= 1:
        yield from map(work, items)
        return
    pool = ThreadPoolExecutor(workers, thread_name_prefix="masks")
    stop = stop or threading.Event()
    waiting = iter(items)
    running: deque[Future[_T]] = deque(pool.submit(work, p) for p in islice(waiting, workers))
    try:
        while running:
            while check is not None and not running[0].done():
                check()
                futures_wait([running[0]], timeout=CHECK_EVERY_S)
            done = running.popleft().result()
            running.extend(pool.submit(work, item) for item in islice(waiting, 1))  # the next
            yield done
    finally:
        stop.set()
        for future in running:
            future.cancel()
        pool.shutdown(wait=True)


def photo_masks(photos: Sequence[Photo], method: MaskMethod = "auto",
                model_path: Path | None = None,
                progress: Progress | None = None) -> list[MaskResult]:
    """Each photo's mask: its own (alpha or uploaded) if it has one, else a found one.

    Args:
        photos: N photos.
        method: background removal for photos without a mask ("auto": learned where the
            model is installed, else GrabCut).
        model_path: a local ONNX saliency model for the learned method (None: the bundled one).
        progress: reports stage "masks" after each photo and checks for cancellation.
    Returns:
        N results: mask [H_i, W_i] bool, its source, warnings (see ``mask_checks``), and
        where a learned mask is in doubt.
    Raises:
        InputError: an unusable mask (too little or too much of the photo), or an unknown
            method, or a model file that is missing or unreadable.
    """
    chosen = resolve_method(method, model_path)
    needs_model = chosen == "learned" and any(p.mask is None for p in photos)
    workers = min(PHOTOS_AT_ONCE, len(photos))
    session = saliency.load_model(model_path, saliency.pass_threads(workers)) \
        if needs_model else None
    masks: list[np.ndarray] = []
    kept: list[np.ndarray] = []
    doubts: list[np.ndarray | None] = []
    sources: list[MaskSource] = []
    stop = threading.Event()
    with closing(in_order(lambda photo: _one_mask(photo, chosen, session, stop), photos,
                          workers, None if progress is None else progress.check,
                          stop)) as found:
        for i, (mask, raw, doubt, source) in enumerate(found):
            masks.append(mask)
            kept.append(raw)
            doubts.append(doubt)
            sources.append(source)
            if progress is not None:
                progress.step("masks", i + 1, len(photos))
    median = median_cover(masks)
    return [MaskResult(mask, source, mask_warnings(photo.name, mask, raw, median), doubt)
            for photo, mask, raw, source, doubt in zip(photos, masks, kept, sources, doubts,
                                                       strict=True)]


def mask_overlay(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A picture of the mask over its photo: the background dimmed and tinted blue, the
    object's outline drawn in yellow, so a cut is judged at a glance.

    Args:
        rgb: [H, W, 3] float in [0, 1] or uint8.
        mask: [H, W] bool.
    Returns:
        [H, W, 3] uint8.
    """
    image = rgb if rgb.dtype == np.uint8 else np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
    out = image.copy()
    tint = np.array([20, 60, 160], np.float32)
    out[~mask] = (0.4 * image[~mask] + 0.6 * tint).astype(np.uint8)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_SIMPLE)
    thickness = max(2, round(max(mask.shape) / 300))
    cv2.drawContours(out, contours, -1, (255, 220, 0), thickness, lineType=cv2.LINE_AA)
    return out
