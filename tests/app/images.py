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
