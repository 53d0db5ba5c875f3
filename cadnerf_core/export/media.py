"""Image and video writers: PNG views, the H.264 orbit video and its GIF, atomically.

The video is tagged and converted as BT.709 (limited range), the colour space browsers and
players assume for HD video, so its colours match the PNG views; its index (``moov``) comes
first so a browser starts playing before the download ends.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from cadnerf_core.jobfolder import atomic_path

GIF_MAX_FPS = 15
"""The GIF keeps every k-th frame so that it plays at most this many frames a second (same
length as the video; more frames only make the file larger)."""

GIF_MAX_SIDE = 320
"""Longest side of the GIF in pixels: a preview to share; the MP4 is the sharp one."""

BT709 = ["-vf", "scale=out_color_matrix=bt709:out_range=tv,format=yuv420p",
         "-colorspace", "bt709", "-color_primaries", "bt709", "-color_trc", "bt709",
         "-color_range", "tv"]
"""ffmpeg options: convert RGB with the BT.709 matrix and say so in the stream."""


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8."""
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an [H, W, 3] float image as PNG, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(to_uint8(rgb), "RGB").save(tmp, format="PNG")


def write_video(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """H.264 MP4 (yuv420p, BT.709, moov atom first), atomically.

    Args:
        frames: [H, W, 3] uint8 each, H and W even.
    """
    import imageio_ffmpeg

    height, width = frames[0].shape[:2]
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
            macro_block_size=2, quality=7,
            output_params=[*BT709, "-movflags", "+faststart"])
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()


def gif_durations(n: int, fps: float) -> list[int]:
    """Per-frame GIF delays in milliseconds, multiples of 10 (GIF counts centiseconds), that
    add up to ``n / fps`` seconds: a constant rounded delay would drift by up to 5 ms a frame."""
    ends = [round(i * 100 / fps) * 10 for i in range(n + 1)]
    return [max(10, b - a) for a, b in zip(ends, ends[1:], strict=False)]


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """Looping animated GIF as long as the video: at most ``GIF_MAX_FPS`` frames a second and
    ``GIF_MAX_SIDE`` pixels a side, atomically. frames: [H, W, 3] uint8 each."""
    step = max(1, -(-fps // GIF_MAX_FPS))
    kept = frames[::step]
    images = []
    for frame in kept:
        image = Image.fromarray(frame, "RGB")
        image.thumbnail((GIF_MAX_SIDE, GIF_MAX_SIDE), Image.Resampling.LANCZOS)
        images.append(image)
    durations = gif_durations(len(kept), fps / step)
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=durations, loop=0)
