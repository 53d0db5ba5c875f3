"""What a photo or an uploaded mask must be for the pipeline to use it, and the working size.

Light on purpose (Pillow and numpy only): the web service checks uploads with these same rules
at the door, so a photo the worker cannot use is refused with a 422 naming it instead of failing
the job later. The reasons for each value are in ``docs/reliability.md`` ("Door checks").
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

MIN_SIDE = 64
"""Pixels: smaller photos hold too little of the object."""
MAX_PIXELS = 40_000_000
"""40 megapixels: larger photos are refused before decoding."""
MAX_ASPECT = 4.0
"""Longer over shorter side: a phone's widest photo (21:9) is 2.3; a strip beyond this holds
no walk-around view (and background removal cannot seed itself on it)."""
WORKING_PIXELS = 3_000_000
"""Photos are decoded and kept at most this many pixels (2000 x 1500 at 4:3, their aspect
kept): the canonical crops are at most 1024 px and masks are found on copies of about 512 px,
so more pixels only cost memory (a 40 MP photo as float32 RGB is 480 MB; at this size 36 MB)."""
MIN_COVER, MAX_COVER = 0.01, 0.95
"""A mask covering less (or, uploaded or found, more) of its photo marks no usable object."""
COVER_SIDE = 512
"""An uploaded mask's cover is measured on a copy about this many pixels on its longer side."""


def shape_problem(width: int, height: int) -> tuple[str, str] | None:
    """(message, hint) when a photo of this size cannot be used; None when it can.

    Checks the smallest side and the aspect ratio (the megapixel limit is checked first, from
    the header, by the callers).
    """
    if min(width, height) < MIN_SIDE:
        return (f"the photo is only {width}x{height} pixels",
                f"use photos at least {MIN_SIDE} pixels on each side")
    aspect = max(width, height) / min(width, height)
    if aspect > MAX_ASPECT:
        return (f"the photo is {width}x{height} pixels, {aspect:.1f} times longer than wide; "
                f"at most {MAX_ASPECT:g} is usable",
                "crop it to the object (a normal photo, not a strip or a panorama)")
    return None


def working_size(width: int, height: int) -> tuple[int, int]:
    """The (width, height) a photo of this size is worked on: itself up to ``WORKING_PIXELS``,
    else scaled down with its aspect kept."""
    if width * height <= WORKING_PIXELS:
        return width, height
    scale = math.sqrt(WORKING_PIXELS / (width * height))
    return max(1, int(width * scale)), max(1, int(height * scale))


def has_transparency(image: Image.Image) -> bool:
    """Whether an opened image carries an alpha channel or a transparent palette entry."""
    return image.mode in ("RGBA", "LA", "PA") or (
        image.mode == "P" and "transparency" in image.info)


def mask_array(image: Image.Image) -> np.ndarray:
    """A mask image as bool [H, W]: its alpha if it has real transparency, else nonzero pixels."""
    if has_transparency(image):
        alpha = np.asarray(image.convert("RGBA"))[..., 3]
        if (alpha < 128).any():
            return alpha >= 128
    return np.asarray(image.convert("L")) > 0


def mask_cover(image: Image.Image) -> float:
    """The fraction of its photo an (opened) mask image marks as object, measured on a copy
    of about ``COVER_SIDE`` pixels (nearest-neighbour: the mask's own values, no blending)."""
    scale = min(1.0, COVER_SIDE / max(image.size))
    if scale < 1.0:
        size = (max(1, round(image.width * scale)), max(1, round(image.height * scale)))
        image = image.resize(size, Image.Resampling.NEAREST)
    return float(mask_array(image).mean())


def cover_problem(cover: float) -> tuple[str, str] | None:
    """(message, hint) when an uploaded mask covering ``cover`` of its photo is unusable."""
    if cover < MIN_COVER:
        return (f"the uploaded mask marks {100 * cover:.1f}% of the photo as the object: "
                "almost nothing", "send a mask with the object white (or opaque) and the "
                "background black, or send no mask and let the service find the object")
    if cover > MAX_COVER:
        return (f"the uploaded mask marks {100 * cover:.1f}% of the photo as the object: "
                "almost no background is left", "send a mask with the background black (or "
                "transparent), or send no mask and let the service find the object")
    return None
