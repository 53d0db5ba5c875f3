"""Phone-style HEIC (and AVIF) test photos made in code from upright pixels, with EXIF."""

from __future__ import annotations

import io

import numpy as np
import pillow_heif
from PIL import Image

pillow_heif.register_heif_opener()

# EXIF orientation -> the transpose that turns upright pixels into the stored ones (the inverse
# of what a viewer applies: 6 is shown rotated 90 degrees clockwise, so it is stored rotated 90
# degrees counter-clockwise).
TO_STORED = {2: Image.Transpose.FLIP_LEFT_RIGHT, 3: Image.Transpose.ROTATE_180,
             4: Image.Transpose.FLIP_TOP_BOTTOM, 5: Image.Transpose.TRANSPOSE,
             6: Image.Transpose.ROTATE_90, 7: Image.Transpose.TRANSVERSE,
             8: Image.Transpose.ROTATE_270}


def stored_pixels(upright: np.ndarray, orientation: int) -> np.ndarray:
    """The pixels a camera stores for a photo shown as ``upright`` ([H, W] or [H, W, C])."""
    if orientation not in TO_STORED:
        return upright
    return np.asarray(Image.fromarray(upright).transpose(TO_STORED[orientation]))


def phone_photo(upright: np.ndarray, orientation: int = 6, focal_35mm: int | None = 26,
                fmt: str = "HEIF") -> bytes:
    """A photo file (HEIC, or ``fmt`` "AVIF") shown as ``upright`` [H, W, 3] uint8: its stored
    pixels are turned by the inverse of ``orientation``, which its EXIF carries with
    ``FocalLengthIn35mmFilm`` = ``focal_35mm`` (None: no focal length)."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    if focal_35mm is not None:
        exif.get_ifd(0x8769)[0xA405] = focal_35mm
    buffer = io.BytesIO()
    Image.fromarray(stored_pixels(upright, orientation)).save(
        buffer, format=fmt, exif=exif.tobytes(), quality=95)
    return buffer.getvalue()


def gradient(width: int, height: int) -> np.ndarray:
    """RGB uint8 [H, W, 3]: red grows to the right, green downward, a blue top-left corner, so
    any rotation or mirror of it differs from it."""
    x = np.linspace(0, 255, width)[None, :].repeat(height, 0)
    y = np.linspace(0, 255, height)[:, None].repeat(width, 1)
    rgb = np.stack([x, y, np.full_like(x, 60)], -1).astype(np.uint8)
    rgb[: height // 4, : width // 4, 2] = 255
    return rgb


def claiming_size(data: bytes, side: int) -> bytes:
    """The HEIC ``data`` with its header (the ``ispe`` box) claiming ``side`` x ``side`` pixels:
    a bomb that only a check made before decoding refuses cheaply."""
    at = data.index(b"ispe")
    size = side.to_bytes(4, "big")
    return data[:at + 8] + size + size + data[at + 16:]
