"""Background removal: one bool mask per photo.

A photo's own mask (its alpha, or one the user uploaded) wins. Otherwise OpenCV GrabCut, which
needs no downloaded weights: it runs on a copy downscaled to about 320 pixels, seeded with a
band along the image border as sure background and the centre as probable foreground. The
result is cleaned to one connected component (the one nearest the centre, weighted by size)
with holes filled, then scaled back up. On cluttered real scenes it is rough (the retrieval
benchmark scores it against real photos' own masks): an uploaded mask or alpha is better. A
learned remover (a U2Net-style ONNX model, as used by ``rembg``) can be used instead, only from
weights already on disk.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from scipy import ndimage

from cadnerf_core.errors import InputError
from cadnerf_core.intake.photos import Photo
from cadnerf_core.jobfolder import MaskSource
from cadnerf_core.progress import Progress

log = logging.getLogger(__name__)

WORK_SIDE = 320  # GrabCut runs on a copy about this many pixels on its longer side
MIN_COVER, MAX_COVER = 0.01, 0.95  # a found mask outside these fractions is not trusted
BAND_SIDES, BAND_TOP_BOTTOM = 0.10, 0.05  # sure-background band, fractions of width, height
CENTRE_SIGMA = 0.3  # of each side: the centre prior that picks the object's component
GRABCUT_ITERATIONS = 5
MASK_HINT = "upload a mask for this photo (white = object, black = background)"

MaskMethod = Literal["auto", "learned", "grabcut"]


@dataclass
class MaskResult:
    """One photo's mask, where it came from, and what looks wrong with it."""

    mask: np.ndarray  # [H, W] bool, the photo's own size (after EXIF orientation)
    source: MaskSource
    warnings: list[str] = field(default_factory=list)  # each names the photo and what to do


