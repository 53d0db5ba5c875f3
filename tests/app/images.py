"""Test images made in code."""

from __future__ import annotations

import io

from PIL import Image


def image_bytes(size: tuple[int, int] = (80, 64), fmt: str = "PNG", color: int = 90,
                mode: str = "RGB") -> bytes:
    """A small image with a dark square (the object) on white."""
    image = Image.new(mode, size, "white" if mode != "L" else 255)
    w, h = size
    image.paste(color if mode == "L" else (color, color, color),
                (w // 4, h // 4, 3 * w // 4, 3 * h // 4))
    buffer = io.BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()


def mask_bytes(size: tuple[int, int] = (80, 64), fmt: str = "PNG",
               cover: tuple[float, float, float, float] = (0.25, 0.25, 0.75, 0.75)) -> bytes:
    """A mask image: black (background) with a white box (the object) spanning the fractions
    ``cover`` = (left, top, right, bottom) of the image; (0, 0, 1, 1) is all white."""
    image = Image.new("L", size, 0)
    w, h = size
    left, top, right, bottom = cover
    if right > left and bottom > top:
        image.paste(255, (round(left * w), round(top * h), round(right * w), round(bottom * h)))
    buffer = io.BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()
