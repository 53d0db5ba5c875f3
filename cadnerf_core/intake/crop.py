"""The canonical crop: a square around the object's mask, with a fixed margin, resized.

Library silhouettes and user photos go through the same crop, so an object fills the frame the
same way whatever its distance or position in the photo. The crop is an affine map of pixel
coordinates (scale, then shift), so it composes exactly with a pinhole camera:
``K_crop = A @ K``. A match against a library view therefore gives the photo's camera exactly:
the library pose, with intrinsics ``A_photo^-1 @ A_view @ K_library`` in the photo's pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

DEFAULT_MARGIN = 0.1  # fraction of the crop side left free on each side of the object


@dataclass(frozen=True)
class CropBox:
    """A square window in source pixels, resized to ``size`` x ``size``.

    ``x0, y0`` is the window's top-left corner and ``side`` its side, in source pixels; the
    window may extend past the image (padding).
    """

    x0: float
    y0: float
    side: float
    size: int

    @property
    def scale(self) -> float:
        """Output pixels per source pixel."""
        return self.size / self.side

    def affine(self) -> np.ndarray:
        """[3, 3] map from source pixel coordinates to crop pixel coordinates."""
        s = self.scale
        return np.array([[s, 0.0, -s * self.x0], [0.0, s, -s * self.y0], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict[str, float]:
        return {"x0": self.x0, "y0": self.y0, "side": self.side, "size": self.size}


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box of a non-empty mask as (x_min, y_min, x_max, y_max), max exclusive."""
    rows = np.flatnonzero(mask.any(axis=1))  # not np.nonzero: 10x quicker on 12 MP masks
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) == 0:
        raise ValueError("empty mask has no bounding box")
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def canonical_box(mask: np.ndarray, size: int, margin: float = DEFAULT_MARGIN) -> CropBox:
    """The square window centred on the mask's bounding box, its larger side filling
    ``1 - 2 * margin`` of the window.

    Args:
        mask: [H, W] bool.
        size: output side in pixels.
        margin: free fraction of the window on each side.
    """
    x_min, y_min, x_max, y_max = mask_bbox(mask)
    extent = max(x_max - x_min, y_max - y_min)
    side = extent / (1.0 - 2.0 * margin)
    cx, cy = (x_min + x_max) / 2.0, (y_min + y_max) / 2.0
    return CropBox(cx - side / 2.0, cy - side / 2.0, side, size)


def apply_crop(image: np.ndarray, box: CropBox, interpolation: int | None = None,
               fill: float = 0.0) -> np.ndarray:
    """Resample ``image`` ([H, W] or [H, W, C]) into the crop window. Returns [size, size, ...].

    Bool masks are resampled as floats and thresholded at one half, so thin parts survive
    downscaling as they would in a rendered silhouette. Shrinking uses area averaging.
    """
    is_bool = image.dtype == bool
    src = image.astype(np.float32) if is_bool else image
    sx = sy = 1.0
    if box.scale < 1:
        # warpAffine has no area filter: shrink with INTER_AREA first, then warp what is left.
        h, w = src.shape[:2]
        new_w, new_h = max(1, round(w * box.scale)), max(1, round(h * box.scale))
        src = cv2.resize(src, (new_w, new_h), interpolation=cv2.INTER_AREA)
        sx, sy = new_w / w, new_h / h
    s = box.scale
    # Map from (possibly shrunk) source to output, in pixel-corner coordinates.
    lin = np.array([[s / sx, 0.0], [0.0, s / sy]])
    shift = np.array([-s * box.x0, -s * box.y0])
    # OpenCV maps pixel centres: out_c + .5 = lin @ (src_c + .5) + shift.
    M = np.concatenate([lin, (shift + lin @ np.array([0.5, 0.5]) - 0.5)[:, None]], axis=1)
    flags = cv2.INTER_LINEAR if interpolation is None else interpolation
    border = (fill,) * (src.shape[2] if src.ndim == 3 else 1)
    out = cv2.warpAffine(src, M, (box.size, box.size), flags=flags,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=border)
    return out > 0.5 if is_bool else out


def crop_intrinsics(K: np.ndarray, box: CropBox) -> np.ndarray:
    """Intrinsics of the crop of an image taken with ``K``. Returns [3, 3]."""
    return box.affine() @ K


def uncrop_intrinsics(K_crop: np.ndarray, box: CropBox) -> np.ndarray:
    """Intrinsics in the source image of a camera known in crop pixels. Returns [3, 3]."""
    return np.linalg.inv(box.affine()) @ K_crop