def largest_component(mask: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """The largest 8-connected component of ``mask`` with its holes filled. [H, W] bool.

    Args:
        mask: [H, W] bool.
        weight: optional [H, W] per-pixel weight; the component of largest total weight wins.
    """
    labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return mask.copy()
    pixels = np.ones(mask.shape) if weight is None else weight
    sizes = ndimage.sum(pixels, labels, index=np.arange(1, count + 1))
    return np.asarray(ndimage.binary_fill_holes(labels == int(np.argmax(sizes)) + 1), dtype=bool)


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


def _grabcut(image: np.ndarray) -> np.ndarray:
    """GrabCut seeded from the border band. image [h, w, 3] uint8 -> [h, w] bool.

    The band is sure background, everything inside it probable foreground; of what GrabCut
    keeps, the component with the most centre weight is the object.
    """
    band = border_band(image.shape[:2])
    seeds = np.full(image.shape[:2], cv2.GC_PR_FGD, dtype=np.uint8)
    seeds[band] = cv2.GC_BGD
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # GrabCut's k-means: same photo, same mask
    cv2.grabCut(image, seeds, (0, 0, 1, 1), bgd, fgd, GRABCUT_ITERATIONS, cv2.GC_INIT_WITH_MASK)
    found = (seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)
    return largest_component(found, centre_weight(image.shape[:2]))


def _learned(rgb: np.ndarray, weights: Path) -> np.ndarray:
    """Saliency from a U2Net-style ONNX model (rembg's pre/post-processing). -> [H, W] bool."""
    try:
        import onnxruntime as ort  # type: ignore[import-not-found]
    except ImportError as exc:
        raise InputError("the learned background remover needs onnxruntime", item="masks",
                         hint="pip install onnxruntime, or use method 'grabcut'") from exc
    session = ort.InferenceSession(str(weights), providers=["CPUExecutionProvider"])
    small = np.asarray(cv2.resize(rgb, (320, 320), interpolation=cv2.INTER_AREA), np.float64)
    scaled = small / max(float(small.max()), 1e-6)
    mean, std = np.array([0.485, 0.456, 0.406]), np.array([0.229, 0.224, 0.225])
    batch = ((scaled - mean) / std).transpose(2, 0, 1)[None].astype(np.float32)
    pred = session.run(None, {session.get_inputs()[0].name: batch})[0][0, 0]
    pred = (pred - pred.min()) / max(float(pred.max() - pred.min()), 1e-6)
    full = cv2.resize(pred.astype(np.float32), (rgb.shape[1], rgb.shape[0]))
    return largest_component(full > 0.5)


def _downscaled(rgb: np.ndarray) -> np.ndarray:
    """[H, W, 3] float -> uint8 copy about ``WORK_SIDE`` on its longer side (never enlarged)."""
    scale = min(1.0, WORK_SIDE / max(rgb.shape[:2]))
    size = (max(1, round(rgb.shape[1] * scale)), max(1, round(rgb.shape[0] * scale)))
    small = cv2.resize(rgb.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    return np.clip(small * 255.0 + 0.5, 0, 255).astype(np.uint8)


def check_cover(mask: np.ndarray, name: str, automatic: bool) -> None:
    """Raise InputError naming the photo when a mask covers too little (or, if found
    automatically, too much) of it.

    Args:
        mask: [H, W] bool.
        name: the photo's name.
        automatic: the mask came from background removal (then > 95% is refused too).
    """
    cover = float(mask.mean())
    if cover < MIN_COVER:
        what = "background removal found" if automatic else "the mask covers"
        raise InputError(f"{what} {100 * cover:.1f}% of the photo, too little of an object",
                         item=name, hint=MASK_HINT if automatic else "check the mask")
    if automatic and cover > MAX_COVER:
        raise InputError(f"background removal kept {100 * cover:.1f}% of the photo: it could "
                         "not tell the object from the background", item=name, hint=MASK_HINT)


def remove_background(photo: Photo, method: Literal["grabcut", "learned"] = "grabcut",
                      weights: str | Path | None = None) -> np.ndarray:
    """Find the object in a photo.

    Args:
        photo: the photo (its own mask, if any, is ignored here).
        method: "grabcut" (built in) or "learned" (an ONNX saliency model at ``weights``).
        weights: local path of the learned model's weights; never downloaded.
    Returns:
        mask: [H, W] bool.
    Raises:
        InputError: naming the photo if the mask covers < 1% or > 95% of it, or if the
            learned model's weights are missing.
    """
    height, width = photo.rgb.shape[:2]
    if method == "learned":
        if weights is None or not Path(weights).is_file():
            raise InputError(f"no weights for the learned background remover at {weights}",
                             item=photo.name, hint="give the path of a local ONNX model, or "
                             "use method 'grabcut'")
        mask = _learned(photo.rgb, Path(weights))
    elif method == "grabcut":
        small = _grabcut(_downscaled(photo.rgb))
        mask = cv2.resize(small.astype(np.float32), (width, height),
                          interpolation=cv2.INTER_LINEAR) > 0.5
    else:
        raise InputError(f"unknown background removal method {method!r}", item="masks",
                         hint="use 'grabcut' or 'learned'")
    check_cover(mask, photo.name, automatic=True)
    return mask


def photo_masks(photos: Sequence[Photo], method: MaskMethod = "auto",
                model_path: Path | None = None,
                progress: Progress | None = None) -> list[MaskResult]:
    """Each photo's mask: its own (alpha or uploaded) if it has one, else a found one.

    Args:
        photos: N photos.
        method: background removal for photos without a mask ("auto": GrabCut).
        model_path: a local ONNX saliency model, for "learned".
        progress: reports stage "masks" after each photo and checks for cancellation.
    Returns:
        N results: mask [H_i, W_i] bool, its source, warnings.
    """
    results = []
    for i, photo in enumerate(photos):
        if photo.mask is not None:
            check_cover(photo.mask, photo.name, automatic=False)
            results.append(MaskResult(photo.mask, photo.mask_source or "uploaded"))
        else:
            found: Literal["learned", "grabcut"] = "learned" if method == "learned" else "grabcut"
            results.append(MaskResult(remove_background(photo, found, model_path), found))
            log.debug("%s: background removed, %.1f%% kept", photo.name,
                      100 * results[-1].mask.mean())
        if progress is not None:
            progress.step("masks", i + 1, len(photos))
    return results
