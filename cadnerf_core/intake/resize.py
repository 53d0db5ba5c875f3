"""Working copies of photos and masks: one rule for "about N pixels on the longer side".

Background removal, the mask checks and the stored overlays each work on a smaller copy so
that a 12-megapixel photo costs milliseconds; they share the size rule and the mask resize here.
"""

from __future__ import annotations

import cv2
import numpy as np


def fitted_size(shape: tuple[int, ...], side: int) -> tuple[int, int] | None:
    """(width, height) about ``side`` pixels on the longer side of an [H, W, ...] shape, or
    None where it already fits (a copy is never enlarged)."""
    height, width = shape[:2]
    scale = side / max(height, width)
    if scale >= 1.0:
        return None
    return max(1, round(width * scale)), max(1, round(height * scale))


def resized_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """[h, w] bool -> [height, width] bool through uint8 (no float copy): area averaging when
    shrinking, smooth edges when enlarging; a pixel is kept where over half of it is object."""
    shrink = width * height < mask.shape[0] * mask.shape[1]
    mode = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(mask.astype(np.uint8) * 255, (width, height), interpolation=mode) > 127


def shrunk_mask(mask: np.ndarray, side: int) -> np.ndarray:
    """[H, W] bool -> a bool copy about ``side`` pixels on its longer side (never enlarged)."""
    size = fitted_size(mask.shape, side)
    return mask if size is None else resized_mask(mask, *size)


def downscaled(rgb: np.ndarray, side: int) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8 copy about ``side`` on its longer side (never
    enlarged). Resized before conversion, so no full-size float copy is made."""
    size = fitted_size(rgb.shape, side)
    small = rgb if size is None else cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    return np.clip(small * 255.0 + 0.5, 0, 255).astype(np.uint8)
